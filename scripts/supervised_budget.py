"""How many referential-game and translator steps the task language needs: TL quality against budget.

``python scripts/supervised_budget.py runs/clevr/oracle/dataset --env clevr --seeds 5 --rg-milestones 5000 10000 20000
--translator-steps 1000 3000 10000``

Trains the env recipe's referential game (``experiments/recipes.py``) for every seed at once and, at each RG
milestone, trains translators for each ``--translator-steps`` budget from the generator's TL and prints the
translated table's ``task_language_quality`` (mean and per seed, as the experiment reports print it) and the time
each part took. Writes the rows as JSON with ``--json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from talar_jax.runtime import configure  # noqa: E402

configure()

import jax  # noqa: E402
import numpy as np  # noqa: E402

from experiments.recipes import get_recipe  # noqa: E402
from talar_jax.dataset import TaskDataset  # noqa: E402
from talar_jax.language import build_cache  # noqa: E402
from talar_jax.optim import fit_seeds  # noqa: E402
from talar_jax.talar import (  # noqa: E402
    make_generate_task_language,
    make_task_language_data,
    make_train_task_language,
    make_train_translator,
    make_translate,
    prepare_referential_data,
    task_language_quality,
)


def _budget(text: str) -> tuple[int, float]:
    """``STEPS@LR`` -> (steps, learning rate)."""
    try:
        steps, rate = text.split("@")
        return int(steps), float(rate)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected STEPS@LR such as 2000@0.002, got {text!r}") from None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, help="an oracle stage's dataset/ folder")
    parser.add_argument("--env", default="clevr")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rg-milestones", type=int, nargs="+", default=[5000, 10000, 20000])
    parser.add_argument("--translator-steps", type=int, nargs="+", default=[1000, 3000, 10000])
    parser.add_argument("--sentence-readout", default="sentence+prefixes")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--receiver-prefix-dims", type=int, default=None, help="TalarConfig.receiver_prefix_dims")
    parser.add_argument("--receiver-hidden", type=int, nargs="+", default=None, help="TalarConfig.receiver_hidden")
    parser.add_argument("--rg-token-slots", type=int, default=None, help="TalarConfig.rg_token_slots")
    parser.add_argument(
        "--translators",
        nargs="+",
        type=_budget,
        default=None,
        help="STEPS@LR translator budgets to try instead of --translator-steps at the recipe's LR",
    )
    args = parser.parse_args()
    recipe = get_recipe(args.env)
    cache = build_cache(args.env, progress=False)
    data = make_task_language_data(TaskDataset.load(args.dataset), cache, args.sentence_readout)
    config = dataclasses.replace(recipe.talar, rg_steps=max(args.rg_milestones))
    if args.receiver_prefix_dims:
        config = dataclasses.replace(config, receiver_prefix_dims=args.receiver_prefix_dims)
    if args.receiver_hidden:
        config = dataclasses.replace(config, receiver_hidden=tuple(args.receiver_hidden))
    if args.rg_token_slots:
        config = dataclasses.replace(config, rg_token_slots=args.rg_token_slots)
    rg_data = prepare_referential_data(config, data)
    fit = make_train_task_language(config, cache.vocab_size, cache.max_tokens)
    keys = jax.random.split(jax.random.key(args.seed), args.seeds)
    state = jax.jit(jax.vmap(fit.init, in_axes=(0, None)))(keys, rg_data)
    generate = jax.jit(jax.vmap(make_generate_task_language(config), in_axes=(0, None, None)))
    translate = jax.jit(jax.vmap(make_translate(config), in_axes=(0, None)))
    budgets = args.translators or [(steps, config.translator_learning_rate) for steps in args.translator_steps]
    rows, done, rg_seconds = [], 0, 0.0
    for milestone in sorted(args.rg_milestones):
        steps = milestone - done
        run = jax.jit(jax.vmap(lambda s, d, n=steps: fit.run(s, d, steps=n), in_axes=(0, None)))
        start = time.perf_counter()
        state, losses = run(state, rg_data)
        losses = np.asarray(losses)
        rg_seconds += time.perf_counter() - start
        done = milestone
        targets = generate(state.params["generator"], data.states, data.final_states)
        for translator_steps, translator_rate in budgets:
            timings: dict[str, float] = {}
            translator_config = dataclasses.replace(
                config, translator_steps=translator_steps, translator_learning_rate=translator_rate
            )
            translator_fit = make_train_translator(translator_config)
            params, _ = fit_seeds(
                translator_fit, keys, targets, data, in_axes=(0, None), progress=False, timings=timings
            )
            tables = np.asarray(translate(params, data.sentence_embeddings))
            quality = [task_language_quality(t, cache.goal_ids, cache.is_train) for t in tables]
            row = {
                "rg_steps": milestone,
                "translator_steps": translator_steps,
                "translator_learning_rate": translator_rate,
                "rg_loss_end": float(losses[:, -max(1, steps // 20) :].mean()),
                "rg_seconds_with_compile": rg_seconds,
                "translator_seconds": timings["run_s"],
                **{k: [round(q[k], 3) for q in quality] for k in quality[0]},
            }
            rows.append(row)
            means = {k: round(float(np.mean(row[k])), 3) for k in quality[0]}
            print(json.dumps({k: v for k, v in row.items() if k not in quality[0]} | means), flush=True)
    if args.json:
        arguments = {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}
        args.json.write_text(json.dumps({"args": arguments, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
