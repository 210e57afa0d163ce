"""What fine-tuning BERT inside policy training costs (paper Fig. 14, Appendix E.5), against the frozen BERT-binary.

``python -m benchmarks.finetuned_bert [--env kitchen] [--first-layers 5 0]``

One PPO update of each conditioner on the same env and settings, side by side in one run: BERT-binary (a dense layer
on the cached sentence embedding) and the fine-tuned BERT-binary training BERT's encoder layers from each
``--first-layers`` index up (0: all of BERT and its embeddings, the paper's). Every minibatch step of a fine-tuned
update runs BERT forward and backward over the env's training instructions (one batched pass), and every rollout
encodes every instruction once. The measured update uses ``--num-envs`` envs x 64 steps and one epoch of 128-row
minibatches, and again with more epochs: the difference is the minibatch steps' cost, the rest the rollout's. The table
projects one seed's IFP at the recipe's budget (its updates x epochs x minibatches, its rollouts scaled by env steps)
on this machine, one process, no evaluations. Prints a table and writes ``benchmarks/results/finetuned_bert.json``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

import envs
from benchmarks.machine import machine_info
from experiments.cli import ArgumentParser, exit_status
from experiments.config import default_config
from talar_jax import runtime
from talar_jax.baselines import EncodingLayerConditioner, FinetunedBertConditioner
from talar_jax.language import build_cache, load_encoder, load_instructions
from talar_jax.ppo import PPOConfig, derive, make_train

RESULTS = Path(__file__).parent / "results" / "finetuned_bert.json"


def lookups(env_name: str) -> dict:
    """split -> (goal -> cache rows, counts), as the experiments build them."""
    out = {}
    for split in ("train", "test"):
        instructions = load_instructions(env_name, split)
        out[split] = (instructions.goal_cache_rows(), instructions.goal_sentence_counts)
    return out


def time_update(env, conditioner, config: PPOConfig, repeats: int) -> dict:
    """Seconds of one jitted PPO update (rollout + one epoch of minibatch steps) and of its rollout alone."""
    learner = make_train(config, env, conditioner)
    state = jax.jit(learner.init)(jax.random.PRNGKey(0))
    start = time.perf_counter()
    chunk = jax.jit(learner.chunk).lower(state).compile(compiler_options=learner.compiler_options)
    compile_s = time.perf_counter() - start
    state, _ = chunk(state)  # warm-up
    jax.block_until_ready(state)
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        state, _ = chunk(state)
        jax.block_until_ready(state)
        seconds.append(time.perf_counter() - start)
    freeze = jax.jit(conditioner.freeze)
    jax.block_until_ready(freeze(state.params["conditioner"]))
    start = time.perf_counter()
    jax.block_until_ready(freeze(state.params["conditioner"]))
    return {"update_s": float(np.median(seconds)), "encode_all_s": time.perf_counter() - start, "compile_s": compile_s}


def measured_update(num_envs: int) -> tuple[PPOConfig, str]:
    """The PPO update both encoder benchmarks time (``num_envs`` envs x 64 steps, one epoch of minibatches of 128) and
    the words their printout describes it with."""
    config = PPOConfig(num_envs=num_envs, rollout_length=64, num_epochs=1, minibatch_size=128, updates_per_chunk=1)
    minibatches = derive(config).num_minibatches
    return config, f"one PPO update ({num_envs} envs x 64 steps, 1 epoch of {minibatches} minibatches of 128)"


def recipe_steps(recipe: PPOConfig) -> tuple[int, int]:
    """(updates, minibatch steps) of one seed's IFP at ``recipe``'s budget."""
    sizes = derive(recipe)
    updates = recipe.total_env_steps // sizes.env_steps_per_update
    return updates, updates * recipe.num_epochs * sizes.num_minibatches


def time_conditioners(
    env, conditioners: dict, config: PPOConfig, recipe: PPOConfig, repeats: int, extra_epochs: int = 1
) -> list[dict]:
    """One row per labelled conditioner: its update timed with one and ``1 + extra_epochs`` epochs of ``config``; the
    difference is the minibatch steps' cost, the rest the rollout's, and the projection is one seed's IFP at
    ``recipe``'s budget. Where a minibatch step is cheap, more extra epochs keep the difference above timing noise."""
    measured_minibatches = derive(config).num_minibatches
    recipe_updates, recipe_minibatch_steps = recipe_steps(recipe)
    rollout_scale = derive(recipe).env_steps_per_update / derive(config).env_steps_per_update
    more_epochs = dataclasses.replace(config, num_epochs=1 + extra_epochs)
    rows = []
    for label, conditioner in conditioners.items():
        print(f"timing {label} ...", flush=True)
        timing = time_update(env, conditioner, config, repeats)
        longer = time_update(env, conditioner, more_epochs, repeats)["update_s"]
        per_minibatch = max(longer - timing["update_s"], 0.0) / (measured_minibatches * extra_epochs)
        rollout = max(timing["update_s"] - per_minibatch * measured_minibatches, 0.0)
        projected = recipe_updates * rollout * rollout_scale + recipe_minibatch_steps * per_minibatch
        rows.append(
            {
                "conditioner": label,
                **timing,
                "extra_epochs": extra_epochs,
                "more_epochs_update_s": longer,
                "minibatch_step_s": per_minibatch,
                "rollout_s": rollout,
                "projected_recipe_ifp_h_per_seed": projected / 3600,
            }
        )
    return rows


