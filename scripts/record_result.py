"""Copy a finished run's small outputs into ``results/<name>/`` with where they came from.

``python scripts/record_result.py runs/kitchen/talar results/kitchen-talar-5seeds-4M --command "python -m ..."
[--note "machine, sharing, ..."]``

Copies the method folder's config.json, results.md, summary.json, curves.png and tsne.png, every stage's
stage.json (``<stage>_stage.json``), the IFP's metrics.jsonl and the oracle's oracle.json, and writes
``provenance.json``: the command, the commit (``git rev-parse HEAD`` and whether the tree was dirty), the IFP env
steps per seed actually run, the seeds, and the note.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

from talar_jax.report import RECORD_FILES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("method_dir", type=Path, help="a finished method folder, e.g. runs/kitchen/talar")
    parser.add_argument("dest", type=Path, help="results/<name>")
    parser.add_argument("--command", required=True, help="the command that made the run")
    parser.add_argument("--note", default="", help="machine and sharing notes")
    args = parser.parse_args()
    folder, run_root = args.method_dir, args.method_dir.parent
    if not (folder / "summary.json").is_file():
        sys.exit(f"error: {folder} has no summary.json (not a finished method folder)")
    # before anything is written: the record's own files would make every tree look dirty
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain"], capture_output=True, text=True).stdout.strip())
    args.dest.mkdir(parents=True, exist_ok=True)
    for name in RECORD_FILES:
        if (folder / name).is_file():
            shutil.copy(folder / name, args.dest / name)
    for marker in sorted(run_root.glob("**/stage.json")):
        stage = marker.parent.relative_to(run_root).as_posix()
        if stage == "oracle" or stage.startswith(folder.name + "/") or stage == folder.name:
            shutil.copy(marker, args.dest / f"{stage.replace('/', '_')}_stage.json")
    metrics = folder / "ifp" / "ppo" / "metrics.jsonl"
    shutil.copy(metrics, args.dest / "ifp_metrics.jsonl")
    if (run_root / "oracle" / "oracle.json").is_file():
        shutil.copy(run_root / "oracle" / "oracle.json", args.dest / "oracle.json")
    rows = [json.loads(line) for line in metrics.read_text().splitlines()]
    config = json.loads((folder / "config.json").read_text())
    provenance = {
        "command": args.command,
        "commit": commit,
        "tree_dirty_when_recorded": dirty,
        "ifp_env_steps_per_seed": rows[-1]["train/env_steps"] if rows else 0,
        "ifp_env_steps_per_seed_planned": config["ifp"]["total_env_steps"],
        "seeds": config["seeds"],
        "note": args.note,
    }
    (args.dest / "provenance.json").write_text(json.dumps(provenance, indent=2) + "\n")
    print(f"recorded {folder} -> {args.dest}: {json.dumps(provenance)}")


if __name__ == "__main__":
    main()
