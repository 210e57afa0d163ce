"""Probe the referential game on a task dataset (one or more seeds): how much goal information the TL carries.

``python scripts/probe_referential_game.py runs/clevr/oracle/dataset --seeds 3 --temperature 4 --no-reference``

Prints the RG loss against two receivers trained the same way on the same batches: one given no message (zeros,
the loss floor of an ignored TL) and one given the true goal one-hot (the best a message can do); then how often
the generator's deterministic TL decodes to the tuple's goal, and the translated table's ``task_language_quality``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from talar_jax.dataset import TaskDataset  # noqa: E402
from talar_jax.language import build_cache  # noqa: E402
from talar_jax.optim import AdamFit, fit_seeds  # noqa: E402
from talar_jax.talar import (  # noqa: E402
    TalarConfig,
    decodable_fraction,
    make_generate_task_language,
    make_task_language_data,
    make_train_task_language,
    make_train_translator,
    make_translate,
    sample_referential_batch,
    task_language_quality,
)
from talar_jax.task_language import Receiver, referential_game_loss  # noqa: E402


def reference_receiver_loss(data, goals, num_goals, vocab_size, config, informed: bool) -> float:
    receiver = Receiver(vocab_size, config.receiver_hidden)

    def loss_fn(params, rng):
        rows, prefix = sample_referential_batch(*jax.random.split(rng), data, config.referential_batch_size)
        message = jax.nn.one_hot(goals[rows], num_goals) * float(informed)
        logits = receiver.apply(params, message, data.prefix_embeddings[prefix])
        return referential_game_loss(logits, data.prefix_next_token[prefix])

    def init_params(rng):
        return receiver.init(rng, jnp.zeros((1, num_goals)), data.prefix_embeddings[:1])

    _, losses = jax.jit(AdamFit(init_params, loss_fn, config.rg_learning_rate, config.rg_steps))(jax.random.PRNGKey(1))
    return float(np.asarray(losses)[-max(1, config.rg_steps // 20) :].mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, help="folder with task_dataset.npz (an oracle stage's dataset/)")
    parser.add_argument("--env", default="clevr")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--lr", type=float, default=3e-3)
    parser.add_argument("--temperature", type=float, default=2.0)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--receiver-hidden", type=int, nargs="*", default=[256], help="receiver hidden layers")
    parser.add_argument("--seeds", type=int, default=1, help="generator seeds (vmapped); quality is per seed")
    parser.add_argument("--all-tokens", action="store_true", help="Eq. 2 over every token per tuple (rg_all_tokens)")
    parser.add_argument("--sentence-readout", default="sentence+prefixes", help="translator input (sentence_features)")
    parser.add_argument("--no-reference", action="store_true", help="skip the no-message / goal-told receivers")
    args = parser.parse_args()
    cache = build_cache(args.env, progress=False)
    dataset = TaskDataset.load(args.dataset)
    data = make_task_language_data(dataset, cache, args.sentence_readout)
    config = TalarConfig(
        rg_learning_rate=args.lr,
        gumbel_temperature=args.temperature,
        rg_batch_size=args.batch_size,
        rg_steps=args.steps,
        translator_steps=max(1, args.steps // 2),
        receiver_hidden=tuple(args.receiver_hidden),
        rg_all_tokens=args.all_tokens,
    )
    goals, num_goals = jnp.asarray(dataset.goal_ids), cache.num_goals
    for informed in () if args.no_reference else (False, True):
        loss = reference_receiver_loss(data, goals, num_goals, cache.vocab_size, config, informed)
        print(f"receiver given {'the goal' if informed else 'no message'}: RG loss {loss:.3f}")
    start = time.perf_counter()
    keys = jax.random.split(jax.random.PRNGKey(0), args.seeds)
    params, losses = fit_seeds(
        make_train_task_language(config, cache.vocab_size, cache.max_tokens), keys, data, label="RG"
    )
    print(
        f"TALAR generator: RG loss per seed {np.round(losses[:, -max(1, args.steps // 20) :].mean(1), 3)} "
        f"({time.perf_counter() - start:.0f} s)"
    )
    generate = jax.jit(jax.vmap(make_generate_task_language(config), in_axes=(0, None, None)))
    codes = np.asarray(generate(params["generator"], data.states, data.final_states)).round().astype(np.int8)
    every = np.ones(codes.shape[1], bool)
    for seed in range(args.seeds):
        decoded = decodable_fraction(codes[seed], dataset.goal_ids, every, every)
        distinct = len(np.unique(codes[seed], axis=0))
        print(f"seed {seed} generator TL: {distinct} distinct codes; decodes the tuple's goal for {decoded:.3f}")
    targets = jnp.asarray(codes, jnp.float32)
    translator, _ = fit_seeds(
        make_train_translator(config), keys, targets, data, in_axes=(0, None), label="translator", progress=False
    )
    tables = np.asarray(
        jax.jit(jax.vmap(make_translate(config), in_axes=(0, None)))(translator, data.sentence_embeddings)
    )
    for seed in range(args.seeds):
        quality = task_language_quality(tables[seed], cache.goal_ids, cache.is_train)
        print(f"seed {seed} translated table:", {k: round(v, 3) for k, v in quality.items()})


if __name__ == "__main__":
    main()
