"""Referential-game and translator step time: the per-distinct-prefix / per-distinct-sentence layouts against per-row.

``python -m benchmarks.supervised_layouts --env kitchen --dataset runs/kitchen/oracle/dataset``

Times ``--steps`` jitted steps (5 seeds vmapped, compile apart) of the env recipe's referential game and translator
on a task dataset, in the layout the fits choose (the receiver's first layer once per distinct prefix and the
translator once per distinct sentence, when those are fewer than the rows of a step) and in the per-row layout,
side by side in one process; with ``--prefix-dims k`` also the chosen layout of the game whose receiver reads the
prefixes' first k principal components (``TalarConfig.receiver_prefix_dims``), and with ``--token-slots K`` the game
reading at most K token slots per tuple (``TalarConfig.rg_token_slots``; 0: every slot). Beside the current code it
times the formulations before: the translator's attention pooling with autodiff's gradient, and the game's per-row
receiver on the broadcast [TL, prefix] input. Prints a table and writes
``benchmarks/results/supervised_layouts_<env>.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.machine import machine_info
from envs.runtime import program_compiler_options
from experiments.cli import ArgumentParser, exit_status
from experiments.config import default_config
from experiments.methods.base import translator_readout
from talar_jax import runtime, talar, task_language
from talar_jax.dataset import TaskDataset
from talar_jax.language import TOKEN_READOUT, build_cache, load_encoder, readout_features
from talar_jax.talar import (
    make_task_language_data,
    make_train_task_language,
    make_train_translator,
    prepare_referential_data,
    trim_token_padding,
)

RESULTS_DIR = Path(__file__).parent / "results"


def time_fit(fit, data, extra: tuple, seeds: int, steps: int, repeats: int = 3) -> float:
    """Seconds per step of ``fit`` (vmapped over seeds), compile and a warm-up call apart, compiled as the fits are
    (``optim.fit_seeds``: XLA's fusion emitters on)."""
    keys = jax.random.split(jax.random.key(0), seeds)
    in_axes = (0,) + (0,) * len(extra) + (None,)
    state = jax.jit(jax.vmap(fit.init, in_axes=in_axes))(keys, *extra, data)
    run = jax.jit(jax.vmap(lambda s, *x: fit.run(s, *x, steps=steps), in_axes=in_axes))
    compiled = run.lower(state, *extra, data).compile(compiler_options=program_compiler_options(steps_mjx=False))
    jax.block_until_ready(compiled(state, *extra, data))
    seconds = []
    for _ in range(repeats):  # the best of a few calls: a call is about a second, and the machine's speed drifts
        start = time.perf_counter()
        jax.block_until_ready(compiled(state, *extra, data))
        seconds.append(time.perf_counter() - start)
    return min(seconds) / steps


def parse_args() -> argparse.Namespace:
    parser = ArgumentParser(prog="python -m benchmarks.supervised_layouts", description=__doc__)
    parser.add_argument("--env", default="kitchen", help="env whose recipe is timed (default: kitchen)")
    parser.add_argument("--dataset", type=Path, required=True, help="an oracle stage's dataset/ folder")
    parser.add_argument("--seeds", type=int, default=5, help="seeds vmapped in each timed step (default: 5)")
    parser.add_argument("--steps", type=int, default=200, help="timed steps per fit, compile apart (default: 200)")
    parser.add_argument(
        "--sentence-readout",
        default=None,
        help="what the translator reads of an instruction (default: the recipe's, token states where it reads them)",
    )
    parser.add_argument(
        "--prefix-dims", type=int, nargs="*", default=[32], help="also time the game with receiver_prefix_dims = each"
    )
    parser.add_argument(
        "--token-slots",
        type=int,
        nargs="*",
        default=[0],
        help="also time the game with rg_token_slots = each (0: every token slot of the longest instruction)",
    )
    return parser.parse_args()


def time_layouts(args: argparse.Namespace, fits: dict[str, tuple], data, per_row) -> list[dict]:
    """One row per fit: ms per step in the layout the fits choose and in the per-row layout."""
    results = []
    for name, (fit, extra) in fits.items():
        cheap = time_fit(fit, data, extra, args.seeds, args.steps)
        plain = time_fit(fit, per_row, extra, args.seeds, args.steps)
        results.append({"fit": name, "chosen_ms_per_step": 1000 * cheap, "per_row_ms_per_step": 1000 * plain})
        print(
            f"{args.env} {name}: chosen layout {1000 * cheap:.1f} ms/step, per-row {1000 * plain:.1f} ms/step "
            f"({plain / cheap:.2f}x)",
            flush=True,
        )
    return results


def time_prefix_dims(args: argparse.Namespace, config, cache, raw_data, rg: dict) -> None:
    """Adds to the game's row ``rg`` its ms per step with ``receiver_prefix_dims`` = each ``--prefix-dims``."""
    for dims in args.prefix_dims:
        projected_config = dataclasses.replace(config, receiver_prefix_dims=dims)
        fit = make_train_task_language(projected_config, cache.vocab_size, cache.max_tokens)
        projected = time_fit(fit, prepare_referential_data(projected_config, raw_data), (), args.seeds, args.steps)
        rg[f"prefix_dims_{dims}_ms_per_step"] = 1000 * projected
        print(
            f"{args.env} referential game, receiver_prefix_dims={dims}: {1000 * projected:.1f} ms/step "
            f"({rg['chosen_ms_per_step'] / 1000 / projected:.2f}x faster than the whole embedding)",
            flush=True,
        )


def time_token_slots(args: argparse.Namespace, config, cache, data, rg: dict) -> None:
    """Adds to the game's row ``rg`` its ms per step with ``rg_token_slots`` = each ``--token-slots``."""
    for slots in args.token_slots:
        slotted_config = dataclasses.replace(config, rg_token_slots=slots or None)
        fit = make_train_task_language(slotted_config, cache.vocab_size, cache.max_tokens)
        slotted = time_fit(fit, data, (), args.seeds, args.steps)
        rg[f"token_slots_{slots}_ms_per_step"] = 1000 * slotted
        print(
            f"{args.env} referential game, rg_token_slots={slots or 'every slot'}: {1000 * slotted:.1f} ms/step "
            f"(recipe: {config.rg_token_slots or 'every slot'}, {rg['chosen_ms_per_step']:.1f} ms/step)",
            flush=True,
        )


def autodiff_attention_pool(tokens, kernel, bias):
    """The translator's attention pooling as plain JAX, its gradient left to autodiff (the formulation before
    ``talar_jax.task_language.attention_pool`` wrote its gradient out)."""
    real = jnp.any(tokens != 0, axis=-1, keepdims=True)
    weights = jax.nn.softmax(jnp.where(real, tokens @ kernel + bias, -1e9), axis=-2)
    return jnp.einsum("...th,...td->...hd", weights, tokens)


def _broadcast_receiver(receiver_params, task_language, prefixes):
    """The receiver on [TL broadcast over tokens, prefix], one matrix per layer (the formulation before
    ``receiver_logits_per_token`` split the first layer)."""
    messages = jnp.broadcast_to(task_language[:, None, :], (*prefixes.shape[:-1], task_language.shape[-1]))
    x = jnp.concatenate([messages, prefixes], axis=-1)
    layers = receiver_params["params"]["ReluMLP_0"]
    for i in range(len(layers)):
        x = (jax.nn.relu(x) if i else x) @ layers[f"dense_{i}"]["kernel"] + layers[f"dense_{i}"]["bias"]
    return x


def time_formulations(args: argparse.Namespace, fits: dict[str, tuple], data, per_row, results: list[dict]) -> None:
    """Adds to each row its ms per step with the formulation before: autodiff's attention pooling (translator) and
    the broadcast receiver (the game's per-row layout), timed here beside the current ones."""
    patches = {  # fit -> (module, attribute, the formulation before, the layout it was timed in)
        "translator": (task_language, "attention_pool", autodiff_attention_pool, "chosen"),
        "referential game": (talar, "receiver_logits_per_token", _broadcast_receiver, "per_row"),
    }
    for row, (name, (fit, extra)) in zip(results, fits.items()):
        module, attribute, reference, key = patches[name]
        current = getattr(module, attribute)
        setattr(module, attribute, reference)
        try:  # the fit's loss reads the module attribute when traced, so a fresh trace takes the reference
            before = time_fit(fit, per_row if key == "per_row" else data, extra, args.seeds, args.steps)
        finally:
            setattr(module, attribute, current)
        row[f"{key}_before_ms_per_step"] = 1000 * before
        print(
            f"{args.env} {name}, {key} layout with the formulation before: {1000 * before:.1f} ms/step "
            f"({before / (row[f'{key}_ms_per_step'] / 1000):.2f}x the current)",
            flush=True,
        )


def main() -> None:
    runtime.configure()  # with the compile cache: steps are timed compile apart
    args = parse_args()
    cache = build_cache(args.env, progress=False)
    experiment = default_config(args.env)
    config = experiment.talar
    readout = args.sentence_readout or translator_readout(experiment)
    encoder = load_encoder(experiment.encoder) if readout == TOKEN_READOUT else None
    features = readout_features(cache, readout, encoder)  # token states: encoded once per machine, then cached
    raw_data = make_task_language_data(TaskDataset.load(args.dataset), cache)
    raw_data = trim_token_padding(raw_data._replace(sentence_embeddings=jnp.asarray(features, jnp.float32)))
    data = prepare_referential_data(config, raw_data)  # the recipe's game view (the translator reads the same data)
    rows = config.referential_batch_size * cache.max_tokens
    # the per-row layout: tables at least as large as a step's rows make the fits take the per-row branch
    per_row = data._replace(
        prefix_table=np.zeros((rows + 1, data.prefix_table.shape[1]), np.float32),
        dataset_sentences=np.arange(config.batch_size),
    )
    targets = np.zeros((args.seeds, data.states.shape[0], config.spec.size), np.float32)
    fits = {
        "referential game": (make_train_task_language(config, cache.vocab_size, cache.max_tokens), ()),
        "translator": (make_train_translator(config), (targets,)),
    }
    results = time_layouts(args, fits, data, per_row)
    time_formulations(args, fits, data, per_row, results)
    time_prefix_dims(args, config, cache, raw_data, results[0])
    time_token_slots(args, config, cache, data, results[0])
    sizes = {
        "rows_per_rg_step": rows,
        "distinct_training_prefixes": int(data.prefix_table.shape[0]),
        "translator_batch": config.batch_size,
        "distinct_training_sentences": int(data.dataset_sentences.shape[0]),
    }
    machine = machine_info()
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    out = RESULTS_DIR / f"supervised_layouts_{args.env}.json"
    arguments = {**vars(args), "dataset": str(args.dataset), "sentence_readout": readout}
    payload = {"machine": machine, "args": arguments, "sizes": sizes, "rows": results}
    out.write_text(json.dumps(payload, indent=2))
    print(json.dumps(sizes))


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
