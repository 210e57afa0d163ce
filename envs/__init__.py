"""Reusable pure-functional MuJoCo/MJX environments (CLEVR-Robot, FrankaKitchen); no dependency on talar_jax.

``make(name)`` picks the physics with ``default_physics()`` (MuJoCo C where JAX has only a CPU, MJX on an
accelerator; ``make(name, physics="c")`` or ``"mjx"`` chooses). On a CPU, MJX needs
``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`` set before JAX starts (deep kinematic chains otherwise compile about
twice as slowly): building MJX physics sets it while that is still possible and warns otherwise (``envs.runtime``).

With Gymnasium installed, importing ``envs`` registers every env with it (``talar_jax/Clevr-v0``,
``talar_jax/Kitchen-v0``, ... : ``gymnasium_id(name)``); ``gymnasium.make("envs:talar_jax/Kitchen-v0")`` imports
``envs`` itself (``envs.gymnasium_registration``).

An env lists its goals' names in ``env.goal_names`` and turns an id or a name into a goal id with ``env.goal_id``.
"""

import warnings

from envs.base import ActionSpec, Env, EnvConfig, State
from envs.gymnasium_registration import gymnasium_id, register_with_gymnasium
from envs.instructions import InstructionFormat, instruction_envs, instruction_format, register_instruction_format
from envs.physics import PHYSICS_NAMES, CPhysics, MjxPhysics, Physics, PhysicsState, default_physics, make_physics
from envs.registry import get_default_config, make, model_fingerprint, register_environment, registered_names
from envs.wrappers import (
    AutoResetWrapper,
    EpisodeWrapper,
    VmapWrapper,
    Wrapper,
    wrap_for_brax_training,
    wrap_for_training,
)

# Env packages register themselves (and their instruction formats) on import.
from envs import clevr as _clevr  # noqa: F401  isort: skip
from envs import kitchen as _kitchen  # noqa: F401  isort: skip

ALL_ENVS: tuple[str, ...] = registered_names()

# Imports Gymnasium's registry only when Gymnasium is installed (tens of milliseconds next to JAX and MuJoCo's
# seconds); the adapters themselves load at the first gymnasium.make or to_gymnasium.
register_with_gymnasium()

_GYMNASIUM_ADAPTERS = ("to_gymnasium", "to_gymnasium_vector")
_DEPRECATED = {  # old name -> (module, its name there, what to use instead)
    "PHYSICS_BACKENDS": ("envs.physics", "PHYSICS_NAMES", "envs.PHYSICS_NAMES"),
    "default_backend": ("envs.physics", "default_physics", "envs.default_physics()"),
    "goal_names": ("envs.registry", "goal_names", None),  # None: the function warns when called
    "resolve_goal": ("envs.goals", "resolve_goal", "env.goal_id(goal)"),
}


def __getattr__(name: str):
    """``to_gymnasium`` / ``to_gymnasium_vector`` from ``envs.gymnasium_adapter``, imported (with Gymnasium, the
    optional extra ``.[gymnasium]``) on first use only; and the deprecated names, with a warning."""
    import importlib

    if name in _GYMNASIUM_ADAPTERS:
        return getattr(importlib.import_module("envs.gymnasium_adapter"), name)
    if name in _DEPRECATED:
        module, attribute, instead = _DEPRECATED[name]
        if instead is not None:
            warnings.warn(f"envs.{name} is deprecated; use {instead}", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(module), attribute)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "ALL_ENVS",
    "PHYSICS_NAMES",
    "ActionSpec",
    "AutoResetWrapper",
    "CPhysics",
    "Env",
    "EnvConfig",
    "EpisodeWrapper",
    "InstructionFormat",
    "MjxPhysics",
    "Physics",
    "PhysicsState",
    "State",
    "VmapWrapper",
    "Wrapper",
    "default_physics",
    "get_default_config",
    "gymnasium_id",
    "instruction_envs",
    "instruction_format",
    "make",
    "make_physics",
    "model_fingerprint",
    "register_environment",
    "register_instruction_format",
    "register_with_gymnasium",
    "registered_names",
    "to_gymnasium",
    "to_gymnasium_vector",
    "wrap_for_brax_training",
    "wrap_for_training",
]
