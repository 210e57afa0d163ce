"""The shared environment contract: ``State``, ``ActionSpec``, env configs and the ``Env`` base class.

Shaped like MuJoCo Playground / Brax: an env is an object holding constants only; ``reset(key) -> State``
and ``step(state, action) -> State`` are pure, jit- and vmap-able, and return new states (never mutate).
Episode time limits and auto-reset are wrappers (``envs.wrappers``), as in Brax.
"""

from __future__ import annotations

import abc
import dataclasses
import numbers
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar, Literal

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from envs.goals import describe_valid_goals, resolve_goal
from envs.physics import Physics, PhysicsState, default_physics, make_physics


@struct.dataclass
class State:
    """One environment state (a pytree; batch it with ``jax.vmap``).

    Attributes:
        data: physics state (``PhysicsState``: qpos, qvel, time), the same type for both physics engines.
        obs: observation, shape (observation_size,).
        reward: scalar float.
        done: scalar float, 1.0 when the episode *terminated* (success/failure). Time limits are the
            ``EpisodeWrapper``'s business and show up as ``info["truncation"]``.
        metrics: dict of scalar floats for logging (``metrics["success"]`` in every env).
        info: dict for wrapper plumbing (step count, truncation, rng); never task data.
        task: the env's typed task struct (goal id, objects, ...), fixed for an episode.
    """

    data: PhysicsState
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    metrics: dict[str, jax.Array] = struct.field(default_factory=dict)
    info: dict[str, Any] = struct.field(default_factory=dict)
    task: Any = None


