"""Turn a recorded result back into a report-only run folder, so a comparison or study counts it as finished.

``python scripts/restore_record.py results/kitchen-compare-5seeds-4M/gla runs/compare-kitchen-4M/gla``

runs/ is not committed, so a fresh checkout has none of the runs behind results/. A comparison's table
(``compare.md``) and a study's (``study.md``) cover every method or setting whose IFP stage finished in the folder
with the same settings (its recorded stage key); this writes what that check and the tables read, from the record
``scripts/record_result.py`` made: ``ifp/stage.json`` and ``ifp/ppo/metrics.jsonl``, ``summary.json``,
``config.json``, ``language.json``, ``results.md`` and the figures, and a ``RESTORED_FROM_RECORD`` marker naming
the record. No parameters come back: a restored method can be reported, not evaluated again or resumed, and the
t-SNE figures leave it out (they need its codes). Refuses to write into a folder that holds a run.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from talar_jax.report import RECORD_FILES

MARKER = "RESTORED_FROM_RECORD"


def restore(record: Path, dest: Path) -> list[str]:
    """Writes the report-only run folder ``dest`` from ``record``; returns the files written (relative to dest)."""
    ifp_stage = sorted(record.glob("*ifp_stage.json"))
    missing = [name for name in ("summary.json", "config.json", "ifp_metrics.jsonl") if not (record / name).is_file()]
    if missing or len(ifp_stage) != 1:
        raise ValueError(
            f"{record} is not a recorded run (needs summary.json, config.json, ifp_metrics.jsonl and "
            f"one *ifp_stage.json; missing {missing or 'the IFP stage record'})"
        )
    if dest.exists() and any(dest.iterdir()) and not (dest / MARKER).is_file():
        raise ValueError(f"{dest} holds a run; restore into an empty folder")
    (dest / "ifp" / "ppo").mkdir(parents=True, exist_ok=True)
    written = []
    for name in RECORD_FILES:
        if (record / name).is_file():
            shutil.copy(record / name, dest / name)
            written.append(name)
    shutil.copy(ifp_stage[0], dest / "ifp" / "stage.json")
    shutil.copy(record / "ifp_metrics.jsonl", dest / "ifp" / "ppo" / "metrics.jsonl")
    (dest / MARKER).write_text(f"{record}\n")
    return [*written, "ifp/stage.json", "ifp/ppo/metrics.jsonl", MARKER]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("record", type=Path, help="a folder record_result.py wrote, e.g. results/.../gla")
    parser.add_argument("dest", type=Path, help="the method folder to write, e.g. runs/compare-kitchen-4M/gla")
    args = parser.parse_args(argv)
    try:
        written = restore(args.record, args.dest)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    print(f"restored {args.record} -> {args.dest}: {', '.join(written)}")


if __name__ == "__main__":
    main()
