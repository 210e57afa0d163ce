"""Adds a ``recorded`` block to every recorded ``summary.json`` under ``results/`` that lacks the fields new runs write
(env, method, seeds, IFP env steps per seed, number of patterns, commit), so a reader or a script can tell a number's
budget without guessing from a folder name. ``python scripts/annotate_results.py [--check]``

Sources, in order: the summary's own fields; the folder's ``provenance.json``; its ``config.json`` (configured IFP
budget, patterns); ``ifp_metrics.jsonl`` (env steps actually run); the commits results/README.md names for runs
recorded before provenance was written (``KNOWN_COMMITS``); otherwise the commit is null, with a note. ``--check``
exits non-zero if any summary lacks the fields (the test suite runs it).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent.parent / "results"
FIELDS = ("env", "method", "seeds", "ifp_env_steps_per_seed", "num_patterns", "commit")
KNOWN_COMMITS = {  # commits results/README.md gives for runs recorded before summary.json carried them
    "clevr-talar-5seeds-2M-final": "320a93b",
    "kitchen-talar-5seeds-600k-final": "320a93b",
    "kitchen-talar-5seeds-1200k": "1fd39c6",
    "clevr-talar-alltokens-5seeds-2M": "8b0276a",
    "kitchen-talar-5seeds-scripted-posture-partial": "eceee9d",
}
CONFIGURED_STEPS = {  # the IFP budget of folders without config.json (from the command in results/README.md)
    "clevr-compare-5seeds-400k": 400_000,
    "clevr-compare-t4-5seeds-246k": 245_760,
}


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
        steps = (config.get("ifp") or {}).get("total_env_steps") or CONFIGURED_STEPS.get(folder.name)
        steps_note = "configured (the run stops at the first chunk boundary past it)"
    commit = provenance.get("commit") or KNOWN_COMMITS.get(folder.name)
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
        block["commit_note"] = "not recorded at the time (before runs wrote their commit); see results/README.md"
    return block


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only report summaries without the fields")
    args = parser.parse_args()
    paths = sorted(p for p in RESULTS.glob("**/*summary.json") if "final_success" in json.loads(p.read_text()))
    lacking = []
    for path in paths:
        summary = json.loads(path.read_text())
        if not missing(summary):
            continue
        if args.check:
            lacking.append(f"{path.relative_to(RESULTS)}: {', '.join(missing(summary))}")
            continue
        summary["recorded"] = annotation(path, summary)
        path.write_text(json.dumps(summary, indent=2) + "\n")
        print(f"{path.relative_to(RESULTS)}: {summary['recorded']}")
    if lacking:
        sys.exit("summaries without env/method/seeds/steps/patterns/commit:\n" + "\n".join(lacking))


if __name__ == "__main__":
    main()
