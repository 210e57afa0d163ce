"""Paper Table 3: CLEVR success on training instructions with 1, 5 and 9 sentence patterns.

``python -m experiments.patterns --seeds 5`` trains TALAR, One-hot, BERT-binary and BERT-continuous with the
first k training patterns (the IFP sees only those; the task language and translator are shared) and writes
``table3.md`` beside the per-run folders.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import tyro

from experiments.compare import CompareArgs, compare
from experiments.pipeline import EXPERIMENT_TALAR, ExperimentConfig
from talar_jax.talar import TalarConfig

PAPER = {"TALAR": (100.0, 100.0, 99.9), "One-hot": (98.2, 91.8, 86.5), "BERT-binary": (82.0, 60.9, 64.0),
         "BERT-continuous": (95.3, 63.1, 60.7)}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class PatternsArgs:
    """Table 3 settings."""

    patterns: tuple[int, ...] = (1, 5, 9)
    """Numbers of training sentence patterns."""
    methods: tuple[str, ...] = ("talar", "onehot", "bert-binary", "bert-continuous")
    """Methods (Table 3 rows)."""
    seeds: int = 5
    """Seeds per method and pattern count."""
    out: Path = Path("runs/patterns-clevr")
    """Output folder (shared oracle, dataset and task language)."""
    quick: bool = False
    """Smoke configuration."""
    physics: str | None = None
    """Physics backend (default: the faster one for this device)."""
    encoder: str | None = None
    """Local BERT folder (default: all-MiniLM-L6-v2)."""
    ifp_env_steps: int | None = None
    """IFP env steps per seed, method and pattern count (default: 2M, the paper's)."""
    talar: TalarConfig = EXPERIMENT_TALAR
    """TL size, referential game and translator settings (as ``experiments.clevr``'s ``--talar.*``)."""
    sentence_readout: str = ExperimentConfig.sentence_readout
    """What translators and BERT-* baselines read of an instruction (as ``experiments.clevr``'s option)."""
    progress: bool = True
    """Progress output."""


def patterns(args: PatternsArgs) -> str:
    rows: dict[str, list[str]] = {}
    for k in args.patterns:
        final = compare(CompareArgs(env="clevr", methods=args.methods, seeds=args.seeds, out=args.out,
                                    quick=args.quick, physics=args.physics, encoder=args.encoder, num_patterns=k,
                                    ifp_env_steps=args.ifp_env_steps, talar=args.talar,
                                    sentence_readout=args.sentence_readout, progress=args.progress))  # fmt: skip
        for label, per_split in final.items():
            rates = np.asarray(per_split["train"]) * 100
            rows.setdefault(label, []).append(f"{rates.mean():.1f} ± {rates.std():.1f}")
    header = "| method | " + " | ".join(f"{k} patterns" for k in args.patterns) + " | paper (1 / 5 / 9) |"
    lines = ["### Success on training instructions (%), CLEVR", "", header, "|---|" + "---|" * (len(args.patterns) + 1)]
    for label, cells in rows.items():
        paper = " / ".join(f"{v:g}" for v in PAPER.get(label, ())) or "-"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {paper} |")
    table = "\n".join(lines) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "table3.md").write_text(table)
    print(table)
    return table


if __name__ == "__main__":
    patterns(tyro.cli(PatternsArgs, description=__doc__))
