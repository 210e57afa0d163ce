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
    """A run that outlives a checkout change (a commit made while it trains) still names the code it started with."""
    from talar_jax import provenance as provenance_module

    started = provenance_module.process_commit()
    assert started == provenance_module.git_commit()  # the checkout has not moved during the test
    monkeypatch.setattr(provenance_module, "git_commit", lambda folder=None: "0" * 40 + "-dirty")
    assert provenance_module.provenance()["commit"] == started


def test_a_finished_stage_with_the_same_key_is_copied_from_another_run(tmp_path):
    calls = []

    def body(stage_dir):
        calls.append(stage_dir)
        (stage_dir / "weights.txt").write_text(f"trained {len(calls)}")
        return {"value": len(calls)}

    quiet = {"log": lambda _: None}
    source, other, target = tmp_path / "source", tmp_path / "other", tmp_path / "target"
    run_stage(source, "talar/ifp", "k1", body, **quiet)
    run_stage(other, "talar/ifp", "k2", body, **quiet)
    (tmp_path / "unfinished" / "talar" / "ifp").mkdir(parents=True)  # a stage interrupted there: never copied
    (tmp_path / "unfinished" / "talar" / "ifp" / "pending.json").write_text(json.dumps({"key": "k1"}))
    folders = (tmp_path / "unfinished", other, source)
    copied = run_stage(target, "talar/ifp", "k1", body, reuse_from=folders, **quiet)
    assert (copied.reused, copied.summary, len(calls)) == (True, {"value": 1}, 2)
    assert (target / "talar" / "ifp" / "weights.txt").read_text() == "trained 1"
    assert not (target / "talar" / "ifp.copying").exists()
    again = run_stage(target, "talar/ifp", "k1", body, reuse_from=folders, **quiet)
    assert again.reused and len(calls) == 2
    fresh = run_stage(target, "talar/ifp", "k3", body, reuse_from=folders, **quiet)  # no run holds k3: it trains
    assert not fresh.reused and len(calls) == 3
    assert (source / "talar" / "ifp" / "weights.txt").read_text() == "trained 1"  # the source is left as it was
