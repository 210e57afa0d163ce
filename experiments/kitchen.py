"""TALAR on FrankaKitchen: ``python -m experiments.kitchen --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from experiments.pipeline import env_command

DEFAULT, run_command, main = env_command("kitchen")

if __name__ == "__main__":
    raise SystemExit(main())
