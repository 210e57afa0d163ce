"""Typed carries of the PPO loop: the conditioned env carry, one transition, the reward normaliser, the learner."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
from flax import struct

from envs.base import State


@struct.dataclass
class EnvCarry:
    """One env slot of the conditioned env: its state and the instruction fixed for the current episode.

    Attributes:
        state: the wrapped env's ``State`` (time limit + auto-reset applied).
        instruction: () int32 instruction id sampled at reset; -1 when the goal has no instruction in the split.
        episode_return: () float32 raw return accumulated since the episode started.
        rng: (2,) uint32 key for re-sampling the instruction when the episode auto-resets.
    """

    state: State
    instruction: jax.Array
    episode_return: jax.Array
    rng: jax.Array


class Transition(NamedTuple):
    """One env step seen by the learner (time-major ``(T, num_envs, ...)`` once unrolled).

    Attributes:
        obs: (obs,) observation the action was taken in.
        instruction: () int32 instruction id (the conditioning vector is recomputed from it in the loss).
        action: () int32 (discrete) or (action,) float32 (continuous, before the env's clipping).
        log_prob: () log-probability of ``action`` under the acting policy.
        value: () value estimate of ``obs``.
        reward: () raw env reward.
        termination: () 1.0 when the episode terminated at this step (no bootstrap).
        truncation: () 1.0 when the episode hit its time limit at this step (not a termination).
        success: () the env's ``metrics["success"]`` after the step.
        episode_return: () raw return of the episode that ended at this step, 0 otherwise.
    """

    obs: jax.Array
    instruction: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    termination: jax.Array
    truncation: jax.Array
    success: jax.Array
    episode_return: jax.Array

    @property
    def episode_done(self) -> jax.Array:
        """1.0 where an episode ended (terminated or truncated) at this step."""
        return self.termination + self.truncation - self.termination * self.truncation


@struct.dataclass
class ReturnNormalizerState:
    """SB3 ``VecNormalize`` reward statistics: running variance of the discounted return (rewards only).

    Attributes:
        returns: (num_envs,) discounted return accumulated since each env's episode start.
        mean: () running mean of ``returns``.
        var: () running (population) variance of ``returns``.
        count: () number of samples seen (starts at 1e-4, as SB3's ``RunningMeanStd``).
    """

    returns: jax.Array
    mean: jax.Array
    var: jax.Array
    count: jax.Array


@struct.dataclass
class TrainingState:
    """Everything one seed's PPO run carries between updates (checkpointed as one pytree).

    Attributes:
        params: ``{"policy": ..., "value": ..., "conditioner": ...}`` plain pytrees of parameters.
        opt_state: optax state of ``params``.
        normalizer: reward normaliser statistics.
        env: (num_envs,)-batched ``EnvCarry``.
        rng: (2,) uint32 key of the learner.
        env_steps: () int32 env steps taken so far.
        updates: () int32 PPO updates done so far.
    """

    params: dict[str, Any]
    opt_state: Any
    normalizer: ReturnNormalizerState
    env: EnvCarry
    rng: jax.Array
    env_steps: jax.Array
    updates: jax.Array
