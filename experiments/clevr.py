"""TALAR on CLEVR-Robot: ``python -m experiments.clevr --seeds 5`` (``--quick`` for a smoke run, ``--help``).

``run_command(argv)`` is the command for Python callers: it returns the run's summary (bad input raises
``experiments.cli.UsageError``).
"""

from functools import partial

from experiments.cli import command
from experiments.config import default_config
from experiments.pipeline import run_command as run_pipeline

DEFAULT = default_config("clevr")
run_command = partial(run_pipeline, "clevr")
main = command(run_command, resumes=True)

if __name__ == "__main__":
    raise SystemExit(main())
