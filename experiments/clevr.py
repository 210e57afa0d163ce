"""TALAR on CLEVR-Robot: ``python -m experiments.clevr --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from experiments.pipeline import env_command

DEFAULT, run_command, main = env_command("clevr")

if __name__ == "__main__":
    raise SystemExit(main())
