"""Results records: copy a finished run's small outputs into ``results/``, put one back as a report-only run folder,
and state every recorded summary's budget.

    python -m experiments.records record runs/kitchen/talar results/kitchen-talar --command "python -m ..."
        [--note "machine, sharing, ..."]
    python -m experiments.records restore results/kitchen-compare/gla runs/compare-kitchen-4M/gla
    python -m experiments.records annotate [--check]

``record`` copies the method folder's config.json, results.md, summary.json, curves.png and tsne.png, every stage's
stage.json (``<stage>_stage.json``), the IFP's metrics.jsonl and the oracle's oracle.json, and writes
``provenance.json``: the command, the commit (``git rev-parse HEAD`` and whether the tree was dirty), the IFP env
steps per seed actually run, the seeds, and the note.

``restore`` turns a record back into a report-only run folder, so a comparison or study counts it as finished. runs/
is not committed, so a fresh checkout has none of the runs behind results/. A comparison's table (``compare.md``) and
a study's (``study.md``) cover every method or setting whose IFP stage finished in the folder with the same settings
(its recorded stage key); this writes what that check and the tables read, from the record ``record`` made:
``ifp/stage.json`` and ``ifp/ppo/metrics.jsonl``, ``summary.json``, ``config.json``, ``language.json``,
``results.md`` and the figures, and a ``RESTORED_FROM_RECORD`` marker naming the record. No parameters come back: a
restored method can be reported, not evaluated again or resumed, and the t-SNE figures leave it out (they need its
codes). Refuses to write into a folder that holds a run.

``annotate`` adds a ``recorded`` block to every recorded ``summary.json`` under ``results/`` that lacks the fields new
runs write (env, method, seeds, IFP env steps per seed, number of patterns, commit), so a reader or a script can tell
a number's budget without guessing from a folder name. Sources, in order: the summary's own fields; the folder's
``provenance.json``; its ``config.json`` (configured IFP budget, patterns); ``ifp_metrics.jsonl`` (env steps actually
run); otherwise the commit is null, with a note. ``--check`` exits non-zero if any summary lacks the fields (the
test suite runs it).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
from pathlib import Path

from experiments.cli import ArgumentParser, CommandError, check_outputs, checked, command, program
from talar_jax.report import RECORD_FILES

RESULTS = Path(__file__).resolve().parent.parent / "results"
"""The checkout's results/ folder (``annotate``'s default)."""
MARKER = "RESTORED_FROM_RECORD"
FIELDS = ("env", "method", "seeds", "ifp_env_steps_per_seed", "num_patterns", "commit")


def record(folder: Path, dest: Path, command: str, note: str = "") -> dict:
    """Copies the finished method folder ``folder``'s small outputs into ``dest``; returns its provenance record."""
    run_root = folder.parent
    if not (folder / "summary.json").is_file():
        raise ValueError(f"{folder} has no summary.json (not a finished method folder)")
    # before anything is written: the record's own files would make every tree look dirty
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain"], capture_output=True, text=True).stdout.strip())
    dest.mkdir(parents=True, exist_ok=True)
    for name in RECORD_FILES:
        if (folder / name).is_file():
            shutil.copy(folder / name, dest / name)
    for marker in sorted(run_root.glob("**/stage.json")):
        stage = marker.parent.relative_to(run_root).as_posix()
        if stage == "oracle" or stage.startswith(folder.name + "/") or stage == folder.name:
            shutil.copy(marker, dest / f"{stage.replace('/', '_')}_stage.json")
    metrics = folder / "ifp" / "ppo" / "metrics.jsonl"
    shutil.copy(metrics, dest / "ifp_metrics.jsonl")
    if (run_root / "oracle" / "oracle.json").is_file():
        shutil.copy(run_root / "oracle" / "oracle.json", dest / "oracle.json")
    rows = [json.loads(line) for line in metrics.read_text().splitlines()]
    config = json.loads((folder / "config.json").read_text())
    provenance = {
        "command": command,
        "commit": commit,
        "tree_dirty_when_recorded": dirty,
        "ifp_env_steps_per_seed": rows[-1]["train/env_steps"] if rows else 0,
        "ifp_env_steps_per_seed_planned": config["ifp"]["total_env_steps"],
        "seeds": config["seeds"],
        "note": note,
    }
    (dest / "provenance.json").write_text(json.dumps(provenance, indent=2) + "\n")
    return provenance


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


def missing(summary: dict) -> list[str]:
    """The provenance fields a summary (or its ``recorded`` block) lacks."""
    recorded = {**summary, **summary.get("recorded", {})}
    return [field for field in FIELDS if field not in recorded]


