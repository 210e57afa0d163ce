"""Gymnasium adapters: ``to_gymnasium`` (one ``gymnasium.Env``) and ``to_gymnasium_vector`` (a batch in one call).

The only module of ``envs`` that imports Gymnasium (``pip install -e .[gymnasium]``). Both adapters keep the env's
JAX ``State`` (attribute ``state``) and run jitted functions built once per adapter; observations, rewards and
infos come back as numpy values. ``terminated`` is the env's ``done`` (success or failure); ``truncated`` is the
time limit (``episode_length`` steps) reached without termination, as in ``envs.wrappers.EpisodeWrapper``.

The vector form steps every sub-env with one jitted call of ``jax.vmap(env.step)``, so with ``physics="c"`` the whole
batch goes to MuJoCo's C engine in one host call. It auto-resets in Gymnasium's *same-step* mode
(``AutoresetMode.SAME_STEP``): a sub-env whose episode ends returns the first observation of its next episode, and
the observation and metrics of the step that ended are in ``info["final_obs"]`` / ``info["final_info"]``.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.base import Env, State
from envs.goals import describe_valid_goals
from envs.registry import make

_NO_GOAL = -1  # "the env samples the goal" in the jitted reset's goal argument


def _build_env(name_or_env: str | Env, physics: str | None, options: dict[str, Any]) -> Env:
    """``envs.make(name, physics=physics, **options)``, or an already built ``Env`` as is (then without options)."""
    if isinstance(name_or_env, str):
        return make(name_or_env, physics=physics, **options)
    if not isinstance(name_or_env, Env):
        raise TypeError(f"expected an env name (see envs.ALL_ENVS) or an envs.Env, got {type(name_or_env).__name__}")
    if options:
        raise ValueError(
            f"option(s) {', '.join(map(repr, sorted(options)))} only apply when the env is built by name; "
            f"this {type(name_or_env).__name__} is already built (pass its name instead)"
        )
    return name_or_env


def _goal_arg(env: Env, goal: Any) -> int:
    """The goal id of one id or goal name (``env.goal_id``), or ``_NO_GOAL`` for None."""
    if goal is None:
        return _NO_GOAL
    if not isinstance(goal, str) and np.ndim(goal) != 0:  # env.goal_id takes arrays of ids; an episode has one goal
        valid = describe_valid_goals(env.goal_names, env.num_goals)
        raise ValueError(f"goal {goal!r} for {type(env).__name__} is not a single goal; give {valid}")
    return int(env.goal_id(goal))


def _check_episode_length(env: Env, episode_length: int | None) -> int:
    length = env.episode_length if episode_length is None else episode_length
    if isinstance(length, bool) or not isinstance(length, numbers.Integral) or length < 1:
        raise ValueError(f"episode_length must be an int >= 1, got {episode_length!r}")
    return int(length)


def _pop_goal(options: dict[str, Any] | None, default: Any) -> Any:
    """The ``goal`` of ``reset``'s options (``default`` when absent); any other option is an error."""
    options = dict(options or {})
    goal = options.pop("goal", default)
    if options:
        raise ValueError(f"unknown reset option(s) {', '.join(map(repr, sorted(options)))}; the only one is 'goal'")
    return goal


def _spaces(env: Env) -> tuple[spaces.Box, spaces.Space]:
    """(observation space, action space) of one env."""
    spec = env.action_spec
    if spec.kind == "discrete":
        action_space = spaces.Discrete(spec.size)
    else:
        action_space = spaces.Box(spec.low, spec.high, (spec.size,), np.float32)
    return spaces.Box(-np.inf, np.inf, (env.observation_size,), np.float32), action_space


