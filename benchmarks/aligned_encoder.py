"""What the Aligned BERT baselines' encoder costs inside policy training (paper Fig. 12, Appendix E.3).

``python -m benchmarks.aligned_encoder [--env kitchen]``

The Aligned baselines run the TL generator's N_pn + N_a MLPs on the cached sentence embedding, and the policy's loss
trains them with the policy. One PPO update is timed side by side in one run for: BERT-binary (one dense layer per
row), the aligned BERT-binary encoding every row it reads (rollout steps and minibatch rows), and the aligned
BERT-binary as ``EncodingLayerConditioner`` runs it, gathering rows of a table encoding (every instruction once per
rollout, the training instructions once per minibatch). Same method and columns as ``benchmarks.finetuned_bert``:
one epoch and nine (``--extra-epochs``) of 128-row minibatches separate the minibatch steps' cost from the
rollout's, and the last column projects one seed's IFP at the recipe's budget on this machine. Prints a table and
writes ``benchmarks/results/aligned_encoder.json``.
"""

from __future__ import annotations

from pathlib import Path

import envs
from benchmarks.finetuned_bert import lookups, measured_update, recipe_steps, report, time_conditioners
from experiments.cli import ArgumentParser, exit_status
from experiments.config import default_config
from talar_jax import runtime
from talar_jax.baselines import EncodingLayerConditioner
from talar_jax.language import build_cache, load_encoder

RESULTS = Path(__file__).parent / "results" / "aligned_encoder.json"


class PerRowAlignedConditioner(EncodingLayerConditioner):
    """The aligned encoding applied to every row it reads (what the table encoding replaces)."""

    encodes_table = False


def main(argv: list[str] | None = None) -> list[dict]:
    runtime.configure()  # the compile cache on, as when the recorded results were measured
    parser = ArgumentParser(prog="python -m benchmarks.aligned_encoder", description=__doc__)
    parser.add_argument(
        "--env", default="kitchen", choices=["clevr", "kitchen"], help="env of the timed update (default: kitchen)"
    )
    parser.add_argument("--num-envs", type=int, default=16, help="envs of the timed PPO update (default: 16)")
    parser.add_argument(
        "--repeats", type=int, default=5, help="timed updates per conditioner; the median counts (default: 5)"
    )
    parser.add_argument(
        "--extra-epochs", type=int, default=8, help="epochs added to the timed update to measure a minibatch step"
    )
    args = parser.parse_args(argv)

    experiment = default_config(args.env)
    talar = experiment.talar
    env = envs.make(args.env, physics="c", **(experiment.env_options or {}))
    cache = build_cache(args.env, load_encoder(None), progress=False)
    features = cache.sentence_features(experiment.sentence_readout)
    splits = lookups(args.env)
    architecture = (talar.spec, talar.generator_hidden)
    conditioners = {
        "bert-binary (dense layer per row)": EncodingLayerConditioner(features, splits, talar.spec.size, True),
        "aligned-bert-binary (per row)": PerRowAlignedConditioner(
            features, splits, talar.spec.size, True, architecture
        ),
        "aligned-bert-binary (table, as run)": EncodingLayerConditioner(
            features, splits, talar.spec.size, True, architecture
        ),
    }
    config, update = measured_update(args.num_envs)
    recipe = experiment.ifp
    _, recipe_minibatch_steps = recipe_steps(recipe)
    rows = time_conditioners(env, conditioners, config, recipe, args.repeats, args.extra_epochs)
    print(
        f"\n{args.env}: {update}, {len(features)} instructions, sentence readout {experiment.sentence_readout!r} "
        f"({features.shape[1]} features), generator {talar.spec.num_predicates} predicate + "
        f"{talar.spec.num_arguments} argument networks of {tuple(talar.generator_hidden)}\n"
    )
    columns = [
        ("update (s)", "update_s", ".2f"),
        ("x BERT-binary", "ratio_to_bert_binary", ".1f"),
        ("minibatch step (s)", "minibatch_step_s", ".4f"),
        ("rollout (s)", "rollout_s", ".2f"),
        ("projected IFP per seed (h)", "projected_recipe_ifp_h_per_seed", ".2f"),
    ]
    payload = {
        "env": args.env,
        "num_envs": args.num_envs,
        "instructions": int(len(features)),
        "features": int(features.shape[1]),
        "recipe_ifp_env_steps": recipe.total_env_steps,
        "recipe_minibatch_steps_per_seed": recipe_minibatch_steps,
    }
    report(rows, "ratio_to_bert_binary", columns, RESULTS, payload)
    return rows


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
