"""The paper's appendix studies of one method's settings: ``python -m experiments.study NAME --env kitchen --seeds 5``.

NAME is one of

* ``ablation`` (paper Fig. 7, section 5.4): TALAR with N_pn in ``--predicates`` (2, 4, 6) x N_a in ``--arguments``
  (2, 3, 4) predicate and argument networks; the paper finds larger better, N_pn = 6, N_a = 4 sufficient.
* ``dataset-size`` (paper Fig. 13, Appendix E.4): TALAR with task datasets of ``--dataset-sizes`` tuples (10k, 25k,
  50k); the paper finds 10k tuples already give 76 %+ on kitchen, above every baseline.
* ``aligned`` (paper Fig. 12, Appendix E.3): TALAR against the BERT baselines whose encoding layer has the TL
  generator's architecture (``--method aligned-bert-binary`` / ``aligned-bert-continuous``) and the plain BERT-binary /
  BERT-continuous; the paper finds the aligned baselines better than the plain ones but below TALAR.
* ``end-to-end`` (paper Fig. 15, Appendix E.6): TALAR against ``--method end-to-end`` (generator, receiver and
  translator trained jointly); the paper finds the two-stage training better.
* ``finetuned-bert`` (paper Fig. 14, Appendix E.5): BERT-binary / BERT-continuous against ``--method
  finetuned-bert-binary`` / ``finetuned-bert-continuous``, whose BERT the policy's loss trains too (the one place
  the language model runs inside a training loop: one batched forward pass over the training instructions per
  minibatch, and one over every instruction per rollout); ``--talar.finetuned-bert-first-layer K`` trains only
  the encoder layers from K up (cheaper). The paper finds the fine-tuned baselines struggle to succeed at all.

Each setting is one experiment folder under ``--out`` (default ``runs/study-<name>-<env>``) with every stage cached,
so an interrupted study resumes where it stopped. The ablation's settings share the first one's oracle and task
dataset (a link to its ``oracle`` folder), as do the methods of the aligned and end-to-end studies; dataset sizes
collect their own. Writes ``study.png`` (final success per setting, train and test instructions, mean ± std over
seeds), ``study-curves.png`` (success over env steps per setting, as the paper's figures draw them), ``study.md``
(final success, and how fast each setting learns: the env steps at which the mean over seeds first reaches 80 % on
training instructions and the mean success over the curve) and ``summary.json`` (env, method, IFP env steps per seed,
seeds, command and commit beside every setting's final success per seed and its learning-speed figures).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Annotated, Any, Literal

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import tyro

from experiments.cli import CLI_CONFIG, valid_or_exit
from experiments.compare import env_option
from experiments.config import ExperimentConfig, default_config
from experiments.pipeline import check_inputs, finished_summary, run, stage_oracle_key
from experiments.recipes import recipe_names
from experiments.reports import ifp_result, learning_curve
from talar_jax import runtime
from talar_jax.checkpoint import write_json_atomic
from talar_jax.language import build_cache
from talar_jax.provenance import provenance
from talar_jax.report import LearningCurve, percent_cell, plot_learning_curves

matplotlib.use("Agg")  # figures are only written to files

STUDIES: tuple[str, ...] = ("ablation", "dataset-size", "aligned", "end-to-end", "finetuned-bert")
ALIGNED_METHODS: tuple[str, ...] = (
    "talar",
    "aligned-bert-binary",
    "aligned-bert-continuous",
    "bert-binary",
    "bert-continuous",
)
FINETUNED_METHODS: tuple[str, ...] = (
    "bert-binary",
    "bert-continuous",
    "finetuned-bert-binary",
    "finetuned-bert-continuous",
)
METHOD_STUDIES: dict[str, tuple[str, ...]] = {
    "aligned": ALIGNED_METHODS,
    "end-to-end": ("talar", "end-to-end"),
    "finetuned-bert": FINETUNED_METHODS,
}
"""Studies that compare methods (one setting per method) rather than TALAR's settings."""

