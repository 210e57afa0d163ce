"""Every recorded result states its budget: env, method, seeds, IFP env steps per seed, patterns and commit."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_recorded_summary_states_its_budget():
    check = subprocess.run(
        [sys.executable, "-m", "experiments.records", "annotate", "--check"], capture_output=True, text=True, cwd=ROOT
    )
    assert check.returncode == 0, check.stderr
    paths = [p for p in (ROOT / "results").glob("**/*summary.json") if "final_success" in json.loads(p.read_text())]
    assert len(paths) >= 10
    for path in paths:
        summary = json.loads(path.read_text())
        recorded = {**summary, **summary.get("recorded", {})}
        assert recorded["env"] in ("clevr", "kitchen") and recorded["seeds"] == len(summary["final_success"]["train"])
        assert recorded["ifp_env_steps_per_seed"] > 0, path


def test_results_page_tables_are_well_formed():
    """Each markdown table row on the results page has its header's number of cells (a row pasted into the wrong
    table, e.g. a runs-table line among the paper items, fails here)."""
    header_cells = None
    for number, line in enumerate((ROOT / "results" / "README.md").read_text().splitlines(), 1):
        if not line.startswith("|"):
            header_cells = None
            continue
        cells = re.sub(r"`[^`]*`", "", line).count("|") - 1  # a "|" inside inline code is not a cell border
        if header_cells is None:
            header_cells = cells
        assert cells == header_cells, f"results/README.md:{number} has {cells} cells, its table {header_cells}"


HISTORY_IN_NAME = re.compile(r"session\d|recipe\d|\d{4}-\d\d-\d\d|fresh-clone|make-run|-alone|REDUCED|\d+seeds?-")


def test_results_holds_one_named_folder_per_item():
    """results/ has at most 15 top-level folders, each linked from the results page's folder table, and no folder at
    any depth is named for its history (a session, recipe number, date, budget or how it was run): a superseded run
    leaves the tree, and budget and seeds live in the record's README and metadata."""
    results = ROOT / "results"
    top = sorted(p.name for p in results.iterdir() if p.is_dir())
    assert len(top) <= 15, top
    page = (results / "README.md").read_text()
    assert [name for name in top if f"]({name}/)" not in page] == []
    named = [p.relative_to(results).as_posix() for p in results.glob("**/") if HISTORY_IN_NAME.search(p.name)]
    assert named == []
