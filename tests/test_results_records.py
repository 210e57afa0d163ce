"""Every recorded result states its budget: env, method, seeds, IFP env steps per seed, patterns and commit."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_recorded_summary_states_its_budget():
    check = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "annotate_results.py"), "--check"], capture_output=True, text=True
    )
    assert check.returncode == 0, check.stderr
    paths = [p for p in (ROOT / "results").glob("**/*summary.json") if "final_success" in json.loads(p.read_text())]
    assert len(paths) >= 10
    for path in paths:
        summary = json.loads(path.read_text())
        recorded = {**summary, **summary.get("recorded", {})}
        assert recorded["env"] in ("clevr", "kitchen") and recorded["seeds"] == len(summary["final_success"]["train"])
        assert recorded["ifp_env_steps_per_seed"] > 0, path
