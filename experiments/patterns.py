"""Paper Table 3: CLEVR success on training instructions with 1, 5 and 9 sentence patterns.

``python -m experiments.patterns --seeds 5`` trains TALAR, One-hot, BERT-binary and BERT-continuous with the
first k training patterns (the IFP sees only those; the task language and translator are shared) and writes
``table3.md`` beside the per-run folders. Nine patterns are the full training set, the same runs as
``experiments.compare`` (``--reuse-stages runs/compare-clevr`` copies them).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from experiments.compare import CompareArgs, compare, main_with
from experiments.methods import METHOD_LABELS
from experiments.pipeline import ExperimentConfig, default_config

PAPER = {
    "TALAR": (100.0, 100.0, 99.9),
    "One-hot": (98.2, 91.8, 86.5),
    "BERT-binary": (82.0, 60.9, 64.0),
    "BERT-continuous": (95.3, 63.1, 60.7),
}


@dataclasses.dataclass(frozen=True)
class PatternsArgs:
    """Table 3 settings."""

    experiment: Annotated[ExperimentConfig, tyro.conf.arg(name="")] = dataclasses.replace(
        default_config("clevr"), out=Path("runs/patterns-clevr")
    )
    """The shared settings, as ``experiments.clevr`` takes them (one output folder: shared oracle, dataset and task
    language; ``--num-patterns`` and ``--method`` are set per row and column)."""
    patterns: tuple[int, ...] = (1, 5, 9)
    """Numbers of training sentence patterns."""
    methods: tuple[str, ...] = ("talar", "onehot", "bert-binary", "bert-continuous")
    """Methods (Table 3 rows)."""
    ifp_env_steps: int | None = None
    """IFP env steps per seed, method and pattern count (default: 2M, the paper's)."""

    def comparison(self, num_patterns: int) -> CompareArgs:
        """The comparison of one column."""
        experiment = dataclasses.replace(self.experiment, num_patterns=num_patterns)
        return CompareArgs(experiment=experiment, methods=self.methods, ifp_env_steps=self.ifp_env_steps)


def patterns(args: PatternsArgs) -> str:
    rows: dict[str, list[str]] = {}
    for k in args.patterns:
        final = compare(args.comparison(k))
        for label in [METHOD_LABELS[method] for method in args.methods]:  # compare.md may show more of its folder
            rates = np.asarray(final[label]["train"]) * 100
            rows.setdefault(label, []).append(f"{rates.mean():.1f} ± {rates.std():.1f}")
    header = "| method | " + " | ".join(f"{k} patterns" for k in args.patterns) + " | paper (1 / 5 / 9) |"
    lines = ["### Success on training instructions (%), CLEVR", "", header, "|---|" + "---|" * (len(args.patterns) + 1)]
    for label, cells in rows.items():
        paper = " / ".join(f"{v:g}" for v in PAPER.get(label, ())) or "-"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {paper} |")
    table = "\n".join(lines) + "\n"
    out = args.experiment.out
    out.mkdir(parents=True, exist_ok=True)
    (out / "table3.md").write_text(table)
    print(table)
    return table


if __name__ == "__main__":
    main_with(PatternsArgs, patterns, None, __doc__)
