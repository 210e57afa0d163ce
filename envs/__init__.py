"""Reusable pure-functional MuJoCo/MJX environments (CLEVR-Robot, FrankaKitchen); no dependency on talar_jax.

On a CPU, MJX needs ``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`` set before JAX starts (deep
kinematic chains otherwise compile into exponentially slow code); the project's entry points set it.
"""

from envs.base import ActionSpec, Env, EnvConfig, State
from envs.instructions import InstructionFormat
from envs.physics import PHYSICS_BACKENDS, CPhysics, MjxPhysics, Physics, PhysicsState, default_backend, make_physics
from envs.registry import (
    get_default_config,
    instruction_envs,
    instruction_format,
    make,
    model_fingerprint,
    register_environment,
    register_instruction_format,
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
    "instruction_envs",
    "instruction_format",
    "make",
    "make_physics",
    "model_fingerprint",
    "register_environment",
    "register_instruction_format",
    "to_gymnasium",
    "to_gymnasium_vector",
    "wrap_for_brax_training",
    "wrap_for_training",
]
