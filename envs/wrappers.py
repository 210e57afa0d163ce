"""Functional wrappers: episode time limit, auto-reset with a *fresh* task, vmap, and Brax training.

A wrapper is an ``Env``: every part of the env contract reads through to the wrapped env unless the wrapper changes
it, so code that takes an ``Env`` takes a wrapped one too. ``reset(rng, goal=None, **options)`` passes ``goal`` and
any other keyword on to the wrapped env.

``AutoResetWrapper`` differs from Brax's on purpose: Brax restores the first state of the batch slot
(same goal forever), which is wrong for goal-conditioned tasks; here a finished episode is replaced by
a newly sampled one (new scene, new goal), drawing its key from ``info["rng"]``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs.base import Env, State


def _read_through(name: str) -> property:
    return property(lambda self: getattr(self.env, name), doc=f"The wrapped env's ``{name}``.")


class Wrapper(Env):
    """An ``Env`` that delegates everything it does not override to the wrapped env.

    The members of the env contract are read through explicitly (properties below), because ``Env`` defines them:
    the class attribute would otherwise win over the wrapped env's value. Anything else an env has (its own helpers,
    ``config``, ``mj_model``, ``physics``) is reached through ``__getattr__``.
    """

    def __init__(self, env: Env):  # no Env.__init__: a wrapper builds no model and no physics of its own
        self.env = env

    def reset(self, rng: jax.Array, goal: jax.Array | int | str | None = None, **options: Any) -> State:
        return self._reset_wrapped(rng, goal, **options)

    def step(self, state: State, action: jax.Array) -> State:
        return self.env.step(state, action)

    def _reset_wrapped(self, rng: jax.Array, goal: Any = None, **options: Any) -> State:
        """The wrapped env's reset with ``goal`` and ``options``; ``goal`` is left out when None, so that an env whose
        ``reset`` takes only a key can be wrapped."""
        if goal is None:
            return self.env.reset(rng, **options)
        return self.env.reset(rng, goal, **options)

    config_class = _read_through("config_class")
    render_camera = _read_through("render_camera")
    load_model = _read_through("load_model")
    render = _read_through("render")
    action_spec = _read_through("action_spec")
    action_size = _read_through("action_size")
    check_action = _read_through("check_action")
    action_out_of_range = _read_through("action_out_of_range")
    num_goals = _read_through("num_goals")
    goal_names = _read_through("goal_names")
    goal_id = _read_through("goal_id")
    goal_out_of_range = _read_through("goal_out_of_range")
    retarget = _read_through("retarget")
    goal_feature_size = _read_through("goal_feature_size")
    goal_features = _read_through("goal_features")
    state_observation_size = _read_through("state_observation_size")
    agent_observation_size = _read_through("agent_observation_size")
    observation_size = _read_through("observation_size")
    observe_goal = _read_through("observe_goal")
    episode_length = _read_through("episode_length")

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

    def __init__(self, env: Env, episode_length: int | None = None, action_repeat: int = 1):
        super().__init__(env)
        self._episode_length = int(episode_length if episode_length is not None else env.episode_length)
        if self._episode_length < 1:
            raise ValueError(f"episode_length must be >= 1, got {self._episode_length}")
        self.action_repeat = int(action_repeat)
        if self.action_repeat < 1:
            raise ValueError(f"action_repeat must be >= 1, got {self.action_repeat}")

    @property
    def episode_length(self) -> int:
        """The time limit this wrapper applies (the wrapped env's own by default)."""
        return self._episode_length

    def reset(self, rng: jax.Array, goal: jax.Array | int | str | None = None, **options: Any) -> State:
        state = self._reset_wrapped(rng, goal, **options)
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

    def retarget(self, state: State, goal: jax.Array | int | str) -> State:
        """The wrapped env's ``retarget``; a new goal starts a new time limit (``steps`` back to 0)."""
        state = self.env.retarget(state, goal)
        info = {**state.info, "steps": jnp.zeros((), jnp.int32), "truncation": jnp.zeros((), jnp.float32)}
        return state.replace(info=info)


class AutoResetWrapper(Wrapper):
    """When a step ends an episode, the returned state already holds a freshly reset episode.

    ``reward``, ``done``, ``metrics`` and ``info["truncation"]`` still describe the step that ended. A ``goal``
    given to ``reset`` is the first episode's; the episodes that follow sample theirs.
    """

    def reset(self, rng: jax.Array, goal: jax.Array | int | str | None = None, **options: Any) -> State:
        rng, rng_reset = jax.random.split(rng)
        state = self._reset_wrapped(rng_reset, goal, **options)
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
    """Batches reset/step over a leading axis of keys / states / actions.

    ``reset``'s ``goal`` is one goal for the whole batch (an id or a name) or an array of one id per key; it is
    checked (``goal_id``) before the batch is traced, where it would have no value.
    """

    def __init__(self, env: Env, batch_size: int | None = None):
        super().__init__(env)
        self.batch_size = batch_size

    def reset(self, rng: jax.Array, goal: jax.Array | int | str | None = None, **options: Any) -> State:
        if self.batch_size is not None:
            rng = jax.random.split(rng, self.batch_size)
        goal = self.env.goal_id(goal)
        if goal is None or np.ndim(goal) == 0:
            return jax.vmap(lambda key: self._reset_wrapped(key, goal, **options))(rng)
        return jax.vmap(lambda key, one: self._reset_wrapped(key, one, **options))(rng, goal)

    def step(self, state: State, action: jax.Array) -> State:
        return jax.vmap(self.env.step)(state, action)


def wrap_for_training(env: Env, episode_length: int | None = None, action_repeat: int = 1) -> Wrapper:
    """Time limit + auto-reset (unbatched: vmap it yourself, as ``talar_jax`` PPO does)."""
    return AutoResetWrapper(EpisodeWrapper(env, episode_length, action_repeat))


class BraxEpisodeMetricsWrapper(Wrapper):
    """Adds the ``info["episode_metrics"]`` / ``info["episode_done"]`` that brax's PPO/SAC training loops read.

    Sits outside ``AutoResetWrapper``: sums reward, length and every metric over the running episode, restarting
    after a step with ``done`` (like brax's own ``EpisodeWrapper``), so values at a done step cover that episode.
    """

    def __init__(self, env: Env, action_repeat: int = 1):
        super().__init__(env)
        self.action_repeat = action_repeat

    def reset(self, rng: jax.Array, goal: jax.Array | int | str | None = None, **options: Any) -> State:
        state = self._reset_wrapped(rng, goal, **options)
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
    env: Env,
    episode_length: int | None = None,
    action_repeat: int = 1,
    randomization_fn: Any = None,
) -> Wrapper:
    """Pass as ``brax.training.agents.ppo.train(..., wrap_env_fn=wrap_for_brax_training)``."""
    if randomization_fn is not None:
        raise NotImplementedError("domain randomisation is not supported by talar-jax envs")
    wrapped = BraxEpisodeMetricsWrapper(wrap_for_training(env, episode_length, action_repeat), action_repeat)
    return VmapWrapper(wrapped)
