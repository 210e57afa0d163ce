"""A tiny goal-conditioned point env (no physics) with discrete or continuous actions, for PPO tests.

It also stands for a third env package: beside the env it describes how its instructions are read
(``INSTRUCTION_FORMAT``, its sentences in ``tests/data/point_instructions.json``) and ``register`` does what an env
package's ``__init__`` does, importing only ``envs``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs.base import ActionSpec, Env, EnvConfig, State
from envs.instructions import InstructionFormat, SentencesByGoal, register_instruction_format, section, string_list
from envs.physics import PhysicsState
from envs.registry import register_environment

GOALS = np.array([[0.5, 0.5], [-0.5, 0.5], [-0.5, -0.5], [0.5, -0.5]], np.float32)  # (4, 2)
MOVES = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], np.float32)  # (5, 2) discrete actions
STEP = 0.1
SUCCESS_RADIUS = 0.12


@dataclasses.dataclass(frozen=True)
class PointConfig(EnvConfig):
    """Point env options."""

    episode_length: int = 20
    """Steps before truncation."""
    continuous: bool = False
    """Continuous 2-D velocity actions in [-1, 1] instead of 5 discrete moves."""


@struct.dataclass
class PointTask:
    goal: jax.Array  # () int32 index into GOALS


class PointEnv(Env):
    """Move a point from near the origin to one of four corners; the goal is not in the observation.

    | obs index | meaning |
    |---|---|
    | 0, 1 | position (x, y) |

    Reward: 10 x the decrease of the distance to the goal, +1 on success (distance < 0.12), which terminates.
    """

    config_class = PointConfig
    xml_path = Path(__file__)  # no MJCF: the file defining the env is what results made on it depend on

    def __init__(self, config: PointConfig | None = None, physics: str = "none"):
        self.config = config if config is not None else PointConfig()
        self.physics = None

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec("continuous", 2) if self.config.continuous else ActionSpec("discrete", len(MOVES))

    @property
    def num_goals(self) -> int:
        return len(GOALS)

    @property
    def state_observation_size(self) -> int:
        return 2

    def reset(self, rng: jax.Array) -> State:
        rng_goal, rng_pos = jax.random.split(rng)
        goal = jax.random.randint(rng_goal, (), 0, len(GOALS)).astype(jnp.int32)
        pos = jax.random.uniform(rng_pos, (2,), minval=-0.1, maxval=0.1)
        zero = jnp.zeros((), jnp.float32)
        data = PhysicsState(qpos=pos, qvel=jnp.zeros(2), time=zero)
        return State(data=data, obs=pos, reward=zero, done=zero, metrics={"success": zero}, task=PointTask(goal))

    def step(self, state: State, action: jax.Array) -> State:
        action = self.check_action(action)
        delta = action if self.config.continuous else jnp.asarray(MOVES)[action]
        target = jnp.asarray(GOALS)[state.task.goal]
        pos = jnp.clip(state.data.qpos + STEP * delta, -1.0, 1.0)
        before, after = jnp.linalg.norm(state.data.qpos - target), jnp.linalg.norm(pos - target)
        success = (after < SUCCESS_RADIUS).astype(jnp.float32)
        data = state.data.replace(qpos=pos, time=state.data.time + 1.0)
        return state.replace(
            data=data, obs=pos, reward=10.0 * (before - after) + success, done=success, metrics={"success": success}
        )


INSTRUCTIONS_FILE = Path(__file__).parent / "data" / "point_instructions.json"


def read_sentences(data: dict, path: Path) -> dict[str, SentencesByGoal]:
    """``{"train": (sentences, goal ids), "test": ...}``: the ``point`` object lists one sentence per goal and split."""
    found = section(data, "point", path)
    out = {}
    for split in ("train", "test"):
        sentences = string_list(found.get(split), f"point.{split}", path)
        if len(sentences) != len(GOALS):
            raise ValueError(f"instruction file {path}: point.{split} must hold one sentence per goal ({len(GOALS)})")
        out[split] = (sentences, list(range(len(GOALS))))
    return out


INSTRUCTION_FORMAT = InstructionFormat(
    len(GOALS), read_sentences, aliases=("point-continuous",), default_file=INSTRUCTIONS_FILE
)


def register() -> None:
    """Registers ``point``, its variant ``point-continuous`` and their instructions, as an env package would."""
    register_environment("point", PointEnv)
    register_environment("point-continuous", PointEnv, continuous=True)
    register_instruction_format("point", INSTRUCTION_FORMAT)