def report(rows: list[dict], ratio: str, columns: list[tuple[str, str, str]], path: Path, payload: dict) -> None:
    """Adds ``ratio`` (each row's update over the first row's) to the rows, prints them as a markdown table of
    (header, key, format) columns and writes the machine, ``payload`` and the rows as JSON to ``path``."""
    print("| conditioner | " + " | ".join(header for header, _, _ in columns) + " |")
    print("|---|" + "---:|" * len(columns))
    for row in rows:
        row[ratio] = row["update_s"] / rows[0]["update_s"]
        print(f"| {row['conditioner']} | " + " | ".join(format(row[key], fmt) for _, key, fmt in columns) + " |")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"machine": machine_info(), **payload, "rows": rows}, indent=2) + "\n")
    print(f"\nwrote {path}")


def main(argv: list[str] | None = None) -> list[dict]:
    runtime.configure()  # the compile cache on, as when the recorded results were measured
    parser = ArgumentParser(prog="python -m benchmarks.finetuned_bert", description=__doc__)
    parser.add_argument(
        "--env", default="kitchen", choices=["clevr", "kitchen"], help="env of the timed update (default: kitchen)"
    )
    parser.add_argument(
        "--first-layers",
        type=int,
        nargs="+",
        default=[5, 0],
        help="fine-tuned variants to time: BERT trained from encoder layer K up, 0 for all of it (default: 5 0)",
    )
    parser.add_argument("--num-envs", type=int, default=16, help="envs of the timed PPO update (default: 16)")
    parser.add_argument(
        "--repeats", type=int, default=2, help="timed updates per conditioner; the median counts (default: 2)"
    )
    args = parser.parse_args(argv)

    experiment = default_config(args.env)
    env = envs.make(args.env, physics="c", **(experiment.env_options or {}))
    encoder = load_encoder(None)
    cache = build_cache(args.env, encoder, progress=False)
    splits = lookups(args.env)
    size = experiment.talar.spec.size
    mask = (np.arange(cache.token_ids.shape[1])[None, :] < cache.token_lengths[:, None]).astype(np.int32)
    train_rows = np.flatnonzero(cache.is_train)
    config, update = measured_update(args.num_envs)
    recipe = experiment.ifp
    _, recipe_minibatch_steps = recipe_steps(recipe)

    frozen = EncodingLayerConditioner(cache.sentence_embeddings, splits, size, True)
    conditioners = {"bert-binary (frozen BERT)": frozen}
    for first in args.first_layers:
        label = "all of BERT" if first == 0 else f"layers {first}-{encoder.config.num_hidden_layers - 1}"
        conditioners[f"finetuned-bert-binary ({label})"] = FinetunedBertConditioner(
            encoder.config, encoder.params, cache.token_ids, mask, splits, size, True, first, train_rows
        )
    rows = time_conditioners(env, conditioners, config, recipe, args.repeats)
    print(
        f"\n{args.env}: {update}, {len(train_rows)} training instructions; projection: "
        f"{recipe.total_env_steps:,} env steps = {recipe_minibatch_steps:,} minibatch steps per seed\n"
    )
    columns = [
        ("update (s)", "update_s", ".2f"),
        ("x frozen", "ratio_to_frozen", ".1f"),
        ("minibatch step (s)", "minibatch_step_s", ".3f"),
        ("rollout (s)", "rollout_s", ".2f"),
        ("encode every instruction (s)", "encode_all_s", ".3f"),
        ("projected IFP per seed (h)", "projected_recipe_ifp_h_per_seed", ".1f"),
    ]
    payload = {
        "env": args.env,
        "num_envs": args.num_envs,
        "training_instructions": int(len(train_rows)),
        "recipe_ifp_env_steps": recipe.total_env_steps,
        "recipe_minibatch_steps_per_seed": recipe_minibatch_steps,
    }
    report(rows, "ratio_to_frozen", columns, RESULTS, payload)
    return rows


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
