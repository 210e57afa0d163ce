"""A damaged or incomplete run folder gets one ``error:`` line naming the file and what rebuilds it, exit status 2,
and nothing written: through ``experiments.instruct`` and ``experiments.generalize`` (in the process and as
``python -m``) and through ``talar_jax.agent.load``. The run is a copy of the shipped kitchen agent."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from experiments import generalize, instruct
from talar_jax.agent import SHIPPED_AGENTS_DIR, SHIPPED_RECORD, AgentError, load
from talar_jax.checkpoint import load_tree

ROOT = Path(__file__).resolve().parent.parent
SENTENCE = "Open the microwave door"
SHIPPED = "restore the shipped agent 'kitchen'"
RERUN = "rerun the command that made the run (python -m experiments.kitchen"


def _copy(tmp_path: Path, shipped: bool = True) -> Path:
    """The shipped kitchen agent copied to ``<tmp>/kitchen/talar`` (the run root is returned); without its
    ``shipped.json`` it is an ordinary run folder of one seed."""
    run = tmp_path / "kitchen"
    shutil.copytree(SHIPPED_AGENTS_DIR / "kitchen" / "talar", run / "talar")
    if not shipped:
        (run / "talar" / SHIPPED_RECORD).unlink()
    return run


def _snapshot(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: max(path.stat().st_size // 2, 1)])


def _exit_status(main, argv) -> int:
    try:
        return main(argv)
    except SystemExit as stop:  # a command that exits instead of returning its status
        return stop.code


def _one_error_line(capsys, main, argv) -> str:
    status = _exit_status(main, argv)
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("error: "), (status, lines)
    return lines[0]


CASES = {
    # name: (file under the method folder, what is done to it, words of the rebuild hint)
    "translator params truncated": ("translator/params.msgpack", _truncate, SHIPPED),
    "policy params truncated": ("ifp/ppo/policy.msgpack", _truncate, SHIPPED),
    "config truncated": ("config.json", _truncate, SHIPPED),
    "config not text": ("config.json", lambda p: p.write_bytes(b"\xff\xfe\x00garbage"), SHIPPED),
    "language record truncated": ("language.json", _truncate, SHIPPED),
    "encoding record truncated": ("encoding.json", _truncate, SHIPPED),
    "calibration truncated": ("confidence.json", _truncate, "python -m experiments.calibrate"),
    "translator params missing": ("translator/params.msgpack", Path.unlink, SHIPPED),
    "policy params missing": ("ifp/ppo/policy.msgpack", Path.unlink, SHIPPED),
    "config missing": ("config.json", Path.unlink, SHIPPED),
}


@pytest.mark.parametrize("case", list(CASES))
def test_instruct_names_the_damaged_file_and_what_rebuilds_it(case, tmp_path, capsys):
    name, damage, hint = CASES[case]
    run = _copy(tmp_path)
    damage(run / "talar" / name)
    before = _snapshot(run)
    line = _one_error_line(capsys, instruct.main, [str(run), SENTENCE])
    assert str(run / "talar" / name) in line and hint in line, line
    assert _snapshot(run) == before


def test_a_run_folder_is_rebuilt_by_removing_the_stage_and_rerunning_its_command(tmp_path, capsys):
    run = _copy(tmp_path, shipped=False)
    _truncate(run / "talar" / "translator" / "params.msgpack")
    before = _snapshot(run)
    line = _one_error_line(capsys, instruct.main, [str(run), SENTENCE])
    assert f"{run / 'talar' / 'translator' / 'params.msgpack'} is damaged" in line
    assert f"remove {run / 'talar' / 'translator'} and {RERUN} --out {run}" in line, line
    with pytest.raises(AgentError, match="params.msgpack is damaged") as error:
        load(run)
    assert "\n" not in str(error.value)
    mine = tmp_path / "mine.json"
    mine.write_text('{"kitchen": {"microwave": ["Open the microwave door"]}}')
    line = _one_error_line(capsys, generalize.main, [str(run), "--instructions", str(mine)])
    assert "params.msgpack is damaged" in line
    assert _snapshot(run) == before


@pytest.mark.parametrize(("name", "problem"), [("config.json", "is damaged"), ("encoding.json", "is not valid JSON")])
def test_generalize_names_a_truncated_record(name, problem, tmp_path, capsys):
    run = _copy(tmp_path, shipped=False)
    _truncate(run / "talar" / name)
    mine = tmp_path / "mine.json"
    mine.write_text('{"kitchen": {"microwave": ["Open the microwave door"]}}')
    before = _snapshot(run)
    line = _one_error_line(capsys, generalize.main, [str(run), "--instructions", str(mine)])
    assert f"{run / 'talar' / name} {problem}" in line, line
    assert "rerun the command that made the run (python -m experiments." in line, line
    assert _snapshot(run) == before


def _orbax_run(tmp_path: Path) -> Path:
    """The agent copy with its policy as an orbax checkpoint (as a trained run keeps it), not a shipped file."""
    import orbax.checkpoint as ocp

    run = _copy(tmp_path, shipped=False)
    ppo = run / "talar" / "ifp" / "ppo"
    policy = load_tree(ppo / "policy.msgpack")
    (ppo / "policy.msgpack").unlink()
    with ocp.CheckpointManager((ppo / "checkpoints").absolute()) as manager:
        manager.save(7, args=ocp.args.StandardSave({"params": policy}))
        manager.wait_until_finished()
    return run


def test_a_truncated_policy_checkpoint_is_one_line_from_the_command_line_act_anyway_too(tmp_path):
    run = _orbax_run(tmp_path)
    checkpoints = run / "talar" / "ifp" / "ppo" / "checkpoints"
    largest = max((p for p in checkpoints.rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
    _truncate(largest)  # the array data: the restore fails with orbax's OUT_OF_RANGE
    before = _snapshot(run)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for extra in ([], ["--act-anyway"]):
        done = subprocess.run(
            [sys.executable, "-m", "experiments.instruct", str(run), SENTENCE, *extra],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=900,
        )
        errors = [line for line in done.stderr.splitlines() if line.strip()]
        assert done.returncode == 2 and len(errors) == 1, (done.returncode, done.stderr[-3000:])
        assert errors[0].startswith(f"error: the policy checkpoint in {checkpoints} is damaged"), errors
        assert f"remove {run / 'talar' / 'ifp'} and {RERUN}" in errors[0]
    assert _snapshot(run) == before


def test_a_truncated_translator_is_one_line_from_the_command_line(tmp_path):
    run = _copy(tmp_path)
    _truncate(run / "talar" / "translator" / "params.msgpack")
    before = _snapshot(run)
    done = subprocess.run(
        [sys.executable, "-m", "experiments.instruct", str(run), SENTENCE],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=900,
    )
    errors = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(errors) == 1, (done.returncode, done.stderr[-3000:])
    assert errors[0].startswith(f"error: {run / 'talar' / 'translator' / 'params.msgpack'} is damaged")
    assert SHIPPED in errors[0] and done.stdout == ""
    assert _snapshot(run) == before


def test_a_failed_restore_leaves_no_late_reports_but_others_pass(caplog):
    """The reads still in flight after a damaged checkpoint's restore fails report late, at random (a callback into
    the closed event loop, a failed future nobody reads); those two reports are dropped, nothing else is."""
    import asyncio
    import gc
    import logging
    import sys

    from talar_jax import agent

    agent._quiet_failed_restore()
    seen = []
    previous = sys.unraisablehook
    try:
        sys.unraisablehook = lambda unraisable: seen.append(str(unraisable.exc_value))
        agent._quiet_failed_restore()  # the project's hook wraps this recorder
        hook = sys.unraisablehook
        for message in ("Event loop is closed", "something else"):
            hook(type("Unraisable", (), {"exc_value": RuntimeError(message)})())
    finally:
        sys.unraisablehook = previous
    assert seen == ["something else"]
    loop = asyncio.new_event_loop()
    with caplog.at_level(logging.ERROR, logger="asyncio"):
        future = loop.create_future()
        future.set_exception(ValueError("Requested byte range is not valid"))
        del future
        gc.collect()
        logging.getLogger("asyncio").error("another asyncio error")
    loop.close()
    messages = [record.getMessage() for record in caplog.records]
    assert not any("never retrieved" in m for m in messages) and "another asyncio error" in messages