PAPER = {
    "ablation": "larger N_pn and N_a better on train and test; too large slows training; N_pn = 6, N_a = 4 sufficient "
    "(Fig. 7, kitchen, 4M steps)",
    "dataset-size": "10,000 tuples already give 76 %+ success, above every baseline (Fig. 13, kitchen)",
    "end-to-end": "training the TL generator and the translator apart is better than jointly (Fig. 15, kitchen)",
    "aligned": "the aligned baselines improve on the plain ones but stay below TALAR in learning speed and final "
    "score (Fig. 12, kitchen)",
    "finetuned-bert": "with BERT's parameters trained during policy learning, the baselines struggle to succeed at "
    "all (Fig. 14, kitchen)",
}


@dataclasses.dataclass(frozen=True)
class StudyArgs:
    """Which study, over which settings, on the experiment settings every run shares."""

    name: tyro.conf.Positional[Literal["ablation", "dataset-size", "aligned", "end-to-end", "finetuned-bert"]]
    """The study: ablation (Fig. 7), dataset-size (Fig. 13), aligned (Fig. 12), end-to-end (Fig. 15) or
    finetuned-bert (Fig. 14)."""
    experiment: Annotated[ExperimentConfig, tyro.conf.arg(name="")] = ExperimentConfig(env="kitchen")
    """The shared settings, as the env commands take them (``--env``, ``--seeds``, ``--talar.*``, ...; defaults: the
    env's recipe; ``--out`` defaults to runs/study-<name>-<env>)."""
    predicates: tuple[int, ...] = (2, 4, 6)
    """ablation: numbers of predicate networks N_pn."""
    arguments: tuple[int, ...] = (2, 3, 4)
    """ablation: numbers of argument networks N_a."""
    dataset_sizes: tuple[int, ...] = (10_000, 25_000, 50_000)
    """dataset-size: task-dataset sizes (tuples)."""
    ifp_env_steps: int | None = None
    """IFP env steps per seed and setting (default: the env command's, the paper's budget)."""
    only: tuple[str, ...] = ()
    """Settings to run in this call (labels as in study.md: npn6-na4, tuples10000, aligned-bert-binary, ...; default:
    all). The outputs cover every setting whose run finished with the study's settings, so a long study can be run
    a few settings at a time."""
    report_only: bool = False
    """Run nothing: rewrite the study's figures, table and summary over the settings already finished (after
    restoring recorded runs with ``scripts/restore_record.py``, or after a change to the report)."""


def settings(args: StudyArgs) -> dict[str, ExperimentConfig]:
    """Label -> resolved experiment of every setting of the study (validated: one ValueError per bad input)."""
    base = args.experiment
    if base.method != "talar":
        if args.name in METHOD_STUDIES:
            raise ValueError(f"the {args.name} study sets each setting's method itself; drop --method {base.method}")
        raise ValueError(f"the {args.name} study varies TALAR's task language; got --method {base.method}")
    if args.ifp_env_steps is not None and args.ifp_env_steps < 1:
        raise ValueError(f"--ifp-env-steps must be >= 1, got {args.ifp_env_steps}")
    out = base.out if base.out is not None else Path(f"runs/study-{args.name}-{base.env}")
    variants: dict[str, ExperimentConfig] = {}
    if args.name == "ablation":
        if not args.predicates or not args.arguments or min(args.predicates + args.arguments) < 1:
            raise ValueError("--predicates and --arguments need positive counts")
        talar = check_inputs(base).talar
        for predicates in args.predicates:
            for arguments in args.arguments:
                spec = dataclasses.replace(talar.spec, num_predicates=predicates, num_arguments=arguments)
                variant = dataclasses.replace(base, talar=dataclasses.replace(talar, spec=spec))
                variants[f"npn{predicates}-na{arguments}"] = variant
    elif args.name in METHOD_STUDIES:
        for method in METHOD_STUDIES[args.name]:
            variants[method] = dataclasses.replace(base, method=method)
    else:
        if not args.dataset_sizes or min(args.dataset_sizes) < 1:
            raise ValueError("--dataset-sizes needs positive sizes")
        for size in args.dataset_sizes:
            variants[f"tuples{size}"] = dataclasses.replace(base, num_tuples=size)
    if args.report_only and args.only:
        raise ValueError("--report-only runs no setting: drop --only")
    unknown = [label for label in args.only if label not in variants]
    if unknown:
        raise ValueError(f"unknown --only setting(s) {unknown}; this study's settings: {', '.join(variants)}")
    resolved = {}
    for label, variant in variants.items():
        config = check_inputs(dataclasses.replace(variant, out=out / label))
        if args.ifp_env_steps is not None:
            config = dataclasses.replace(
                config, ifp=dataclasses.replace(config.ifp, total_env_steps=args.ifp_env_steps)
            )
        resolved[label] = config
    return resolved


