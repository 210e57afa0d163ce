"""TALAR on FrankaKitchen: ``python -m experiments.kitchen --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from typing import Any

from experiments.pipeline import command, default_config
from talar_jax import runtime

DEFAULT = default_config("kitchen")
_command = command("kitchen")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    runtime.start()
    return _command(argv)


if __name__ == "__main__":
    main()
