"""Full-batch translators on a finished run's task language: TL quality against the number of steps.

``python scripts/full_batch_translator_probe.py runs/clevr-2M --env clevr --steps 300 1000 2000``

Reads the run's task dataset and referential-game generator, makes the generator's TL targets, and trains one
translator per seed with ``translator_full_batch`` (the exact expected Eq. 3 loss, one row per distinct instruction)
for each step count, with the seed keys the run's translator stage used. Prints ``task_language_quality`` (mean over
seeds) and the run time, to set beside the run's own (sampled-batch) translator in
``RUN/talar/translator/stage.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from talar_jax.runtime import configure  # noqa: E402

configure()

import jax  # noqa: E402
import numpy as np  # noqa: E402

from experiments.methods import stage_seed_keys  # noqa: E402
from experiments.recipes import get_recipe  # noqa: E402
from talar_jax.checkpoint import load_tree  # noqa: E402
from talar_jax.dataset import TaskDataset  # noqa: E402
from talar_jax.language import build_cache  # noqa: E402
from talar_jax.optim import fit_seeds  # noqa: E402
from talar_jax.talar import (  # noqa: E402
    make_generate_task_language,
    make_task_language_data,
    make_train_translator,
    make_translate,
    task_language_quality,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a finished run folder (with oracle/ and talar/task_language/)")
    parser.add_argument("--env", default="clevr")
    parser.add_argument("--steps", type=int, nargs="+", default=[300, 1000, 2000])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--sentence-readout", default="sentence+prefixes")
    args = parser.parse_args()
    cache = build_cache(args.env, progress=False)
    data = make_task_language_data(TaskDataset.load(args.run / "oracle" / "dataset"), cache, args.sentence_readout)
    config = get_recipe(args.env).talar
    generator = load_tree(args.run / "talar" / "task_language" / "params.msgpack")["generator"]
    generate = jax.jit(jax.vmap(make_generate_task_language(config), in_axes=(0, None, None)))
    targets = generate(generator, data.states, data.final_states)
    keys = stage_seed_keys(0, "talar/translator", args.seeds)  # the run's translator stage's (base seed 0)
    translate = jax.jit(jax.vmap(make_translate(config), in_axes=(0, None)))
    for steps in args.steps:
        fit = make_train_translator(dataclasses.replace(config, translator_full_batch=True, translator_steps=steps))
        timings: dict[str, float] = {}
        params, losses = fit_seeds(fit, keys, targets, data, in_axes=(0, None), progress=False, timings=timings)
        tables = np.asarray(translate(params, data.sentence_embeddings))
        quality = [task_language_quality(t, cache.goal_ids, cache.is_train) for t in tables]
        means = {k: round(float(np.mean([q[k] for q in quality])), 3) for k in quality[0]}
        print(steps, means, "loss", losses[:, -10:].mean().round(4), {k: round(v, 1) for k, v in timings.items()})


if __name__ == "__main__":
    main()