def _check_actions(space: spaces.Space, actions: Any, batch_shape: tuple[int, ...]) -> np.ndarray:
    """``actions`` as a numpy array of ``batch_shape`` members of ``space``, or a ValueError saying what is expected."""
    array = np.asarray(actions)
    if isinstance(space, spaces.Discrete):
        valid = array.shape == batch_shape and np.issubdtype(array.dtype, np.integer)
        valid = valid and bool(np.all((array >= 0) & (array < space.n)))
        expected, array = f"int(s) in [0, {space.n})", array.astype(np.int32) if valid else array
    else:
        shape = batch_shape + space.shape
        valid = array.shape == shape and (np.issubdtype(array.dtype, np.floating) or array.dtype.kind in "iu")
        valid = valid and bool(np.all((array >= space.low) & (array <= space.high)))  # also rejects NaN
        expected = f"float(s) in [{space.low.min()}, {space.high.max()}] (clip them, e.g. gymnasium's ClipAction)"
        array = array.astype(np.float32) if valid else array
    if not valid:
        shown = " ".join(repr(actions).split())  # one line, shortened
        shown = shown if len(shown) <= 80 else shown[:77] + "..."
        raise ValueError(
            f"invalid action {shown} (dtype {array.dtype}, shape {array.shape}): "
            f"expected shape {batch_shape + space.shape} of {expected}"
        )
    return array


def _make_reset(env: Env):
    """(key, goal) -> (next key, State): ``env.reset`` with the goal id ``goal``, or a sampled goal for -1.

    Both ways are computed and one is selected, so a single trace serves fixed and sampled goals (a reset does
    no physics step: it is cheap next to ``step``).
    """

    def reset(key: jax.Array, goal: jax.Array) -> tuple[jax.Array, State]:
        key, sub = jax.random.split(key)
        sampled, fixed = env.reset(sub), env.reset(sub, jnp.maximum(goal, 0))
        return key, jax.tree.map(lambda a, b: jnp.where(goal >= 0, b, a), sampled, fixed)

    return reset


def _goal_of(state: State) -> jax.Array | None:
    """The episode's goal id (-1 for tasks without one), None for envs whose task has no ``goal``."""
    return getattr(state.task, "goal", None)


def _new_key(np_random: np.random.Generator) -> jax.Array:
    return jax.random.key(int(np_random.integers(2**32)))