def annotation(path: Path, summary: dict) -> dict:
    """The ``recorded`` block of one summary file."""
    folder = path.parent
    name = path.name.removesuffix("summary.json").rstrip("-")
    config = json.loads((folder / "config.json").read_text()) if (folder / "config.json").is_file() else {}
    provenance = json.loads((folder / "provenance.json").read_text()) if (folder / "provenance.json").is_file() else {}
    env = config.get("env") or next(e for e in ("clevr", "kitchen") if e in folder.name)
    method = summary.get("method") or config.get("method") or re.sub(r"-patterns\d+$", "", name) or "talar"
    patterns = re.search(r"patterns(\d+)", name)
    seeds = len(summary["final_success"]["train"]) if "final_success" in summary else provenance.get("seeds")
    steps, steps_note = provenance.get("ifp_env_steps_per_seed"), "run (provenance.json)"
    if steps is None and (folder / "ifp_metrics.jsonl").is_file():
        rows = [json.loads(line) for line in (folder / "ifp_metrics.jsonl").read_text().splitlines()]
        steps, steps_note = int([r for r in rows if "eval/train/success_per_seed" in r][-1]["train/env_steps"]), "run"
    if steps is None:
        steps = (config.get("ifp") or {}).get("total_env_steps")
        steps_note = "configured (the run stops at the first chunk boundary past it)"
    commit = provenance.get("commit")
    block = {
        "env": env,
        "method": method,
        "seeds": seeds,
        "ifp_env_steps_per_seed": steps,
        "ifp_env_steps_note": steps_note,
        "num_patterns": int(patterns.group(1)) if patterns else config.get("num_patterns"),
        "commit": commit,
    }
    if commit is None:
        block["commit_note"] = "not recorded at the time (before runs wrote their commit); see results/history.md"
    return block


def annotate(results: Path = RESULTS, check: bool = False) -> list[str]:
    """Adds the ``recorded`` block to every summary under ``results`` that lacks the fields (with ``check``, only
    lists them); returns one line per summary lacking them (empty unless ``check``)."""
    paths = sorted(p for p in results.glob("**/*summary.json") if "final_success" in json.loads(p.read_text()))
    lacking = []
    for path in paths:
        summary = json.loads(path.read_text())
        if not missing(summary):
            continue
        if check:
            lacking.append(f"{path.relative_to(results)}: {', '.join(missing(summary))}")
            continue
        summary["recorded"] = annotation(path, summary)
        path.write_text(json.dumps(summary, indent=2) + "\n")
        print(f"{path.relative_to(results)}: {summary['recorded']}")
    return lacking


def parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog=program(), description=__doc__)  # talar-records or python -m experiments.records
    commands = parser.add_subparsers(dest="subcommand", required=True)
    to_record = commands.add_parser("record", help="copy a finished method folder's outputs into results/<name>")
    to_record.add_argument("method_dir", type=Path, help="a finished method folder, e.g. runs/kitchen/talar")
    to_record.add_argument("dest", type=Path, help="results/<name>")
    to_record.add_argument("--command", required=True, help="the command that made the run")
    to_record.add_argument("--note", default="", help="machine and sharing notes")
    to_restore = commands.add_parser("restore", help="put a record back as a report-only run folder")
    to_restore.add_argument("record", type=Path, help="a folder `record` wrote, e.g. results/.../gla")
    to_restore.add_argument("dest", type=Path, help="the method folder to write, e.g. runs/compare-kitchen-4M/gla")
    to_annotate = commands.add_parser("annotate", help="state every recorded summary's budget")
    to_annotate.add_argument("--check", action="store_true", help="only report summaries without the fields")
    to_annotate.add_argument(
        "--results", type=Path, default=RESULTS, help="the results folder (default: the checkout's)"
    )
    return parser


def run_command(argv: list[str] | None = None) -> None:
    """``python -m experiments.records`` for Python callers; bad input raises ``experiments.cli.UsageError``."""
    args = parser().parse_args(argv)
    if args.subcommand in ("record", "restore"):
        check_outputs((args.dest, "DEST", "folder"))
    if args.subcommand == "record":
        provenance = checked(record, args.method_dir, args.dest, args.command, args.note)
        print(f"recorded {args.method_dir} -> {args.dest}: {json.dumps(provenance)}")
    elif args.subcommand == "restore":
        written = checked(restore, args.record, args.dest)
        print(f"restored {args.record} -> {args.dest}: {', '.join(written)}")
    else:
        lacking = annotate(args.results, args.check)
        if lacking:
            missing = "; ".join(lacking)
            raise CommandError(f"summaries without env/method/seeds/steps/patterns/commit: {missing}", 1)


main = command(run_command)

if __name__ == "__main__":
    raise SystemExit(main())
