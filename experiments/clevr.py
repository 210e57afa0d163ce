"""TALAR on CLEVR-Robot: ``python -m experiments.clevr --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from experiments.pipeline import command

DEFAULT, main = command("clevr", total_env_steps=2_000_000)

if __name__ == "__main__":
    main()