@dataclasses.dataclass(frozen=True)
class ActionSpec:
    """What ``step`` accepts.

    ``discrete``: an integer in [0, size) or, for RL libraries that only emit continuous vectors
    (``brax.training.agents.ppo``), a float vector of ``size`` scores whose argmax is taken.
    ``continuous``: a float vector of ``size`` entries, clipped to [low, high].
    ``multi_discrete``: an int vector with one entry per head (``sizes``).
    """

    kind: Literal["discrete", "continuous", "multi_discrete"]
    size: int
    low: float = -1.0
    high: float = 1.0
    sizes: tuple[int, ...] = ()
    """``multi_discrete`` only: one integer per head, head i in [0, sizes[i]) (``size`` = sum(sizes), the number of
    logits; Gymnasium's MultiDiscrete). Used by policies whose action is a code, e.g. a task-language code."""

    def __post_init__(self):
        if self.kind == "multi_discrete" and (not self.sizes or self.size != sum(self.sizes)):
            raise ValueError(f"a multi_discrete ActionSpec needs sizes and size == sum(sizes), got {self}")


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Fields every env config has; env-specific configs subclass this (frozen dataclasses)."""

    episode_length: int = 50
    """Steps before the episode is truncated (applied by ``envs.wrappers.EpisodeWrapper``)."""
    goal_observation: bool = False
    """Append the episode's goal to the observation (``Env.goal_features``), so that a stock trainer that sees
    only ``state.obs`` can learn the goal task. Off by default: TALAR's policies read the goal from language.
    Envs with a single fixed task (``clevr-arrangement``, ``kitchen-all``) have no goal part."""


def check_choice(option: str, value: str, choices: Sequence[str]) -> None:
    """Raises ``ValueError`` naming ``option`` and its valid values unless ``value`` is one of ``choices`` (the envs'
    configs check their string options with it, so every such error reads alike)."""
    if value not in choices:
        raise ValueError(f"unknown {option} {value!r}; choose one of {', '.join(choices)}")


def replace_config(config: EnvConfig, overrides: dict[str, Any]) -> EnvConfig:
    """``dataclasses.replace`` with one clear error for unknown keys or wrongly typed values."""
    fields = {f.name: f for f in dataclasses.fields(config)}
    unknown = sorted(set(overrides) - set(fields))
    if unknown:
        raise ValueError(
            f"unknown option(s) {', '.join(map(repr, unknown))} for {type(config).__name__}; "
            f"valid options: {', '.join(sorted(fields))}"
        )
    for key, value in overrides.items():
        default = getattr(config, key)
        ok = isinstance(value, type(default)) or (isinstance(default, float) and isinstance(value, int))
        if isinstance(default, bool) != isinstance(value, bool) or not ok:
            raise TypeError(
                f"option {key!r} of {type(config).__name__} expects {type(default).__name__}, "
                f"got {value!r} ({type(value).__name__})"
            )
    return dataclasses.replace(config, **overrides)


class Env(abc.ABC):
    """Base class of every talar-jax environment.

    Subclasses set ``xml_path`` (the MJCF beside the env module) and ``config_class``, implement ``reset`` and
    ``step``, and override ``check_config`` when some option values cannot run. ``self`` holds constants only; all
    per-episode data lives in ``State``.
    """

    config_class: ClassVar[type[EnvConfig]] = EnvConfig
    xml_path: ClassVar[Path]
    render_camera: ClassVar[dict[str, Any]] = {
        "lookat": (0.0, 0.0, 0.0),
        "distance": 2.0,
        "azimuth": 90.0,
        "elevation": -45.0,
    }
    """Free camera of ``render`` (``lookat``, ``distance``, ``azimuth``, ``elevation``)."""

    def __init_subclass__(cls, **kwargs: Any):
        super().__init_subclass__(**kwargs)
        if "goal_names_of" in cls.__dict__:
            warnings.warn(
                f"{cls.__name__}.goal_names_of is deprecated: override the goal_names property instead",
                DeprecationWarning,
                stacklevel=2,
            )

    def __init__(self, config: EnvConfig | None = None, physics: str | None = None):
        """``physics``: ``"mjx"``, ``"c"``, or None for ``envs.default_physics()`` (C on a CPU, MJX on an
        accelerator)."""
        self.config = config if config is not None else self.config_class()
        if not isinstance(self.config, self.config_class):
            raise TypeError(f"{type(self).__name__} expects a {self.config_class.__name__}, got {type(self.config)}")
        self.check_config(self.config)
        self.mj_model = self.load_model()
        self.physics: Physics = make_physics(default_physics() if physics is None else physics, self.mj_model)

    def check_config(self, config: EnvConfig) -> None:
        """Raises ``ValueError`` for option values this env cannot run; called before the model is built (override
        it, with ``check_choice`` for string options, so that a bad value stops ``make`` with one clear line)."""

    def load_model(self) -> mujoco.MjModel:
        """Compiles the env's MJCF (override to edit the spec before compiling)."""
        return mujoco.MjModel.from_xml_path(str(self.xml_path))

    # --- the functional API -------------------------------------------------------------------------
    @abc.abstractmethod
    def reset(self, rng: jax.Array, goal: jax.Array | int | str | None = None) -> State:
        """Samples an initial state and a task (the task of goal ``goal`` when given, for envs with goal ids).

        ``goal`` is a goal id (an int or an integer array) or a goal name (``goal_names``). Implementations pass it
        through ``goal_id`` first: a concrete goal out of range raises ``ValueError``. A traced one (an argument of
        a ``jit``-ed or ``vmap``-ed reset) has no value while tracing; implementations return a state whose ``obs``
        and ``reward`` are NaN when it lies out of range (``goal_out_of_range`` and ``flag_out_of_range``).
        """

    @abc.abstractmethod
    def step(self, state: State, action: jax.Array) -> State:
        """Applies ``action`` and returns the next state (see ``check_action`` for what is checked where)."""

    def retarget(self, state: State, goal: jax.Array | int | str) -> State:
        """``state`` pursuing ``goal`` from now on, without a reset: the physics is untouched, the task's goal
        fields, the goal part of ``obs`` and the goal's metrics are those a reset into this very scene would give
        (``reward`` and ``done`` 0). Pure, jit- and vmap-able, like ``reset``; ``goal`` as ``reset`` takes it (a
        traced goal out of range gives NaN ``obs`` and ``reward``). Used to run a chain of goals in one episode.

        Envs without a goal choice (``clevr-arrangement``, ``kitchen-all``) and envs that do not implement it
        raise ``NotImplementedError``."""
        raise NotImplementedError(f"{type(self).__name__} cannot give a running episode a new goal (no retarget)")

    def render(self, qpos: np.ndarray, width: int = 320, height: int = 240) -> list[np.ndarray]:
        """(T, nq) physics positions (e.g. ``state.data.qpos`` along an episode) -> T RGB frames (uint8).

        Raises ``envs.render.RenderError`` when no OpenGL backend is available (see ``envs.render``).
        """
        from envs.render import render_frames

        return render_frames(
            self.mj_model, np.asarray(qpos).reshape(-1, self.mj_model.nq), self.render_camera, width, height
        )

    # --- sizes --------------------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def action_spec(self) -> ActionSpec: ...

    @property
    @abc.abstractmethod
    def num_goals(self) -> int: ...

    # --- goals --------------------------------------------------------------------------------------
    @property
    def goal_names(self) -> tuple[str, ...]:
        """The name of each goal id (``num_goals`` of them), or () when the env's goals have ids only: what
        ``goal_id``, ``reset`` and the Gymnasium adapters accept besides ids. Envs with names override it."""
        return type(self).goal_names_of(self.config)

    @classmethod
    def goal_names_of(cls, config: EnvConfig) -> tuple[str, ...]:
        """Deprecated: ``goal_names`` calls it for subclasses that still define it (with a warning at definition)."""
        return ()

    def goal_id(self, goal: jax.Array | int | str | None) -> jax.Array | int | None:
        """The goal id of ``goal``, checked when it has a value: the one way to turn what a person or a program
        gives as a goal into an id (``reset`` calls it).

        An int, a string of digits or a goal name (``goal_names``; case, spaces, ``_`` and ``-`` do not matter)
        becomes an int; a concrete integer array is returned as is once every entry lies in [0, num_goals); None
        stays None. Anything else raises one ``ValueError`` line naming the valid ids and names. A traced goal
        (inside ``jit``/``vmap``) is returned untouched: its value is unknown while tracing, so ``reset`` flags it
        in the state it returns instead (``goal_out_of_range``).
        """
        if goal is None or isinstance(goal, jax.core.Tracer):
            return goal
        where = type(self).__name__
        if isinstance(goal, str | numbers.Integral):
            return resolve_goal(goal, self.goal_names, self.num_goals, where)
        array = np.asarray(goal)
        if not np.issubdtype(array.dtype, np.integer):
            valid = describe_valid_goals(self.goal_names, self.num_goals)
            raise ValueError(f"goal of dtype {array.dtype} for {where} is not a goal id; give {valid}")
        outside = array[(array < 0) | (array >= self.num_goals)]
        if outside.size:
            resolve_goal(int(outside.flat[0]), self.goal_names, self.num_goals, where)  # raises the range error
        return goal

    def check_goal(self, goal: jax.Array | int | str | None) -> jax.Array | int | None:
        """Deprecated name of ``goal_id``."""
        warnings.warn("Env.check_goal is deprecated; use Env.goal_id", DeprecationWarning, stacklevel=2)
        return self.goal_id(goal)

    def goal_out_of_range(self, goal: jax.Array | int | None) -> jax.Array | None:
        """For a traced goal id, whether it lies outside [0, num_goals) (a traced bool); None for a goal with a
        value (``goal_id`` checked it) or no goal, so nothing is added to the compiled program then."""
        if not isinstance(goal, jax.core.Tracer):
            return None
        return (goal < 0) | (goal >= self.num_goals)

    @property
    @abc.abstractmethod
    def state_observation_size(self) -> int:
        """Size of the observation without the goal part (the env's own observation)."""

    @property
    def agent_observation_size(self) -> int:
        """How many leading entries of the env's observation describe the agent itself (a robot's joints) rather than
        the scene it acts on: 0 when the agent is not observed. What a task did to the scene is the change of the
        other entries."""
        return 0

    @property
    def goal_feature_size(self) -> int:
        """Size of ``goal_features`` (0 for envs without a goal choice)."""
        return 0

    def goal_features(self, task: Any) -> jax.Array:
        """The goal part of the observation, a float32 vector of ``goal_feature_size`` entries."""
        return jnp.zeros((0,), jnp.float32)

    @property
    def observation_size(self) -> int:
        """Size of ``state.obs``: the env's observation, plus the goal part when ``goal_observation`` is on."""
        goal = self.goal_feature_size if self.config.goal_observation else 0
        return self.state_observation_size + goal

    def observe_goal(self, obs: jax.Array, task: Any) -> jax.Array:
        """``obs`` with the goal part appended when ``goal_observation`` is on (subclasses call it last)."""
        if not self.config.goal_observation:
            return obs
        return jnp.concatenate([obs, self.goal_features(task).astype(obs.dtype)])

    @property
    def action_size(self) -> int:
        return self.action_spec.size

    @property
    def episode_length(self) -> int:
        return self.config.episode_length

    @property
    def backend(self) -> str:
        """Deprecated: the physics' name is ``env.physics.name``."""
        warnings.warn("Env.backend is deprecated; use env.physics.name", DeprecationWarning, stacklevel=2)
        return self.physics.name

    @property
    def unwrapped(self) -> Env:
        return self

    # --- helpers for subclasses ---------------------------------------------------------------------
    def check_action(self, action: jax.Array) -> jax.Array:
        """Validates an action's shape/dtype (and value, when concrete); returns it in canonical form.

        Discrete envs return an int32 scalar; continuous envs a float32 vector clipped to [low, high].
        Raises ``ValueError``/``TypeError`` with the expected form. A concrete discrete action out of range raises
        too. A traced one (an argument of a ``jit``-ed step) has no value while tracing: it is clipped into range
        here, and discrete envs flag it in the state ``step`` returns (``action_out_of_range``).
        """
        spec = self.action_spec
        action = jnp.asarray(action)
        if spec.kind == "discrete":
            if jnp.issubdtype(action.dtype, jnp.integer):
                if action.shape != ():
                    raise ValueError(f"a discrete action is a scalar int in [0, {spec.size}), got shape {action.shape}")
                if not isinstance(action, jax.core.Tracer):
                    value = int(action)
                    if not 0 <= value < spec.size:
                        raise ValueError(f"action {value} is out of range: valid actions are 0..{spec.size - 1}")
                return jnp.clip(action, 0, spec.size - 1).astype(jnp.int32)
            if action.shape != (spec.size,):
                raise ValueError(
                    f"a discrete action is a scalar int in [0, {spec.size}) or a float vector of {spec.size} scores; "
                    f"got dtype {action.dtype} shape {action.shape}"
                )
            return jnp.argmax(action).astype(jnp.int32)
        if action.shape != (spec.size,):
            raise ValueError(f"a continuous action has shape ({spec.size},), got {action.shape}")
        if not jnp.issubdtype(action.dtype, jnp.floating):
            raise TypeError(f"a continuous action is a float vector, got dtype {action.dtype}")
        if not isinstance(action, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(action))):
            raise ValueError(f"action contains NaN or inf: {np.asarray(action)}")
        return jnp.clip(action.astype(jnp.float32), spec.low, spec.high)

    def action_out_of_range(self, action: jax.Array) -> jax.Array | None:
        """For a traced integer action of a discrete env, whether it lies outside [0, size) (a traced bool); None
        otherwise (a concrete action is checked by ``check_action``, scores are argmax-ed, continuous actions are
        clipped by definition), so nothing is added to the compiled program then."""
        spec = self.action_spec
        if spec.kind != "discrete" or not isinstance(action, jax.core.Tracer):
            return None
        if not jnp.issubdtype(action.dtype, jnp.integer):
            return None
        return (action < 0) | (action >= spec.size)

    @staticmethod
    def flag_out_of_range(state: State, out_of_range: jax.Array | None) -> State:
        """``state`` with NaN ``obs`` and ``reward`` where ``out_of_range`` holds, so that a goal or action that
        could not be checked while tracing cannot pass unnoticed through a training loop; ``state`` itself when
        ``out_of_range`` is None. Two selects: the physics and every in-range value are untouched."""
        if out_of_range is None:
            return state
        nan = jnp.float32(jnp.nan)
        return state.replace(
            obs=jnp.where(out_of_range, nan, state.obs), reward=jnp.where(out_of_range, nan, state.reward)
        )
