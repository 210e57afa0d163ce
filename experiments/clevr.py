"""TALAR on CLEVR-Robot: ``python -m experiments.clevr --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from experiments.config import default_config
from experiments.pipeline import command

DEFAULT = default_config("clevr")
main = command("clevr")

if __name__ == "__main__":
    main()
