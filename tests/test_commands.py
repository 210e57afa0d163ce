"""The ``talar-*`` console commands resolve to callables, and starting a command is what sets the process up:
importing the experiment modules changes nothing (no XLA flag, no JAX backend, no git call)."""

import os
import subprocess
import sys
import tomllib
from importlib import import_module
from pathlib import Path

from experiments import commands

ROOT = Path(__file__).resolve().parent.parent


def console_scripts() -> dict[str, str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


def test_every_console_script_resolves_to_a_callable_that_runs_a_main():
    scripts = console_scripts()
    assert set(scripts) == set(commands.COMMANDS)
    for name, target in scripts.items():
        module, _, attr = target.partition(":")
        assert callable(getattr(import_module(module), attr)), target
        assert callable(import_module(commands.COMMANDS[name]).main), name


def test_a_command_exits_0_unless_its_main_returns_a_status(monkeypatch):
    mains = {"summary": lambda argv=None: {"final": 1.0}, "status": lambda argv=None: 3, "none": lambda argv=None: None}
    monkeypatch.setattr(commands.importlib, "import_module", lambda name: type("M", (), {"main": mains[name]}))
    assert commands.run("summary") == 0 and commands.run("status") == 3 and commands.run("none") == 0


def test_importing_the_commands_sets_nothing_up():
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "MUJOCO_GL", "TF_CPP_MIN_LOG_LEVEL")}
    probe = (
        "import os, sys\n"
        "import jax._src.xla_bridge as xla_bridge\n"
        "from experiments import commands\n"
        "for module in commands.COMMANDS.values():\n"
        "    __import__(module)\n"
        "from talar_jax import provenance\n"
        "assert 'XLA_FLAGS' not in os.environ and 'MUJOCO_GL' not in os.environ, os.environ\n"
        "assert not xla_bridge._backends, 'a JAX backend started on import'\n"
        "assert provenance.process_commit.cache_info().currsize == 0, 'git ran on import'\n"
        "from talar_jax import runtime\n"
        "runtime.start(compile_cache=False)\n"
        "assert runtime.CPU_XLA_FLAG in os.environ['XLA_FLAGS'] and os.environ['MUJOCO_GL'] == 'egl'\n"
        "assert os.environ['TF_CPP_MIN_LOG_LEVEL'] == '2'\n"
        "from mujoco.rendering.classic import gl_context\n"
        "assert gl_context._MUJOCO_GL == 'egl'  # read again: the renderer takes EGL\n"
        "assert provenance.process_commit.cache_info().currsize == 1\n"
    )
    env.pop("DISPLAY", None)
    result = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
