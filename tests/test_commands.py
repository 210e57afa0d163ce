"""The ``talar-*`` console commands are the modules' ``main`` functions, which return the exit status (a summary goes
to Python callers through ``run_command``); starting a command is what sets the process up: importing the experiment
modules changes nothing (no XLA flag, no JAX backend, no git call)."""

import os
import subprocess
import sys
import tomllib
from importlib import import_module
from pathlib import Path

import pytest

from experiments.cli import CommandError, UsageError, command

ROOT = Path(__file__).resolve().parent.parent


def console_scripts() -> dict[str, str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


def test_every_console_script_is_the_main_of_its_python_m_module():
    for name, target in console_scripts().items():
        module, _, attr = target.partition(":")
        assert module == f"experiments.{name.removeprefix('talar-')}" and attr == "main", target
        assert callable(import_module(module).main) and callable(import_module(module).run_command), target


@pytest.mark.parametrize(
    ("outcome", "status", "stderr"),
    [
        ({"final": 1.0}, 0, ""),
        (None, 0, ""),
        (3, 3, ""),
        (UsageError("--seeds must be >= 1, got 0"), 2, "error: --seeds must be >= 1, got 0\n"),
        (CommandError("table3 stopped with status 1", 1), 1, "error: table3 stopped with status 1\n"),
        (KeyboardInterrupt(), 130, "stopped (Ctrl-C); run the same command again to resume\n"),
    ],
)
def test_main_returns_the_exit_status_and_prints_at_most_one_line(outcome, status, stderr, capsys):
    def run_command(argv):
        if isinstance(outcome, BaseException):
            raise outcome
        return outcome

    assert command(run_command, resumes=True)(["--x"]) == status
    printed = capsys.readouterr()
    assert printed.err == stderr and printed.out == ""


def test_importing_the_commands_sets_nothing_up():
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "MUJOCO_GL", "TF_CPP_MIN_LOG_LEVEL")}
    probe = (
        "import os, sys\n"
        "import jax\n"
        "import tomllib\n"
        "scripts = tomllib.loads(open('pyproject.toml').read())['project']['scripts']\n"
        "for target in scripts.values():\n"
        "    __import__(target.partition(':')[0])\n"
        "from talar_jax import provenance\n"
        "assert 'XLA_FLAGS' not in os.environ and 'MUJOCO_GL' not in os.environ, os.environ\n"
        "jax.config.update('jax_num_cpu_devices', 2)  # raises once a JAX backend has started\n"
        "assert provenance.process_commit.cache_info().currsize == 0, 'git ran on import'\n"
        "from talar_jax import runtime\n"
        "runtime.start(compile_cache=False)\n"
        "assert runtime.CPU_XLA_FLAG in os.environ['XLA_FLAGS'] and os.environ['MUJOCO_GL'] == 'egl'\n"
        "assert os.environ['TF_CPP_MIN_LOG_LEVEL'] == '2' and jax.config.jax_logging_level == 'ERROR'\n"
        "import logging\n"
        "jax_log = logging.getLogger('jax')\n"
        "assert jax_log.level == logging.NOTSET and not jax_log.handlers  # JAX's Python warnings show as before\n"
        "from mujoco.rendering.classic import gl_context\n"
        "assert gl_context.GLContext.__module__ == 'mujoco.egl'  # read again: the renderer takes EGL\n"
        "assert provenance.process_commit.cache_info().currsize == 1\n"
    )
    env.pop("DISPLAY", None)
    result = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