def share_oracle(first: Path, target: Path) -> None:
    """Links ``target/oracle`` to ``first/oracle`` (same oracle settings: its stage key matches, nothing reruns)."""
    source = first / "oracle"
    if (target / "oracle").exists() or not (source / "stage.json").is_file():
        return
    target.mkdir(parents=True, exist_ok=True)
    os.symlink(os.path.relpath(source.resolve(), target.resolve()), target / "oracle")


HEADER = (
    "| setting | train instructions (%) | test instructions (%) | IFP env steps per seed | IFP wall-clock (min) "
    "| 80 % first reached (env steps) | mean success over the curve (%) |"
)
SPEED_THRESHOLD = 0.8
"""Learning speed: the first evaluation at which the mean success over seeds (training instructions) reaches it."""


def setting_curve(config: ExperimentConfig) -> LearningCurve | None:
    """A setting's learning curve from its IFP's ``metrics.jsonl`` (also in a restored record); None without one."""
    ifp = ifp_result(config)
    if not (ifp.path / "ppo" / "metrics.jsonl").is_file():
        return None
    curve = learning_curve(ifp)
    return curve if curve.env_steps.size else None


def learning_speed(curve: LearningCurve) -> dict[str, float | int | None]:
    """Training instructions: the env steps at which the mean over seeds first reaches ``SPEED_THRESHOLD`` (None:
    never) and the mean success over the curve (mean over seeds, then over evaluations)."""
    mean = np.asarray(curve.success["train"], float).mean(0)
    reached = np.flatnonzero(mean >= SPEED_THRESHOLD)
    return {
        "env_steps_to_80_percent": int(curve.env_steps[reached[0]]) if reached.size else None,
        "curve_mean_success": float(mean.mean()),
    }


def ifp_seconds(summary: dict[str, Any]) -> float | None:
    """Wall-clock seconds of a setting's IFP stage (all its seeds, when it ran), from its run summary."""
    seconds = [value for name, value in summary.get("stage_seconds", {}).items() if name.endswith("ifp")]
    return float(seconds[0]) if seconds else None


