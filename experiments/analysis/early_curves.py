"""Compare methods' learning curves up to a common env-step budget, for a run cut short of the paper's.

``python -m experiments.analysis.early_curves --until 327680 --split train
"Fine-tuned BERT-continuous=runs/study/x/x" "BERT-continuous=results/kitchen-compare/bert-continuous" ...``

Each ``LABEL=FOLDER`` names a record (``experiments.records record``'s ``ifp_metrics.jsonl``) or a run's method folder
(``ifp/ppo/metrics.jsonl``). PPO here has no learning-rate schedule, so the first evaluations of a longer run are those
a run stopped at ``--until`` would have made: a reduced-budget probe can be read against the first ``--until`` env
steps of runs at the paper's budget. Prints a markdown table: success at every evaluation up to ``--until`` (mean
over seeds, then the per-seed values), the mean success over that part of the curve per seed, and the last
evaluation's success per goal (pooled over seeds). ``--plot PATH`` also draws the curves up to ``--until`` on training
and test instructions (mean +- std over seeds, as the run reports draw them).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from experiments.cli import ArgumentParser, UsageError, check_outputs, command
from talar_jax.report import LearningCurve, plot_learning_curves


def metrics_path(folder: Path) -> Path:
    """The IFP metrics file of a record or of a run's method folder."""
    for candidate in (folder / "ifp_metrics.jsonl", folder / "ifp" / "ppo" / "metrics.jsonl"):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"{folder} holds neither ifp_metrics.jsonl nor ifp/ppo/metrics.jsonl")


def early_curve(path: Path, until: int, split: str) -> dict:
    """Evaluations of one method up to ``until`` env steps: env steps (T,), success per seed (S, T) and the last
    one's success per goal (pooled over seeds; None: no episode)."""
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    rows = [r for r in rows if f"eval/{split}/success_per_seed" in r and r["train/env_steps"] <= until]
    if not rows:
        raise ValueError(f"{path}: no evaluation on {split} instructions at or before {until} env steps")
    success = np.array([r[f"eval/{split}/success_per_seed"] for r in rows], float).T
    return {
        "env_steps": np.array([r["train/env_steps"] for r in rows]),
        "success": success,
        "last_per_goal": rows[-1][f"eval/{split}/success_per_goal"],
    }


def _cell(values: np.ndarray) -> str:
    per_seed = "/".join(f"{100 * v:.0f}" for v in values)
    return f"{100 * values.mean():.1f} ({per_seed})" if len(values) > 1 else f"{100 * values.mean():.1f}"


def table(curves: dict[str, dict], split: str) -> str:
    """Markdown: one row per method, one column per evaluation step every method reached, then the curve mean."""
    steps = sorted(set.intersection(*(set(c["env_steps"].tolist()) for c in curves.values())))
    if not steps:
        raise ValueError("the methods share no evaluation step")
    head = [f"{s:,}" for s in steps]
    lines = [
        f"success on {split} instructions, % (mean over seeds, then per seed)",
        "",
        "| method | seeds | " + " | ".join(head) + " | mean over these | last, per goal |",
        "|---" * (len(head) + 4) + "|",
    ]
    for label, curve in curves.items():
        at = [curve["success"][:, list(curve["env_steps"]).index(s)] for s in steps]
        goals = "/".join("-" if g is None else f"{100 * g:.0f}" for g in curve["last_per_goal"])
        cells = [_cell(a) for a in at] + [_cell(np.stack(at, axis=1).mean(axis=1)), goals]
        lines.append(f"| {label} | {curve['success'].shape[0]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def run_command(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(prog="python -m experiments.analysis.early_curves", description=__doc__)
    parser.add_argument("methods", nargs="+", help="LABEL=FOLDER (a record or a run's method folder)")
    parser.add_argument("--until", type=int, required=True, help="last env step per seed to compare")
    parser.add_argument(
        "--split", choices=("train", "test"), default="train", help="instruction split of the table (default: train)"
    )
    parser.add_argument("--plot", type=Path, help="also write the curves up to --until to this PNG")
    args = parser.parse_args(argv)
    check_outputs((args.plot, "--plot", "file"))
    pairs = [m.split("=", 1) for m in args.methods]
    if any(len(p) != 2 or not p[0] for p in pairs):
        raise UsageError("methods are given as LABEL=FOLDER")
    splits = ("train", "test") if args.plot else (args.split,)  # the plot draws both
    by_split = {s: {label: early_curve(metrics_path(Path(f)), args.until, s) for label, f in pairs} for s in splits}
    print(table(by_split[args.split], args.split))
    if args.plot:
        both = {
            label: LearningCurve(
                by_split["train"][label]["env_steps"], {s: by_split[s][label]["success"] for s in splits}
            )
            for label, _ in pairs
        }
        print(f"wrote {plot_learning_curves(both, args.plot, title=f'first {args.until:,} env steps')}")


main = command(run_command, bad_input=(FileNotFoundError, ValueError))

if __name__ == "__main__":
    raise SystemExit(main())
