"""Cached pipeline stages: reuse on the same key, rerun on a changed key, rerun after an interruption."""

import json

import pytest

from talar_jax.stages import run_stage, stable_hash


def test_stage_reuse_rerun_and_interrupt(tmp_path):
    calls = []

    def body(stage_dir):
        calls.append(stage_dir)
        (stage_dir / "out.txt").write_text("x")
        return {"value": len(calls)}

    first = run_stage(tmp_path, "s", "k1", body, log=lambda _: None)
    again = run_stage(tmp_path, "s", "k1", body, log=lambda _: None)
    assert (first.reused, again.reused, len(calls)) == (False, True, 1)
    assert again.summary == {"value": 1}
    changed = run_stage(tmp_path, "s", "k2", body, log=lambda _: None)
    assert not changed.reused and len(calls) == 2

    def crashing(stage_dir):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_stage(tmp_path, "t", "k", crashing, log=lambda _: None)
    assert not (tmp_path / "t" / "stage.json").exists()  # an interrupted stage is never trusted
    assert json.loads((tmp_path / "t" / "pending.json").read_text())["key"] == "k"
    assert not run_stage(tmp_path, "t", "k", body, log=lambda _: None).reused


def test_stable_hash_depends_on_content_only():
    assert stable_hash({"a": 1, "b": (2, 3)}) == stable_hash({"b": [2, 3], "a": 1})
    assert stable_hash({"a": 1}) != stable_hash({"a": 2})


def test_provenance_names_the_commit_the_process_started_on(monkeypatch):
    """A run that outlives a checkout change (a commit made while it trains) still names the code it imported."""
    from talar_jax import provenance as provenance_module

    started = provenance_module.PROCESS_COMMIT
    assert started == provenance_module.git_commit()  # the checkout has not moved during the test
    monkeypatch.setattr(provenance_module, "git_commit", lambda folder=None: "0" * 40 + "-dirty")
    assert provenance_module.provenance()["commit"] == started
