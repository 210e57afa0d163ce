"""TALAR against the paper's baselines: ``python -m experiments.compare --env clevr --seeds 5``.

Runs every method on the same oracle, task dataset and language cache (one output folder, shared stages) and
writes ``compare.png`` (Fig. 4 style: all methods, train and test instructions, mean ± std over seeds) and
``compare.md`` (final success rates).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import tyro

from experiments import clevr, kitchen
from experiments.methods import METHOD_LABELS, METHODS
from experiments.pipeline import EXPERIMENT_TALAR, ExperimentConfig, learning_curve, run, run_name
from talar_jax.report import plot_learning_curves, results_table
from talar_jax.stages import StageResult
from talar_jax.talar import TalarConfig

DEFAULTS = {"clevr": clevr.DEFAULT, "kitchen": kitchen.DEFAULT}


@dataclasses.dataclass(frozen=True)
class CompareArgs:
    """Which env, methods and seeds to compare."""

    env: str = "clevr"
    """clevr or kitchen."""
    methods: tuple[str, ...] = tuple(METHODS)
    """Methods to run (TALAR first is conventional)."""
    seeds: int = 5
    """Seeds per method."""
    out: Path | None = None
    """Output folder (default runs/compare-<env>)."""
    quick: bool = False
    """Smoke configuration."""
    physics: str | None = None
    """Physics backend (default: the faster one for this device)."""
    encoder: str | None = None
    """Local BERT folder (default: all-MiniLM-L6-v2)."""
    num_patterns: int | None = None
    """CLEVR: train on the first k sentence patterns (Table 3)."""
    ifp_env_steps: int | None = None
    """IFP env steps per seed and method (default: the env command's, the paper's budget)."""
    talar: TalarConfig = EXPERIMENT_TALAR
    """TL size, referential game and translator settings (the env commands' ``--talar.*``, same defaults)."""
    sentence_readout: str = ExperimentConfig.sentence_readout
    """What translators and BERT-* baselines read of an instruction (as the env commands' ``--sentence-readout``)."""
    progress: bool = True
    """Progress output."""


def base_config(args: CompareArgs) -> ExperimentConfig:
    if args.env not in DEFAULTS:
        raise ValueError(f"unknown env {args.env!r}; valid: {', '.join(DEFAULTS)}")
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown or not args.methods:
        raise ValueError(f"unknown method(s) {unknown}; valid methods: {', '.join(METHODS)}")
    default = DEFAULTS[args.env]
    if args.ifp_env_steps is not None:
        if args.ifp_env_steps < 1:
            raise ValueError(f"--ifp-env-steps must be >= 1, got {args.ifp_env_steps}")
        default = dataclasses.replace(default, ifp=dataclasses.replace(default.ifp, total_env_steps=args.ifp_env_steps))
    return dataclasses.replace(
        default, seeds=args.seeds, out=args.out or Path(f"runs/compare-{args.env}"), quick=args.quick, talar=args.talar,
        physics=args.physics, encoder=args.encoder, num_patterns=args.num_patterns, progress=args.progress,
        sentence_readout=args.sentence_readout,
    )  # fmt: skip


def compare(args: CompareArgs) -> dict[str, dict[str, np.ndarray]]:
    """Runs each method (reusing finished stages) and writes the joint figure and table; returns final rates."""
    base = base_config(args)
    curves, final = {}, {}
    for method in args.methods:
        config = dataclasses.replace(base, method=method)
        run(config)
        ifp = StageResult(base.out / run_name(config) / "ifp", "", {}, 0.0, True)
        curve = learning_curve(ifp)
        curves[METHOD_LABELS[method]] = curve
        final[METHOD_LABELS[method]] = {split: rates[:, -1] for split, rates in curve.success.items()}
    title = f"{args.env} ({args.seeds} seeds)"
    suffix = f"-patterns{args.num_patterns}" if args.num_patterns else ""
    plot_learning_curves(curves, base.out / f"compare{suffix}.png", title=title)
    table = results_table(final, title=f"Final success rate, {title}")
    (base.out / f"compare{suffix}.md").write_text(table)
    print(table)
    return final


if __name__ == "__main__":
    compare(tyro.cli(CompareArgs, description=__doc__))
