"""Hierarchical RL with a frozen instruction-following policy (paper section 5.3, Appendix D.1.3).

A high-level policy picks a code every ``hold`` low-level steps; the frozen IFP acts on that code for ``hold`` steps
and the high-level reward is the sum of the low-level rewards (the number of goal configurations holding at each
step). What the high-level action is decides the method:

- TALAR: the action *is* a task-language code, N_pn binary predicate heads and N_a argument heads of ``arg_size``
  (``ActionSpec("multi_discrete")``, learned by PPO with ``FactorisedCategorical``);
- HAL ("aligned", Jiang et al. 2019): the action is the index of a training instruction, which the run's translator
  turns into the TL code the same IFP reads.

``HighLevelEnv`` has the env contract (``reset(rng) -> State``, ``step(state, action) -> State``, sizes), so this
project's PPO trains it unchanged with ``NoInstructionConditioner``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs.base import ActionSpec, State
from talar_jax.conditioning import Conditioner, check_split
from talar_jax.task_language import TaskLanguageSpec

# low_policy(obs (obs,), code (code,), rng) -> low-level action (one env; the frozen IFP)
LowPolicy = Callable[[jax.Array, jax.Array, jax.Array], jax.Array]


@struct.dataclass
class HighLevelTask:
    """Per-episode data of the high-level env: a single task (goal 0) and the key of the IFP's action noise."""

    goal: jax.Array  # () int32, always 0: the long-horizon task is one fixed task
    rng: jax.Array  # PRNG key for the low-level policy's sampling


def talar_action_spec(spec: TaskLanguageSpec) -> ActionSpec:
    """TALAR's high-level action space: N_pn two-way predicate heads, then N_a argument heads of ``arg_size``."""
    sizes = (2,) * spec.num_predicates + (spec.arg_size,) * spec.num_arguments
    return ActionSpec("multi_discrete", sum(sizes), sizes=sizes)


def task_language_code(spec: TaskLanguageSpec, action: jax.Array) -> jax.Array:
    """(N_pn + N_a,) head indices -> the (|L_T|,) TL code the IFP reads: predicate bits, then argument one-hots."""
    predicates = action[: spec.num_predicates].astype(jnp.float32)
    arguments = jax.nn.one_hot(action[spec.num_predicates :], spec.arg_size, dtype=jnp.float32)
    return jnp.concatenate([predicates, arguments.reshape(-1)])


class HighLevelEnv:
    """A long-horizon env seen through a frozen low-level policy held ``hold`` steps per high-level action.

    Args:
        low_env: the long-horizon env (``clevr-arrangement``, ``kitchen-all``), unwrapped; its own time limit is
            not applied: the high-level episode lasts ``episode_length`` high-level steps.
        low_policy: the frozen IFP, ``low_policy(obs, code, rng) -> action``.
        action_spec: the high-level action space.
        code_of_action: high-level action -> the code handed to ``low_policy``.
        hold: low-level steps per high-level action (the paper: 10).
        episode_length: high-level steps per episode.
    """

    def __init__(
        self,
        low_env: Any,
        low_policy: LowPolicy,
        action_spec: ActionSpec,
        code_of_action: Callable[[jax.Array], jax.Array],
        hold: int = 10,
        episode_length: int = 10,
    ):
        if hold < 1 or episode_length < 1:
            raise ValueError(f"hold and episode_length must be >= 1, got {hold} and {episode_length}")
        self.low_env = low_env
        self.low_policy = low_policy
        self.action_spec = action_spec
        self.code_of_action = code_of_action
        self.hold = int(hold)
        self.episode_length = int(episode_length)

    @property
    def observation_size(self) -> int:
        return self.low_env.observation_size

    @property
    def action_size(self) -> int:
        return self.action_spec.size

    @property
    def num_goals(self) -> int:
        return 1

    @property
    def backend(self) -> str | None:
        """The low-level env's physics (it decides how programs stepping this env compile)."""
        return getattr(getattr(self.low_env, "unwrapped", self.low_env), "backend", None)

    @property
    def unwrapped(self) -> HighLevelEnv:
        return self

    def reset(self, rng: jax.Array, goal: Any = None) -> State:
        del goal
        rng_env, rng_policy = jax.random.split(rng)
        low = self.low_env.reset(rng_env)
        zero = jnp.zeros((), jnp.float32)
        metrics = {"success": low.metrics["success"], "low_steps": zero}
        task = HighLevelTask(goal=jnp.zeros((), jnp.int32), rng=rng_policy)
        return State(data=low, obs=low.obs, reward=zero, done=zero, metrics=metrics, info={}, task=task)

    def step(self, state: State, action: jax.Array) -> State:
        """Holds ``code_of_action(action)`` for ``hold`` low-level steps (fewer if the low-level task ends)."""
        code = self.code_of_action(action)
        rng, rng_steps = jax.random.split(state.task.rng)

        def low_step(carry, rng_step):
            low, reward, steps = carry
            running = low.done < 0.5

            def advance(low):
                return self.low_env.step(low, self.low_policy(low.obs, code, rng_step))

            low = jax.lax.cond(running, advance, lambda low: low, low)
            reward = reward + jnp.where(running, low.reward, 0.0)
            return (low, reward, steps + running.astype(jnp.float32)), None

        init = (state.data, jnp.zeros((), jnp.float32), jnp.zeros((), jnp.float32))
        (low, reward, steps), _ = jax.lax.scan(low_step, init, jax.random.split(rng_steps, self.hold))
        metrics = {"success": low.metrics["success"], "low_steps": steps}
        return state.replace(
            data=low, obs=low.obs, reward=reward, done=low.done, metrics=metrics, task=state.task.replace(rng=rng)
        )


class NoInstructionConditioner(Conditioner):
    """For policies that read no instruction (the high-level policy, the flat baseline): a size-0 vector."""

    size = 0
    trainable = False

    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        del rng, goal
        check_split(split)
        return jnp.zeros((), jnp.int32)

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        del params, instruction
        return jnp.zeros((0,), jnp.float32)


class SingleTaskWrapper:
    """A long-horizon env as an env with one goal (id 0), so that goal-keyed evaluation treats it as one task; the
    flat baseline trains on it directly."""

    def __init__(self, env: Any):
        self.env = env

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    @property
    def num_goals(self) -> int:
        return 1

    @property
    def unwrapped(self) -> Any:
        return self.env

    def reset(self, rng: jax.Array, goal: Any = None) -> State:
        del goal
        state = self.env.reset(rng)
        return state.replace(task=state.task.replace(goal=jnp.zeros((), jnp.int32)))

    def step(self, state: State, action: jax.Array) -> State:
        return self.env.step(state, action)


def hal_code_table(codes: np.ndarray) -> tuple[ActionSpec, Callable[[jax.Array], jax.Array]]:
    """HAL's high-level action space over the (num_instructions, |L_T|) translated training instructions."""
    table = jnp.asarray(codes, jnp.float32)
    return ActionSpec("discrete", int(table.shape[0])), lambda action: table[action]
