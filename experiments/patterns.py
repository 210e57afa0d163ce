"""Paper Table 3: CLEVR success on training instructions with 1, 5 and 9 sentence patterns.

``python -m experiments.patterns --seeds 5`` trains TALAR, One-hot, BERT-binary and BERT-continuous with the
first k training patterns (the IFP sees only those; the task language and translator are shared) and writes
``table3.md`` beside the per-run folders. Nine patterns are the full training set, the same runs as
``experiments.compare`` (``--reuse-stages runs/compare-clevr`` copies them).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from experiments.cli import FLATTEN, command, write_output
from experiments.compare import CompareArgs, base_config, compare, finished_summaries, run_parsed
from experiments.config import ExperimentConfig, default_config
from experiments.methods import method_label
from talar_jax import runtime
from talar_jax.report import percent_cell

PAPER = {
    "TALAR": (100.0, 100.0, 99.9),
    "One-hot": (98.2, 91.8, 86.5),
    "BERT-binary": (82.0, 60.9, 64.0),
    "BERT-continuous": (95.3, 63.1, 60.7),
}


@dataclasses.dataclass(frozen=True)
class PatternsArgs:
    """Table 3 settings."""

    experiment: ExperimentConfig = dataclasses.field(
        default=dataclasses.replace(default_config("clevr"), out=Path("runs/patterns-clevr")), metadata=FLATTEN
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


TABLE3_METHODS: tuple[str, ...] = ("talar", "onehot", "bert-binary", "bert-continuous")
TABLE3_PATTERNS: tuple[int, ...] = (1, 5, 9)


def patterns(args: PatternsArgs) -> str:
    """Runs each column of ``--patterns`` and writes ``table3.md`` over the paper's rows and columns (plus those of
    this call): cells of this call's runs, of runs finished earlier in the folder with the same settings (one method
    or pattern count per call adds up to one table), and "-" for those not run yet."""
    methods = TABLE3_METHODS + tuple(m for m in args.methods if m not in TABLE3_METHODS)
    columns = sorted(set(TABLE3_PATTERNS) | set(args.patterns))
    cells: dict[tuple[str, int], str] = {}
    for k in args.patterns:
        final = compare(args.comparison(k))  # also holds the folder's earlier runs of this column
        for method in methods:
            if method_label(method) in final:
                cells[(method, k)] = percent_cell(final[method_label(method)]["train"])
    for k in columns:
        if k not in args.patterns:
            for method, summary in finished_summaries(base_config(args.comparison(k))).items():
                if method in methods:
                    cells[(method, k)] = percent_cell(summary["final_success"]["train"])
    header = (
        "| method | " + " | ".join(f"{k} pattern{'s' if k != 1 else ''}" for k in columns) + " | paper (1 / 5 / 9) |"
    )
    lines = ["### Success on training instructions (%), CLEVR", "", header, "|---|" + "---|" * (len(columns) + 1)]
    for method in methods:
        label = method_label(method)
        paper = " / ".join(f"{v:g}" for v in PAPER.get(label, ())) or "-"
        lines.append(f"| {label} | " + " | ".join(cells.get((method, k), "-") for k in columns) + f" | {paper} |")
    lines += ["", '"-": not run in this folder yet with these settings.']
    table = "\n".join(lines) + "\n"
    write_output(args.experiment.out / "table3.md", table)
    print(table)
    return table


def run_command(argv: list[str] | None = None) -> str:
    """``python -m experiments.patterns`` for Python callers: the table it wrote."""
    runtime.start()
    return run_parsed(PatternsArgs, patterns, argv, __doc__)


main = command(run_command, resumes=True)

if __name__ == "__main__":
    raise SystemExit(main())
