"""TALAR against the paper's baselines: ``python -m experiments.compare --env clevr --seeds 5``.

Runs every method on the same oracle, task dataset and language cache (one output folder, shared stages) and
writes ``compare.png`` (Fig. 4 style: all methods, train and test instructions, mean ± std over seeds),
``compare.md`` (final success rates, and TALAR's margin over the best baseline beside the paper's) and ``tsne.png``
(Fig. 11: every method's instruction codes, seed 0, training and test instructions). The outputs cover every method
whose policy finished in the folder with this comparison's settings, so methods can be run one call at a time.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from experiments.cli import FLATTEN, check_outputs, checked, command, parse, peek
from experiments.config import ExperimentConfig, default_config, run_name
from experiments.lock import hold
from experiments.methods import PAPER_COMPARISON, method_label, method_names
from experiments.pipeline import check_inputs, finished_summary, run, stage_oracle_key
from experiments.recipes import get_recipe, recipe_names
from experiments.reports import ifp_result, learning_curve
from talar_jax import runtime
from talar_jax.language import build_cache
from talar_jax.report import counted, plot_learning_curves, results_table

NOT_A_BASELINE: tuple[str, ...] = ("talar", "handcrafted")
"""Left out of the best baseline: TALAR itself, and Handcrafted (a hand-made goal code: the paper's Fig. 16)."""


@dataclasses.dataclass(frozen=True)
class CompareArgs:
    """Which methods to compare, on the experiment settings every method shares."""

    experiment: ExperimentConfig = dataclasses.field(default=ExperimentConfig(), metadata=FLATTEN)
    """The shared settings, as the env commands take them (``--env``, ``--seeds``, ``--talar.*``, ...; defaults: the
    env's recipe, as ``default_config(env)``; ``--out`` defaults to runs/compare-<env>; ``--method`` is set per
    method)."""
    methods: tuple[str, ...] = PAPER_COMPARISON
    """Methods to run (TALAR first is conventional; default: the paper's eight of Fig. 4)."""
    ifp_env_steps: int | None = None
    """IFP env steps per seed and method (default: the env command's, the paper's budget)."""


def base_config(args: CompareArgs) -> ExperimentConfig:
    """The resolved experiment every method of the comparison runs (validated; one ValueError per bad input)."""
    unknown = [m for m in args.methods if m not in method_names()]
    if unknown or not args.methods:
        raise ValueError(f"unknown method(s) {unknown}; valid methods: {', '.join(method_names())}")
    if args.ifp_env_steps is not None and args.ifp_env_steps < 1:
        raise ValueError(f"--ifp-env-steps must be >= 1, got {args.ifp_env_steps}")
    experiment = args.experiment
    if experiment.out is None:
        experiment = dataclasses.replace(experiment, out=Path(f"runs/compare-{experiment.env}"))
    config = check_inputs(dataclasses.replace(experiment, method=args.methods[0]))
    if args.ifp_env_steps is not None:
        config = dataclasses.replace(config, ifp=dataclasses.replace(config.ifp, total_env_steps=args.ifp_env_steps))
    return config


def parse_args(cls, argv: list[str] | None, description: str | None = None):
    """``cls`` from the command line; a comparison's experiment defaults to the recipe of its ``--env``
    (``default_config(env)``), so ``compare --env kitchen`` runs the kitchen command's settings."""
    default = None
    if cls is CompareArgs:
        env = peek(argv, "--env", default="clevr")
        if env in recipe_names():
            default = CompareArgs(experiment=dataclasses.replace(default_config(env), out=None))
    return parse(cls, argv, default=default, description=description)


def _checked(args) -> Path:
    """Validates every comparison of ``args`` (one ValueError per bad input); returns the output folder."""
    if isinstance(args, CompareArgs):
        return base_config(args).out
    if not args.patterns:  # PatternsArgs: every column's comparison
        raise ValueError("--patterns needs at least one pattern count")
    return [base_config(args.comparison(k)) for k in args.patterns][0].out


def run_parsed(cls, function, argv: list[str] | None, description: str | None):
    """Parses ``cls`` from the command line and calls ``function`` holding the output folder's lock; a bad option
    or output folder, or a folder another command holds, raises ``experiments.cli.UsageError`` before any work."""
    args = parse_args(cls, argv, description)
    out = checked(_checked, args)
    check_outputs((out, "--out", "folder"))
    with hold(out):
        return function(args)


def compare(args: CompareArgs) -> dict[str, dict[str, np.ndarray]]:
    """Runs each method (reusing finished stages) and writes the joint figure and table; returns final rates."""
    base = base_config(args)
    env, seeds, num_patterns = base.env, base.seeds, base.num_patterns
    curves, final = {}, {}
    for method in args.methods:
        run(dataclasses.replace(base, method=method))
    earlier = finished_methods(base, args.methods)  # once: it hashes every method's stage keys
    shown = [m for m in method_names() if m in args.methods or m in earlier]
    for method in shown:
        config = dataclasses.replace(base, method=method)
        curve = learning_curve(ifp_result(config))
        curves[method_label(method)] = curve
        final[method_label(method)] = {split: rates[:, -1] for split, rates in curve.success.items()}
    title = f"{env} ({counted(seeds, 'seed')})"
    suffix = f"-patterns{num_patterns}" if num_patterns else ""
    plot_learning_curves(curves, base.out / f"compare{suffix}.png", title=title)
    table = results_table(final, title=f"Final success rate, {title}") + margin_lines(final, env)
    (base.out / f"compare{suffix}.md").write_text(table)
    print(table)
    print(write_fig11(base, tuple(shown), suffix))
    return final


def finished_summaries(base: ExperimentConfig, skip: tuple[str, ...] = ()) -> dict[str, dict]:
    """Method -> run summary of each method (besides ``skip``) whose run finished in ``base.out`` with exactly this
    comparison's settings (``finished_summary``: a run at another budget or recipe does not count)."""
    candidates = [
        m
        for m in method_names()
        if m not in skip and (base.out / run_name(dataclasses.replace(base, method=m))).is_dir()
    ]
    if not candidates:  # nothing to hash (the language cache's key needs its encoder)
        return {}
    keys = (stage_oracle_key(base), build_cache(base.env, base.encoder, progress=False).key)
    # base is resolved: resolving again would reset quick budgets
    summaries = {m: finished_summary(dataclasses.replace(base, method=m), keys) for m in candidates}
    return {m: summary for m, summary in summaries.items() if summary is not None}


def finished_methods(base: ExperimentConfig, skip: tuple[str, ...] = ()) -> list[str]:
    """Methods (besides ``skip``) whose run finished in ``base.out`` with exactly this comparison's settings."""
    return list(finished_summaries(base, skip))


def margin_lines(final: dict[str, dict[str, np.ndarray]], env: str) -> str:
    """TALAR's lead over the best baseline of the paper's Fig. 4 per split (mean over seeds), beside the paper's."""
    names = [method_label(m) for m in PAPER_COMPARISON if m not in NOT_A_BASELINE]
    baselines = {label: final[label] for label in names if label in final}
    if method_label("talar") not in final or not baselines:
        return ""
    paper_margin = get_recipe(env).paper_margin if env in recipe_names() else None
    paper = f"+{paper_margin:.1f}" if paper_margin is not None else "n/a"
    lines = [
        "",
        f"TALAR over the best baseline (paper: {paper} points; "
        f"{len(baselines)} of the paper's {len(names)} baselines here; Handcrafted is Fig. 16, not a baseline):",
        "",
    ]
    for split, rates in final[method_label("talar")].items():
        best = max(baselines, key=lambda label: float(np.mean(baselines[label][split])))
        margin = 100 * (float(np.mean(rates)) - float(np.mean(baselines[best][split])))
        lines.append(f"- {split} instructions: {margin:+.1f} points (best baseline {best})")
    return "\n".join(lines) + "\n"


def write_fig11(base: ExperimentConfig, methods: tuple[str, ...], suffix: str = "") -> str:
    """Paper Fig. 11 (``tsne<suffix>.png``) for the compared methods' seed 0; returns a line saying what was written."""
    from experiments.tsne import write_tsne_grid
    from talar_jax.agent import AgentError

    folders = [base.out / run_name(dataclasses.replace(base, method=method)) for method in methods]
    try:
        path, skipped = write_tsne_grid(folders, base.out / f"tsne{suffix}.png")
    except AgentError as error:
        return f"t-SNE figure: not written ({error})"
    return f"t-SNE figure (Fig. 11): {path}" + (
        f"; left out (no sentence encoding): {', '.join(skipped)}" if skipped else ""
    )


def run_command(argv: list[str] | None = None) -> dict[str, dict[str, np.ndarray]]:
    """``python -m experiments.compare`` for Python callers: the final success rates."""
    runtime.start()
    return run_parsed(CompareArgs, compare, argv, __doc__)


main = command(run_command, resumes=True)

if __name__ == "__main__":
    raise SystemExit(main())
