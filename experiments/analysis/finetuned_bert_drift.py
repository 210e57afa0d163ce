"""How far a fine-tuned BERT run's encoder moved from the pre-trained weights, and whether its sentence embeddings
still group by goal (paper Fig. 14, Appendix E.5).

    python -m experiments.analysis.finetuned_bert_drift RUN_DIR [--seed 0]

RUN_DIR is a ``finetuned-bert-*`` run (finished or not: the latest policy checkpoint is read). Prints, for one seed:
the relative change of the trained BERT weights, ||theta - theta_0|| / ||theta_0||; and the silhouette by goal of the
training instructions (scikit-learn, Euclidean; 1 = each goal a tight, separate group) and the share of test
instructions whose nearest training instruction names their goal, for three representations: the pooled sentence
embedding under the pre-trained weights (what the frozen BERT-* baselines read), the same under the fine-tuned
weights, and the codes the policy reads (the encoding layer on the fine-tuned embedding).
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from experiments.cli import ArgumentParser, command
from experiments.tsne import goal_grouping as tsne_goal_grouping
from talar_jax import runtime
from talar_jax.agent import AgentError, find_method_folder, read_policy_params
from talar_jax.baselines import FinetunedBertConditioner
from talar_jax.language import build_cache, load_encoder
from talar_jax.language.bert import mean_pool


def relative_change(tuned, pretrained) -> float:
    """||tuned - pretrained|| / ||pretrained|| over every leaf of two matching parameter trees."""
    diff = sum(float(jnp.sum((a - b) ** 2)) for a, b in zip(jax.tree.leaves(tuned), jax.tree.leaves(pretrained)))
    norm = sum(float(jnp.sum(b**2)) for b in jax.tree.leaves(pretrained))
    return float(np.sqrt(diff / norm))


def goal_grouping(vectors: np.ndarray, goals: np.ndarray, is_train: np.ndarray) -> dict[str, float]:
    """Silhouette by goal over the training rows; test rows' nearest-training-goal accuracy (``experiments.tsne``)."""
    grouping = tsne_goal_grouping(vectors, goals, is_train)
    return {key: grouping[key] for key in ("silhouette", "test_nearest_goal")}


def drift(run_dir: str | Path, seed: int = 0) -> dict:
    folder = find_method_folder(run_dir, prefer="talar")
    config = json.loads((folder / "config.json").read_text())
    if not str(config.get("method", "")).startswith("finetuned-"):
        raise AgentError(f"{folder} is a {config.get('method')} run, not a finetuned-bert-* one")
    params = read_policy_params(folder)["conditioner"]
    seeds = jax.tree.leaves(params)[0].shape[0]
    if not 0 <= seed < seeds:
        raise AgentError(f"seed {seed} is not in this run (it has {seeds})")
    params = jax.tree.map(lambda leaf: jnp.asarray(leaf[seed]), params)
    encoder = load_encoder(config.get("encoder"))
    cache = build_cache(config["env"], encoder, progress=False)
    lookups = {"train": (cache.goal_sentences, cache.goal_sentence_counts)}  # only the loss rows matter here
    conditioner = FinetunedBertConditioner.from_cache(
        encoder,
        cache,
        lookups,
        params["layer"]["params"]["Dense_0"]["kernel"].shape[-1],
        config["method"].endswith("binary"),
        config["talar"]["finetuned_bert_first_layer"],
        np.flatnonzero(cache.is_train),
    )

    def pooled(bert):
        hidden = conditioner.model.apply({"params": bert}, conditioner.inputs, conditioner.mask)
        return np.asarray(mean_pool(hidden, conditioner.mask))

    goals, is_train = np.asarray(cache.goal_ids), np.asarray(cache.is_train)
    codes = np.asarray(conditioner.encode(params, jnp.arange(len(goals))))
    return {
        "method": config["method"],
        "seed": seed,
        "first_trained_layer": config["talar"]["finetuned_bert_first_layer"],
        "bert_relative_change": relative_change(params["bert"], conditioner.pretrained),
        "pretrained_embedding": goal_grouping(pooled(conditioner.pretrained), goals, is_train),
        "finetuned_embedding": goal_grouping(pooled(params["bert"]), goals, is_train),
        "codes": goal_grouping(codes, goals, is_train),
    }


def run_command(argv: list[str] | None = None) -> None:
    runtime.start()
    parser = ArgumentParser(prog="python -m experiments.analysis.finetuned_bert_drift", description=__doc__)
    parser.add_argument("run_dir", type=Path, help="a finished finetuned-bert-* run (a run root or its method folder)")
    parser.add_argument("--seed", type=int, default=0, help="which of the run's seeds to measure (default: 0)")
    args = parser.parse_args(argv)
    print(json.dumps(drift(args.run_dir, args.seed), indent=1))


main = command(run_command, bad_input=(AgentError,))

if __name__ == "__main__":
    raise SystemExit(main())
