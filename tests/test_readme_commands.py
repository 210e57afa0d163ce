"""The README's shell commands work as written, in a fresh shell after ``make install``.

Each ``bash`` block after the set-up block runs in one new, clean shell (no inherited ``PATH`` from this process, no
activated venv), in the order a reader would type them. Shell-state lines (``source``, ``cd``, ``export``) run verbatim.
A command that trains for minutes or reads a run folder the reader has not made yet runs as ``COMMAND --help``: that
still proves the shell finds the program and its imports. The rest run verbatim.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
STATE_WORDS = ("source", "cd", "export")
# Commands that train (minutes to days): checked through --help.
TRAINING_MODULES = {
    "experiments.clevr",
    "experiments.kitchen",
    "experiments.paper",
    "experiments.compare",
    "experiments.patterns",
    "experiments.study",
    "experiments.hrl",
}


def shell_blocks(text: str) -> list[list[str]]:
    """The non-empty lines of every ```bash block, in order."""
    blocks = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    return [[line for line in block.splitlines() if line.strip()] for block in blocks]


def command_to_run(line: str) -> str:
    """What the fresh shell runs for one README line (see the module docstring)."""
    words = shlex.split(line, comments=True)
    if words[0] in STATE_WORDS:
        return line
    head = words[:3] if words[:2] == ["python", "-m"] else words[:1]
    module = words[2] if head != words[:1] else ""
    reads_a_run = any(word.startswith("runs/") for word in words)
    interactive = module == "experiments.instruct" and len(words) == 4  # no sentence: reads stdin
    if module in TRAINING_MODULES or reads_a_run or interactive:
        return shlex.join([*head, "--help"]) + " > /dev/null"
    return shlex.join(words)


def test_command_to_run_keeps_state_lines_and_checks_training_by_help():
    assert command_to_run("source .venv/bin/activate   # once") == "source .venv/bin/activate   # once"
    assert command_to_run("python -m experiments.kitchen --seeds 5   # Fig. 4") == (
        "python -m experiments.kitchen --help > /dev/null"
    )
    assert command_to_run('python -m experiments.instruct kitchen "Open it"') == (
        "python -m experiments.instruct kitchen 'Open it'"
    )
    assert command_to_run("python -m experiments.instruct kitchen") == (
        "python -m experiments.instruct --help > /dev/null"
    )
    assert command_to_run('python -m experiments.instruct runs/kitchen "x" --video m.gif').endswith(
        "--help > /dev/null"
    )


def test_the_readme_opens_with_the_two_make_commands():
    setup, *_ = shell_blocks(README.read_text())
    targets = [shlex.split(line, comments=True) for line in setup]
    assert targets == [["make", "run"], ["make", "test"]]
    for _, target in targets:
        done = subprocess.run(["make", "-n", target], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr


def test_the_readmes_commands_work_in_a_fresh_shell():
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("no .venv: `make install` makes the environment the README's commands run in")
    _, *blocks = shell_blocks(README.read_text())
    lines = [command_to_run(line) for block in blocks for line in block]
    assert lines[0].startswith("source .venv/bin/activate")  # the README activates before any other command
    script = "set -euo pipefail\n" + "\n".join(lines) + "\n"
    clean = {"HOME": os.environ.get("HOME", "/root"), "PATH": "/usr/local/bin:/usr/bin:/bin", "LANG": "C.UTF-8"}
    done = subprocess.run(
        ["bash", "--noprofile", "--norc", "-c", script],
        cwd=ROOT,
        env=clean,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert done.returncode == 0, f"{script}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    assert "understood" in done.stdout  # the verbatim instruct line answered


def test_the_license_is_an_spdx_expression():
    """setuptools (>= 77) warns at every install about a ``project.license`` table; a string is what it wants."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert isinstance(project["project"]["license"], str)
    assert any(re.fullmatch(r"setuptools>=(7[7-9]|[89]\d)(\.\d+)*", r) for r in project["build-system"]["requires"])
