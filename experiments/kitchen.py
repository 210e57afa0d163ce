"""TALAR on FrankaKitchen: ``python -m experiments.kitchen --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from experiments.config import default_config
from experiments.pipeline import command

DEFAULT = default_config("kitchen")
main = command("kitchen")

if __name__ == "__main__":
    main()
