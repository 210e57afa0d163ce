"""Acting: the conditioned auto-resetting env (instruction fixed per episode), rollouts and evaluation episodes."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from envs.base import State
from envs.wrappers import wrap_for_training
from talar_jax.conditioning import Conditioner, check_split
from talar_jax.types import EnvCarry, Transition

# policy_step(obs (N, obs), instruction (N,), rng) -> (action (N, ...), log_prob (N,), value (N,))
PolicyStep = Callable[[jax.Array, jax.Array, jax.Array], tuple[jax.Array, jax.Array, jax.Array]]


def goal_of(state: State) -> jax.Array:
    """The () int32 goal id of an env state (``state.task.goal``), with a clear error for envs without one."""
    goal = getattr(state.task, "goal", None)
    if goal is None:
        raise TypeError(f"the env's task ({type(state.task).__name__}) has no `goal` field; PPO needs goal ids")
    return jnp.asarray(goal, jnp.int32)


class ConditionedEnv:
    """Time limit + auto-reset env whose episodes each carry an instruction drawn from a conditioner.

    The instruction is sampled from the episode's goal at reset and re-sampled whenever an episode ends
    (the auto-reset wrapper has then already started the next episode with a fresh goal). Unbatched: vmap it.
    """

    def __init__(self, env: Any, conditioner: Conditioner, split: str = "train"):
        self.env = wrap_for_training(env)
        self.conditioner = conditioner
        self.split = check_split(split)

    def reset(self, rng: jax.Array) -> EnvCarry:
        rng_env, rng_instruction, rng_carry = jax.random.split(rng, 3)
        state = self.env.reset(rng_env)
        instruction = self.conditioner.sample(rng_instruction, goal_of(state), self.split)
        return EnvCarry(state=state, instruction=instruction, episode_return=jnp.zeros((), jnp.float32), rng=rng_carry)

    def step(self, carry: EnvCarry, action: jax.Array) -> tuple[EnvCarry, dict[str, jax.Array]]:
        """Steps one env; returns the new carry and the step's outcome (reward, termination, truncation, ...)."""
        state = self.env.step(carry.state, action)
        done = state.done > 0.5
        truncation = state.info["truncation"].astype(jnp.float32)
        episode_return = carry.episode_return + state.reward
        rng, rng_instruction = jax.random.split(carry.rng)
        fresh_instruction = self.conditioner.sample(rng_instruction, goal_of(state), self.split)
        new_carry = EnvCarry(
            state=state,
            instruction=jnp.where(done, fresh_instruction, carry.instruction),
            episode_return=jnp.where(done, 0.0, episode_return),
            rng=rng,
        )
        outcome = {
            "reward": state.reward.astype(jnp.float32),
            "termination": jnp.where(done, 1.0 - truncation, 0.0),
            "truncation": truncation,
            "success": state.metrics["success"].astype(jnp.float32),
            "episode_return": jnp.where(done, episode_return, 0.0),
        }
        return new_carry, outcome


def generate_unroll(
    env: ConditionedEnv, carry: EnvCarry, policy_step: PolicyStep, rng: jax.Array, length: int
) -> tuple[EnvCarry, Transition]:
    """Runs ``length`` steps of a (num_envs,)-batched carry.

    Returns:
        (final carry, time-major ``Transition`` with leaves (length, num_envs, ...)).
    """
    step_envs = jax.vmap(env.step)

    def one_step(carry: EnvCarry, rng_step: jax.Array) -> tuple[EnvCarry, Transition]:
        obs = carry.state.obs
        action, log_prob, value = policy_step(obs, carry.instruction, rng_step)
        new_carry, outcome = step_envs(carry, action)
        transition = Transition(
            obs=obs, instruction=carry.instruction, action=action, log_prob=log_prob, value=value, **outcome
        )
        return new_carry, transition

    return jax.lax.scan(one_step, carry, jax.random.split(rng, length))


def _record_step(record: dict[str, jax.Array], outcome: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """An evaluation's per-episode record after one more step: episodes still running count the step, and those
    that end on it keep their success and return."""
    running = record["finished"] < 0.5
    ends = running & (outcome["termination"] + outcome["truncation"] > 0.5)
    return {
        **record,
        "finished": jnp.where(ends, 1.0, record["finished"]),
        "success": jnp.where(ends, outcome["success"], record["success"]),
        "episode_return": jnp.where(ends, outcome["episode_return"], record["episode_return"]),
        "episode_length": record["episode_length"] + running.astype(jnp.float32),
    }


def evaluate_episodes(
    env: ConditionedEnv,
    act: Callable[[jax.Array, jax.Array, jax.Array], jax.Array],
    rng: jax.Array,
    num_episodes: int,
) -> dict[str, jax.Array]:
    """Plays one episode in each of ``num_episodes`` envs (fresh goals and instructions) and reports it.

    Args:
        env: the conditioned env (its split picks the instructions).
        act: act(obs (E, obs), instruction (E,), rng) -> action (E, ...).
        rng: PRNG key.
        num_episodes: number of parallel episodes E.

    Returns:
        dict of (E,) arrays: ``success`` (the env's success flag at the episode's end), ``goal``,
        ``instruction``, ``episode_return``, ``episode_length``.
    """
    rng_reset, rng_act = jax.random.split(rng)
    carry = jax.vmap(env.reset)(jax.random.split(rng_reset, num_episodes))
    zeros = jnp.zeros((num_episodes,), jnp.float32)
    first = {
        "goal": goal_of(carry.state),
        "instruction": carry.instruction,
        "finished": zeros,
        "success": zeros,
        "episode_return": zeros,
        "episode_length": zeros,
    }
    step_envs = jax.vmap(env.step)

    def one_step(loop: tuple[EnvCarry, dict[str, jax.Array]], rng_step: jax.Array):
        carry, record = loop
        new_carry, outcome = step_envs(carry, act(carry.state.obs, carry.instruction, rng_step))
        return (new_carry, _record_step(record, outcome)), None

    # A while loop, not a scan over the episode length: it stops once every episode has ended (under vmap, every
    # seed's), which on short successful episodes saves most of an evaluation. The per-step keys are the scan's, so
    # the records are the same.
    steps = int(env.env.episode_length)
    step_keys = jax.random.split(rng_act, steps)

    def running(loop: tuple[jax.Array, EnvCarry, dict[str, jax.Array]]) -> jax.Array:
        t, _, record = loop
        return (t < steps) & jnp.any(record["finished"] < 0.5)

    def body(loop: tuple[jax.Array, EnvCarry, dict[str, jax.Array]]):
        t, carry, record = loop
        (carry, record), _ = one_step((carry, record), step_keys[t])
        return t + 1, carry, record

    _, _, record = jax.lax.while_loop(running, body, (jnp.int32(0), carry, first))
    return record
