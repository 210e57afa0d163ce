"""Reusable pure-functional MuJoCo/MJX environments (CLEVR-Robot, FrankaKitchen); no dependency on talar_jax.

``make(name)`` picks the physics with ``default_backend()`` (MuJoCo C where JAX has only a CPU, MJX on an
accelerator). On a CPU, MJX needs ``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`` set before JAX starts (deep
kinematic chains otherwise compile about twice as slowly): building MJX physics sets it while that is still possible
and warns otherwise (``envs.runtime``). With Gymnasium installed, importing ``envs`` registers every env with it
(``talar_jax/Clevr-v0``, ``talar_jax/Kitchen-v0``, ... : ``gymnasium_id(name)``).
"""

from envs.base import ActionSpec, Env, EnvConfig, State
from envs.goals import resolve_goal
from envs.instructions import InstructionFormat
from envs.physics import PHYSICS_BACKENDS, CPhysics, MjxPhysics, Physics, PhysicsState, default_backend, make_physics
from envs.registry import (
    get_default_config,
    goal_names,
    gymnasium_id,
    instruction_envs,
    instruction_format,
    make,
    model_fingerprint,
    register_environment,
    register_instruction_format,
    register_with_gymnasium,
    registered_names,
)
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


def __getattr__(name: str):
    """``to_gymnasium`` / ``to_gymnasium_vector`` from ``envs.gymnasium_adapter``, imported (with Gymnasium, the
    optional extra ``.[gymnasium]``) on first use only."""
    if name in _GYMNASIUM_ADAPTERS:
        from envs import gymnasium_adapter

        return getattr(gymnasium_adapter, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "ALL_ENVS",
    "PHYSICS_BACKENDS",
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
    "default_backend",
    "get_default_config",
    "goal_names",
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
    "resolve_goal",
    "to_gymnasium",
    "to_gymnasium_vector",
    "wrap_for_brax_training",
    "wrap_for_training",
]
