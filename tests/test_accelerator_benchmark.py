"""``python -m benchmarks.accelerator``: its ``--quick`` run on the CPU (the code paths a GPU's full run takes, at
tiny sizes), its budget and out-of-memory handling, and its errors on bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import accelerator
from experiments.cli import exit_status

ROOT = Path(__file__).resolve().parent.parent
HEADER = {
    "device": "test device",
    "machine": {"jax_backend": "cpu"},
    "versions": {"jax": "0", "mujoco": "0"},
    "quick": True,
    "budget_s": 1.0,
}
ROW = {"section": "env steps", "env": "clevr", "physics": "mjx"}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """(results JSON, markdown table) of one ``--quick`` run in a subprocess, as a person would start it. Its budget
    is unlimited, so that a slow or busy machine skips nothing: what the budget skips is tested on its own below, with
    a budget that is spent before the first measurement, so no test here depends on the machine's speed."""
    out = tmp_path_factory.mktemp("accelerator")
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks.accelerator", "--quick", "--budget-s", "1e9", "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "measuring PPO chunk: kitchen, c physics" in done.stdout  # progress lines as it goes
    return json.loads((out / "accelerator.json").read_text()), (out / "accelerator.md").read_text()


def test_quick_run_measures_every_section_of_both_envs(quick_run):
    results, table = quick_run
    rows = results["rows"]
    assert [row for row in rows if row["status"] != "ok"] == []
    measured = {(row["section"], row["env"], row["physics"]) for row in rows}
    for env in ("clevr", "kitchen"):
        assert ("env steps", env, "mjx") in measured
        assert {("PPO chunk", env, "mjx"), ("PPO chunk", env, "c")} <= measured
        assert ("referential game", env, "-") in measured
        assert f"| PPO chunk | {env} | c |" in table
    assert all(row["steps_per_s"] > 0 and row["compile_s"] >= 0 for row in rows)
    assert results["device"] and results["device"] in table
    assert results["machine"]["jax_backend"] and results["machine"]["cpu_count"] >= 1


def test_a_section_past_its_share_of_the_budget_skips_and_says_why(tmp_path):
    runner = accelerator.Runner(1e-9, tmp_path, HEADER)
    runner.measure({**ROW, "size": "8 envs"}, "series", "label", lambda: pytest.fail("ran past the budget"))
    (row,) = json.loads((tmp_path / "accelerator.json").read_text())["rows"]
    assert row["status"] == "skipped" and "budget" in row["reason"]
    assert "skipped: wall-clock budget" in (tmp_path / "accelerator.md").read_text()


def measured() -> dict:
    return {"steps_per_s": 1.0, "compile_s": 0.0}


def test_out_of_memory_is_recorded_and_ends_the_larger_sizes_of_its_series(tmp_path):
    def allocate():
        raise RuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 80.00GiB.\nmore detail")

    runner = accelerator.Runner(600, tmp_path, HEADER)
    runner.measure({**ROW, "size": "4,096 envs"}, "clevr", "label", allocate)
    runner.measure({**ROW, "size": "16,384 envs"}, "clevr", "label", lambda: pytest.fail("a larger size ran"))
    runner.measure({**ROW, "env": "kitchen", "size": "4,096 envs"}, "kitchen", "label", measured)
    rows = json.loads((tmp_path / "accelerator.json").read_text())["rows"]
    assert [row["status"] for row in rows] == ["out_of_memory", "skipped", "ok"]
    assert "\n" not in rows[0]["reason"] and "out of memory" in rows[1]["reason"]


@pytest.mark.parametrize("args", [["--batches", "1024", "-8"], ["--seeds", "0"], ["--budget-s", "-1"]])
def test_bad_sizes_are_one_line_errors(args, capsys):
    assert exit_status(accelerator.main, args) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {args[0]} must")
