"""A study's outputs (``experiments.study``): ``study.md``, ``study.png``, ``study-curves.png`` and ``summary.json``.

The table gives each setting's final success on training and test instructions, its IFP budget and wall-clock, and
how fast it learns (the env steps at which the mean over seeds first reaches ``SPEED_THRESHOLD`` on training
instructions, and the mean success over the curve); the figures draw the final success per setting and the learning
curves; the summary holds the same numbers per seed with the command and commit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from experiments.config import ExperimentConfig
from experiments.reports import ifp_result, learning_curve
from talar_jax.checkpoint import write_json_atomic
from talar_jax.provenance import provenance
from talar_jax.report import LearningCurve, counted, percent_cell, plot_learning_curves

matplotlib.use("Agg")  # figures are only written to files

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
"""What the paper found, per study (the table's last line)."""

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


def setting_row(label: str, summary: dict[str, Any], speed: dict[str, Any] | None) -> str:
    """A setting's table row (``speed``: its ``learning_speed``, None when it has no learning curve)."""
    success = summary["final_success"]
    minutes = f"{ifp_seconds(summary) / 60:.1f}" if ifp_seconds(summary) is not None else "-"
    train, test = percent_cell(success["train"]), percent_cell(success["test"])
    speed = speed or {}
    reached = "never" if speed else "-"
    if speed.get("env_steps_to_80_percent") is not None:
        reached = f"{speed['env_steps_to_80_percent']:,}"
    area = f"{100 * speed['curve_mean_success']:.1f}" if speed else "-"
    steps = summary["ifp_env_steps_per_seed"]
    return f"| {label} | {train} | {test} | {steps:,} | {minutes} | {reached} | {area} |"


def study_table(
    name: str, title: str, finals: dict[str, dict[str, Any]], speeds: dict[str, dict[str, Any]], missing: list[str]
) -> str:
    """``study.md``: one row per finished setting, the settings not run yet, and the paper's finding."""
    lines = [f"### {title}", "", HEADER, "|---|---:|---:|---:|---:|---:|---:|"]
    lines += [setting_row(label, summary, speeds.get(label)) for label, summary in finals.items()]
    if missing:
        lines += ["", f"Not run yet (**partial study**): {', '.join(missing)}."]
    lines += ["", f"Paper: {PAPER[name]}."]
    return "\n".join(lines) + "\n"


def plot_final_success(finals: dict[str, dict[str, Any]], path: Path, title: str) -> None:
    """``study.png``: final success per setting, training and test instructions, mean ± std over seeds."""
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
    figure.savefig(path, dpi=120)
    plt.close(figure)


def study_summary(
    name: str,
    configs: dict[str, ExperimentConfig],
    finals: dict[str, dict[str, Any]],
    speeds: dict[str, dict[str, Any]],
    missing: list[str],
) -> dict[str, Any]:
    """``summary.json``: the study's shared settings, provenance, and every finished setting's numbers per seed."""
    first = next(iter(configs.values()))
    return {
        "study": name,
        "env": first.env,
        "method": first.method,
        "seeds": first.seeds,
        "num_patterns": first.num_patterns,
        "ifp_env_steps_per_seed": {label: summary["ifp_env_steps_per_seed"] for label, summary in finals.items()},
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
    }


def write_outputs(args, configs: dict[str, ExperimentConfig], finals: dict[str, dict[str, Any]]) -> str:
    """``study.md``, ``study.png``, ``study-curves.png`` and ``summary.json`` in the study folder (``args``: the
    study's ``StudyArgs``); returns the table."""
    first = next(iter(configs.values()))
    out = first.out.parent
    steps = max(summary["ifp_env_steps_per_seed"] for summary in finals.values())
    title = f"{args.name}, {first.env}, {counted(first.seeds, 'seed')}, IFP {steps:,} env steps per seed"
    curves = {label: curve for label in finals if (curve := setting_curve(configs[label])) is not None}
    speeds = {label: learning_speed(curve) for label, curve in curves.items()}
    missing = [label for label in configs if label not in finals]
    table = study_table(args.name, title, finals, speeds, missing)
    (out / "study.md").write_text(table)
    plot_final_success(finals, out / "study.png", title)
    if curves:
        plot_learning_curves(curves, out / "study-curves.png", title=f"{args.name}, {first.env}")
    write_json_atomic(out / "summary.json", study_summary(args.name, configs, finals, speeds, missing))
    return table
