"""TALAR on CLEVR-Robot: ``python -m experiments.clevr --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from __future__ import annotations

from typing import Any

from experiments.cli import command
from experiments.config import default_config
from experiments.pipeline import run_command as run_pipeline

DEFAULT = default_config("clevr")


def run_command(argv: list[str] | None = None) -> dict[str, Any]:
    """The command for Python callers: the run's summary (bad input raises ``experiments.cli.UsageError``)."""
    return run_pipeline("clevr", argv)


main = command(run_command, resumes=True)

if __name__ == "__main__":
    raise SystemExit(main())
