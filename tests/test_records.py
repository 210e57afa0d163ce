"""Results records (``experiments.records``): a finished run copied into a record and put back as a report-only
run folder."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from experiments import records
from experiments.compare import CompareArgs, base_config, finished_summaries
from experiments.config import default_config
from tests.conftest import TINY_BERT


def test_a_recorded_run_restored_into_a_fresh_folder_counts_as_finished(clevr_run, tmp_path, capsys):
    """``record`` then ``restore``: the comparison of a fresh checkout's folder reports the recorded method without
    rerunning it, and a folder holding a run is never overwritten."""
    out, summary = clevr_run
    root = Path(__file__).resolve().parent.parent
    record = tmp_path / "record"
    subprocess.run(
        [sys.executable, "-m", "experiments.records", "record", str(out / "talar"), str(record), "--command", "x"],
        check=True,
        capture_output=True,
        cwd=root,
    )
    fresh = tmp_path / "fresh"
    records.run_command(["restore", str(record), str(fresh / "talar")])
    experiment = default_config("clevr", seeds=2, out=fresh, quick=True, encoder=TINY_BERT, progress=False)
    restored = finished_summaries(base_config(CompareArgs(experiment=experiment, methods=("bert-binary",))))
    assert set(restored) == {"talar"} and restored["talar"]["final_success"] == summary["final_success"]
    assert records.main(["restore", str(record), str(out / "talar")]) == 2
    assert "holds a run" in capsys.readouterr().err


def test_record_restore_and_annotate_a_synthetic_run(tmp_path, capsys):
    """The three subcommands on a hand-made finished run (no training): what ``record`` copies and notes, what
    ``restore`` puts back, and the ``recorded`` block ``annotate`` adds to a summary without the budget fields."""
    run = tmp_path / "run"
    folder = run / "talar"
    (folder / "ifp" / "ppo").mkdir(parents=True)
    (run / "oracle").mkdir()
    (run / "oracle" / "stage.json").write_text('{"key": "o"}')
    (run / "oracle" / "oracle.json").write_text('{"success": 1.0}')
    (folder / "ifp" / "stage.json").write_text('{"key": "i"}')
    metrics = json.dumps({"train/env_steps": 512, "eval/train/success_per_seed": [0.5, 1.0]}) + "\n"
    (folder / "ifp" / "ppo" / "metrics.jsonl").write_text(metrics)
    config = {"env": "clevr", "method": "talar", "seeds": 2, "ifp": {"total_env_steps": 500}}
    (folder / "config.json").write_text(json.dumps(config))
    (folder / "summary.json").write_text(json.dumps({"final_success": {"train": [0.5, 1.0]}}))
    results = tmp_path / "results"
    dest = results / "clevr-talar"
    provenance = records.record(folder, dest, "python -m experiments.clevr", note="a note")
    assert provenance["ifp_env_steps_per_seed"] == 512 and provenance["ifp_env_steps_per_seed_planned"] == 500
    assert provenance["seeds"] == 2 and provenance["note"] == "a note"
    assert sorted(p.name for p in dest.iterdir()) == [
        "config.json",
        "ifp_metrics.jsonl",
        "oracle.json",
        "oracle_stage.json",
        "provenance.json",
        "summary.json",
        "talar_ifp_stage.json",
    ]
    assert records.main(["record", str(run), str(tmp_path / "elsewhere"), "--command", "x"]) == 2
    assert "has no summary.json" in capsys.readouterr().err

    back = tmp_path / "back" / "talar"
    assert records.restore(dest, back)[-3:] == ["ifp/stage.json", "ifp/ppo/metrics.jsonl", records.MARKER]
    assert (back / "ifp" / "ppo" / "metrics.jsonl").read_text() == metrics
    assert (back / "ifp" / "stage.json").read_text() == '{"key": "i"}'
    records.restore(dest, back)  # a restored folder may be restored again
    with pytest.raises(ValueError, match="not a recorded run"):
        records.restore(run, tmp_path / "other")

    fields = "env, method, seeds, ifp_env_steps_per_seed, num_patterns, commit"
    assert records.annotate(results, check=True) == [f"clevr-talar/summary.json: {fields}"]
    assert records.annotate(results) == []
    recorded = json.loads((dest / "summary.json").read_text())["recorded"]
    assert recorded["env"] == "clevr" and recorded["method"] == "talar" and recorded["seeds"] == 2
    assert recorded["ifp_env_steps_per_seed"] == 512 and recorded["commit"] == (provenance["commit"] or None)
    assert records.annotate(results, check=True) == []