class GymnasiumEnv(gym.Env):
    """One ``envs.Env`` as a ``gymnasium.Env`` (build it with ``to_gymnasium``).

    ``reset(seed=s)`` makes the episodes that follow deterministic; ``reset()`` continues from the adapter's key.
    ``reset(options={"goal": g})`` sets the goal of that episode, an id or a name (default: the adapter's ``goal``;
    None samples).
    ``info`` holds the env's metrics as floats (``"success"`` always) and ``"goal"``, the episode's goal id (-1 for
    tasks without one). ``state`` is the current JAX ``State``.
    """

    def __init__(
        self, env: Env, *, render_mode: str | None = None, goal: int | None = None, episode_length: int | None = None
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.jax_env = env
        self.goal = None if goal is None else _goal_arg(env, goal)
        self.episode_length = _check_episode_length(env, episode_length)
        self.render_mode = render_mode
        # One env step holds the control for substeps x timestep seconds (CLEVR 0.4 s, kitchen 0.08 s).
        step_seconds = env.mj_model.opt.timestep * getattr(env.config, "substeps", 1)
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": 1.0 / step_seconds}
        self.observation_space, self.action_space = _spaces(env)
        self._reset = jax.jit(_make_reset(env))
        self._step = jax.jit(env.step)
        self._key: jax.Array | None = None
        self._steps = 0
        self.state: State | None = None

    def _observe(self) -> tuple[np.ndarray, float, bool, dict[str, Any]]:
        obs, reward, done, metrics, goal = jax.device_get(
            (self.state.obs, self.state.reward, self.state.done, self.state.metrics, _goal_of(self.state))
        )
        info = {key: float(value) for key, value in metrics.items()}
        if goal is not None:
            info["goal"] = int(goal)
        return np.array(obs, np.float32), float(reward), bool(done > 0.5), info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Starts an episode; returns (observation, info)."""
        super().reset(seed=seed)
        goal = _goal_arg(self.jax_env, _pop_goal(options, self.goal))
        if seed is not None or self._key is None:
            self._key = _new_key(self.np_random)
        self._key, self.state = self._reset(self._key, jnp.int32(goal))
        self._steps = 0
        obs, _, _, info = self._observe()
        return obs, info

    def step(self, action: Any):
        """Applies ``action``; returns (observation, reward, terminated, truncated, info)."""
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        self.state = self._step(self.state, _check_actions(self.action_space, action, ()))
        self._steps += 1
        obs, reward, terminated, info = self._observe()
        return obs, reward, terminated, not terminated and self._steps >= self.episode_length, info

    def render(self) -> np.ndarray | None:
        """The current frame, (H, W, 3) uint8, with ``render_mode="rgb_array"`` (needs OpenGL: ``envs.render``)."""
        if self.render_mode is None:
            gym.logger.warn("render() does nothing without render_mode='rgb_array'")
            return None
        if self.state is None:
            raise RuntimeError("call reset() before render()")
        return self.jax_env.render(np.asarray(self.state.data.qpos)[None])[0]


class GymnasiumVectorEnv(VectorEnv):
    """``num_envs`` copies of an ``envs.Env`` as a ``gymnasium.vector.VectorEnv`` (build it with
    ``to_gymnasium_vector``), stepped by one jitted, vmapped call with same-step auto-reset.

    ``step`` returns, for each sub-env, the observation of its current episode: when a sub-env's episode ended at
    this step (``terminated | truncated``), a new one has already started and its ending observation is in
    ``info["final_obs"]`` (an object array, ``None`` for the others; mask ``info["_final_obs"]``).
    ``info`` holds the metrics of the step just taken (one array per metric, ``"success"`` always) and ``"goal"``,
    the goal id of each observation's episode; ``info["final_info"]`` holds the metrics and goal of the episodes
    that ended (masked like ``final_obs``). Every info key ``k`` comes with Gymnasium's mask ``"_k"``.

    ``reset(seed=s)`` makes the run deterministic; ``reset(options={"goal": g})`` sets the goal (an id or a name, or
    one per sub-env) of the episodes it starts and of the auto-resets after it (default: the adapter's ``goal``).
    """

    def __init__(self, env: Env, num_envs: int, *, goal: Any = None, episode_length: int | None = None):
        if isinstance(num_envs, bool) or not isinstance(num_envs, numbers.Integral) or num_envs < 1:
            raise ValueError(f"num_envs must be an int >= 1, got {num_envs!r}")
        self.jax_env = env
        self.num_envs = int(num_envs)
        self.goal = goal
        self._goals = self._goal_array(goal)
        self.episode_length = _check_episode_length(env, episode_length)
        self.metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
        self.single_observation_space, self.single_action_space = _spaces(env)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        reset = jax.vmap(_make_reset(env))
        length = self.episode_length

        def step(state: State, steps: jax.Array, keys: jax.Array, goals: jax.Array, actions: jax.Array):
            """The whole batch: one vmapped env step (one host call with the C backend), then auto-resets."""
            stepped = jax.vmap(env.step)(state, actions)
            steps = steps + 1
            terminated = stepped.done > 0.5
            truncated = ~terminated & (steps >= length)
            ended = terminated | truncated

            def reset_ended(keys: jax.Array) -> tuple[jax.Array, State]:
                keys, fresh = reset(keys, goals)
                where = lambda new, old: jnp.where(ended.reshape(ended.shape + (1,) * (new.ndim - 1)), new, old)
                return keys, jax.tree.map(where, fresh, stepped)

            # Resets cost about as much as a CLEVR step: run them only at steps where some episode ended.
            keys, state = jax.lax.cond(ended.any(), reset_ended, lambda keys: (keys, stepped), keys)
            outputs = (stepped.obs, stepped.reward, terminated, truncated, stepped.metrics, _goal_of(stepped))
            return state, jnp.where(ended, 0, steps), keys, outputs

        self._reset = jax.jit(reset)
        self._step = jax.jit(step)
        self._keys: jax.Array | None = None
        self._steps = jnp.zeros(self.num_envs, jnp.int32)
        self.state: State | None = None

    def _goal_array(self, goal: Any) -> jax.Array:
        """(num_envs,) int32 goal ids (-1: sampled) from None, an id, a name or a sequence of num_envs of those."""
        one = goal is None or isinstance(goal, str) or np.ndim(goal) == 0  # a name is a Sequence too
        goals = [goal] * self.num_envs if one else list(goal)
        if len(goals) != self.num_envs:
            raise ValueError(f"goal has {len(goals)} entries for {self.num_envs} sub-envs")
        return jnp.asarray([_goal_arg(self.jax_env, g) for g in goals], jnp.int32)

    def _info(self, metrics: dict[str, np.ndarray], goal: np.ndarray | None, mask: np.ndarray | None = None) -> dict:
        """Gymnasium's vector info: one array per key ``k`` and its mask ``_k`` (all True by default)."""
        info = {key: np.asarray(value) for key, value in metrics.items()}
        if goal is not None:
            info["goal"] = np.asarray(goal)
        mask = np.ones(self.num_envs, bool) if mask is None else mask
        return info | {f"_{key}": mask.copy() for key in info}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Starts an episode in every sub-env; returns (observations, info)."""
        super().reset(seed=seed)
        self._goals = self._goal_array(_pop_goal(options, self.goal))
        if seed is not None or self._keys is None:
            self._keys = jax.random.split(_new_key(self.np_random), self.num_envs)
        self._keys, self.state = self._reset(self._keys, self._goals)
        self._steps = jnp.zeros(self.num_envs, jnp.int32)
        obs, metrics, goal = jax.device_get((self.state.obs, self.state.metrics, _goal_of(self.state)))
        return np.array(obs, np.float32), self._info(metrics, goal)

    def step(self, actions: Any):
        """Steps every sub-env; returns (observations, rewards, terminations, truncations, info)."""
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        actions = _check_actions(self.single_action_space, actions, (self.num_envs,))
        self.state, self._steps, self._keys, outputs = self._step(
            self.state, self._steps, self._keys, self._goals, actions
        )
        (final_obs, reward, terminated, truncated, metrics, final_goal), obs, goal = jax.device_get(
            (outputs, self.state.obs, _goal_of(self.state))
        )
        info = self._info(metrics, goal)
        ended = terminated | truncated
        if ended.any():
            info["final_obs"] = np.full(self.num_envs, None, object)
            for i in np.flatnonzero(ended):
                info["final_obs"][i] = np.array(final_obs[i], np.float32)
            info["final_info"] = self._info(metrics, final_goal, ended)
            info["_final_obs"], info["_final_info"] = ended, ended.copy()
        return np.array(obs, np.float32), np.asarray(reward, np.float64), terminated, truncated, info


def to_gymnasium(
    name_or_env: str | Env,
    physics: str | None = None,
    *,
    render_mode: str | None = None,
    goal: int | str | None = None,
    episode_length: int | None = None,
    **options: Any,
) -> GymnasiumEnv:
    """A registered env (built with ``envs.make(name, physics=physics, **options)``) or a built ``envs.Env`` as a
    ``gymnasium.Env``.

    Args:
        name_or_env: one of ``envs.ALL_ENVS``, or an ``envs.Env`` (then ``physics`` is its own and ``options``
            must be empty).
        physics: ``"c"`` (MuJoCo's C engine, the fast choice on a CPU), ``"mjx"``, or None for
            ``envs.default_physics()`` (C where JAX has only a CPU, MJX on an accelerator), as ``envs.make``.
        render_mode: None or ``"rgb_array"`` (``render()`` returns the current frame).
        goal: the goal of every episode: an id in [0, env.num_goals) or a goal name (``env.goal_names``, e.g.
            ``"microwave"``); None samples one per episode.
        episode_length: steps before ``truncated`` (default: the env config's ``episode_length``).
        **options: fields of the env's config (``envs.get_default_config(name)``).
    """
    env = _build_env(name_or_env, physics, options)
    return GymnasiumEnv(env, render_mode=render_mode, goal=goal, episode_length=episode_length)


def to_gymnasium_vector(
    name_or_env: str | Env,
    num_envs: int,
    physics: str | None = None,
    *,
    goal: int | str | Sequence[int | str | None] | None = None,
    episode_length: int | None = None,
    **options: Any,
) -> GymnasiumVectorEnv:
    """``num_envs`` copies of an env as a ``gymnasium.vector.VectorEnv`` stepped by one jitted vmapped call, with
    same-step auto-reset (``metadata["autoreset_mode"] == AutoresetMode.SAME_STEP``; see ``GymnasiumVectorEnv``).

    Arguments as for ``to_gymnasium``; ``goal`` may also give one goal (or None) per sub-env.
    """
    env = _build_env(name_or_env, physics, options)
    return GymnasiumVectorEnv(env, num_envs, goal=goal, episode_length=episode_length)