def write_outputs(args: StudyArgs, configs: dict[str, ExperimentConfig], finals: dict[str, dict[str, Any]]) -> str:
    """``study.md``, ``study.png`` and ``summary.json`` in the study folder; returns the table."""
    out = next(iter(configs.values())).out.parent
    first = next(iter(configs.values()))
    steps = {label: summary["ifp_env_steps_per_seed"] for label, summary in finals.items()}
    title = f"{args.name}, {first.env}, {first.seeds} seeds, IFP {max(steps.values()):,} env steps per seed"
    lines = [
        f"### {title}",
        "",
        HEADER,
    ]
    lines.append("|---|---:|---:|---:|---:|---:|---:|")
    curves = {label: curve for label in finals if (curve := setting_curve(configs[label])) is not None}
    speeds = {label: learning_speed(curve) for label, curve in curves.items()}
    for label, summary in finals.items():
        success = summary["final_success"]
        minutes = f"{ifp_seconds(summary) / 60:.1f}" if ifp_seconds(summary) is not None else "-"
        train, test = percent_cell(success["train"]), percent_cell(success["test"])
        speed = speeds.get(label, {})
        reached = "never" if label in speeds else "-"
        if speed.get("env_steps_to_80_percent") is not None:
            reached = f"{speed['env_steps_to_80_percent']:,}"
        area = f"{100 * speed['curve_mean_success']:.1f}" if speed else "-"
        lines.append(f"| {label} | {train} | {test} | {steps[label]:,} | {minutes} | {reached} | {area} |")
    missing = [label for label in configs if label not in finals]
    if missing:
        lines += ["", f"Not run yet (**partial study**): {', '.join(missing)}."]
    lines += ["", f"Paper: {PAPER[args.name]}."]
    table = "\n".join(lines) + "\n"
    (out / "study.md").write_text(table)

    figure, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    labels = list(finals)
    for axis, split in zip(axes, ("train", "test"), strict=True):
        rates = [100 * np.asarray(finals[label]["final_success"][split]) for label in labels]
        axis.bar(range(len(labels)), [r.mean() for r in rates], yerr=[r.std() for r in rates], capsize=3)
        axis.set_xticks(range(len(labels)), labels, rotation=45, ha="right")
        axis.set_title(f"{split} instructions")
        axis.set_ylim(0, 100)
    axes[0].set_ylabel("final success (%)")
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(out / "study.png", dpi=120)
    plt.close(figure)
    if curves:
        plot_learning_curves(curves, out / "study-curves.png", title=f"{args.name}, {first.env}")

    write_json_atomic(
        out / "summary.json",
        {
            "study": args.name,
            "env": first.env,
            "method": first.method,
            "seeds": first.seeds,
            "num_patterns": first.num_patterns,
            "ifp_env_steps_per_seed": steps,
            **provenance(),
            "settings": {
                label: {
                    "folder": str(config.out),
                    "method": config.method,
                    "final_success": finals[label]["final_success"],
                    "learning_speed": speeds.get(label),
                }
                for label, config in configs.items()
                if label in finals
            },
            "not_run": missing,
        },
    )
    return table


def study(args: StudyArgs, configs: dict[str, ExperimentConfig] | None = None) -> dict[str, dict[str, Any]]:
    """Runs the settings of ``--only`` (default: all; reusing finished stages) and writes the study's figure, table
    and summary over every setting finished with the study's settings; ``configs``: ``settings(args)`` when already
    computed (each resolves its encoder folder)."""
    configs = configs if configs is not None else settings(args)
    first = next(iter(configs.values())).out
    selected = [] if args.report_only else [label for label in configs if not args.only or label in args.only]
    finals = {}
    for index, label in enumerate(selected):
        config = configs[label]
        print(f"[study {args.name}] setting {index + 1}/{len(selected)}: {label} -> {config.out}", flush=True)
        if (args.name == "ablation" or args.name in METHOD_STUDIES) and config.out != first:
            share_oracle(first, config.out)
        finals[label] = run(config)
    rest = [label for label in configs if label not in finals]
    if rest:  # the language cache is the same for every setting: read its key once
        cache_key = build_cache(configs[rest[0]].env, configs[rest[0]].encoder, progress=False).key
        for label in rest:
            summary = finished_summary(configs[label], (stage_oracle_key(configs[label]), cache_key))
            if summary is not None:
                finals[label] = summary
    finals = {label: finals[label] for label in configs if label in finals}
    if not finals:
        where = first.parent
        raise SystemExit(f"error: no setting of the {args.name} study has finished in {where}: nothing to report")
    print(write_outputs(args, configs, finals))
    return finals


def main(argv: list[str] | None = None) -> dict[str, dict[str, Any]]:
    runtime.start()
    env = env_option(argv, default="kitchen")
    default = None
    if env in recipe_names():
        default = StudyArgs(tyro.MISSING, experiment=dataclasses.replace(default_config(env), out=None))
    args = tyro.cli(StudyArgs, args=argv, default=default, description=__doc__, config=CLI_CONFIG)
    return study(args, valid_or_exit(settings, args))


if __name__ == "__main__":
    main()
