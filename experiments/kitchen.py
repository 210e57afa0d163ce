"""TALAR on FrankaKitchen: ``python -m experiments.kitchen --seeds 5`` (``--quick`` for a smoke run, ``--help``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import tyro

from experiments.pipeline import ExperimentConfig, run
from talar_jax.ppo import PPOConfig

DEFAULT = ExperimentConfig(
    env="kitchen",
    out=Path("runs/kitchen"),
    ifp=dataclasses.replace(PPOConfig(), eval_every_chunks=2, eval_episodes=80, total_env_steps=4_000_000),
)


def main(argv: list[str] | None = None) -> dict:
    return run(tyro.cli(ExperimentConfig, default=DEFAULT, args=argv, description=__doc__))


if __name__ == "__main__":
    main()
