"""TALAR on FrankaKitchen: ``python -m experiments.kitchen --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from experiments.pipeline import command

DEFAULT, main = command("kitchen", total_env_steps=4_000_000)

if __name__ == "__main__":
    main()
