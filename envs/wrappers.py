"""Functional wrappers: episode time limit, auto-reset with a *fresh* task, vmap, and Brax training.

``AutoResetWrapper`` differs from Brax's on purpose: Brax restores the first state of the batch slot
(same goal forever), which is wrong for goal-conditioned tasks; here a finished episode is replaced by
a newly sampled one (new scene, new goal), drawing its key from ``info["rng"]``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from envs.base import Env, State


class Wrapper:
    """Delegates everything it does not override to the wrapped env."""

    def __init__(self, env: Env | Wrapper):
        self.env = env

    def reset(self, rng: jax.Array) -> State:
        return self.env.reset(rng)

    def step(self, state: State, action: jax.Array) -> State:
        return self.env.step(state, action)

    @property
    def unwrapped(self) -> Env:
        return self.env.unwrapped

    def __getattr__(self, name: str) -> Any:
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)


class EpisodeWrapper(Wrapper):
    """Ends an episode after ``episode_length`` steps.

    Adds ``info["steps"]`` and ``info["truncation"]`` (1.0 when the episode ended by the time limit and not
    by termination, so learners can bootstrap). ``done`` becomes 1.0 on termination or truncation.
    """

    def __init__(self, env: Env | Wrapper, episode_length: int | None = None, action_repeat: int = 1):
        super().__init__(env)
        self.episode_length = int(episode_length if episode_length is not None else env.episode_length)
        if self.episode_length < 1:
            raise ValueError(f"episode_length must be >= 1, got {self.episode_length}")
        self.action_repeat = int(action_repeat)
        if self.action_repeat < 1:
            raise ValueError(f"action_repeat must be >= 1, got {self.action_repeat}")

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        info = {**state.info, "steps": jnp.zeros((), jnp.int32), "truncation": jnp.zeros((), jnp.float32)}
        return state.replace(info=info)

    def step(self, state: State, action: jax.Array) -> State:
        reward = jnp.zeros((), jnp.float32)
        for _ in range(self.action_repeat):
            state = self.env.step(state, action)
            reward = reward + state.reward
        steps = state.info["steps"] + self.action_repeat
        timed_out = steps >= self.episode_length
        truncation = jnp.where(timed_out & (state.done < 0.5), 1.0, 0.0).astype(jnp.float32)
        done = jnp.where(timed_out, 1.0, state.done).astype(jnp.float32)
        info = {**state.info, "steps": steps, "truncation": truncation}
        return state.replace(reward=reward, done=done, info=info)


class AutoResetWrapper(Wrapper):
    """When a step ends an episode, the returned state already holds a freshly reset episode.

    ``reward``, ``done``, ``metrics`` and ``info["truncation"]`` still describe the step that ended.
    """

    def reset(self, rng: jax.Array) -> State:
        rng, rng_reset = jax.random.split(rng)
        state = self.env.reset(rng_reset)
        return state.replace(info={**state.info, "rng": rng})

    def step(self, state: State, action: jax.Array) -> State:
        if "steps" in state.info:  # a fresh episode must not inherit a stale step count
            state = state.replace(info={**state.info, "steps": jnp.where(state.done > 0.5, 0, state.info["steps"])})
        stepped = self.env.step(state, action)
        rng, rng_reset = jax.random.split(stepped.info["rng"])
        fresh = self.env.reset(rng_reset)
        done = stepped.done > 0.5

        def where_done(new, old):
            return jnp.where(done, new, old)

        keep = ("truncation", "rng")
        info = {
            key: (value if key in keep or key not in fresh.info else jax.tree.map(where_done, fresh.info[key], value))
            for key, value in stepped.info.items()
        }
        info["rng"] = rng
        return stepped.replace(
            data=jax.tree.map(where_done, fresh.data, stepped.data),
            obs=jax.tree.map(where_done, fresh.obs, stepped.obs),
            task=jax.tree.map(where_done, fresh.task, stepped.task),
            info=info,
        )


class VmapWrapper(Wrapper):
    """Batches reset/step over a leading axis of keys / states / actions."""

    def __init__(self, env: Env | Wrapper, batch_size: int | None = None):
        super().__init__(env)
        self.batch_size = batch_size

    def reset(self, rng: jax.Array) -> State:
        if self.batch_size is not None:
            rng = jax.random.split(rng, self.batch_size)
        return jax.vmap(self.env.reset)(rng)

    def step(self, state: State, action: jax.Array) -> State:
        return jax.vmap(self.env.step)(state, action)


def wrap_for_training(env: Env | Wrapper, episode_length: int | None = None, action_repeat: int = 1) -> Wrapper:
    """Time limit + auto-reset (unbatched: vmap it yourself, as ``talar_jax`` PPO does)."""
    return AutoResetWrapper(EpisodeWrapper(env, episode_length, action_repeat))


class BraxEpisodeMetricsWrapper(Wrapper):
    """Adds the ``info["episode_metrics"]`` / ``info["episode_done"]`` that brax's PPO/SAC training loops read.

    Sits outside ``AutoResetWrapper``: sums reward, length and every metric over the running episode, restarting
    after a step with ``done`` (like brax's own ``EpisodeWrapper``), so values at a done step cover that episode.
    """

    def __init__(self, env: Env | Wrapper, action_repeat: int = 1):
        super().__init__(env)
        self.action_repeat = action_repeat

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        zero = jnp.zeros((), jnp.float32)
        episode_metrics = {"sum_reward": zero, "length": zero, **{key: zero for key in state.metrics}}
        return state.replace(info={**state.info, "episode_metrics": episode_metrics, "episode_done": zero})

    def step(self, state: State, action: jax.Array) -> State:
        stepped = self.env.step(state, action)
        keep = 1.0 - state.info["episode_done"]
        previous = state.info["episode_metrics"]
        current = {"sum_reward": stepped.reward, "length": jnp.float32(self.action_repeat), **stepped.metrics}
        episode_metrics = {key: previous[key] * keep + current[key] for key in previous}
        info = {**stepped.info, "episode_metrics": episode_metrics, "episode_done": stepped.done}
        return stepped.replace(info=info)


def wrap_for_brax_training(
    env: Env | Wrapper,
    episode_length: int | None = None,
    action_repeat: int = 1,
    randomization_fn: Any = None,
) -> Wrapper:
    """Pass as ``brax.training.agents.ppo.train(..., wrap_env_fn=wrap_for_brax_training)``."""
    if randomization_fn is not None:
        raise NotImplementedError("domain randomisation is not supported by talar-jax envs")
    wrapped = BraxEpisodeMetricsWrapper(wrap_for_training(env, episode_length, action_repeat), action_repeat)
    return VmapWrapper(wrapped)
