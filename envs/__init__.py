"""Reusable pure-functional MuJoCo/MJX environments (CLEVR-Robot, FrankaKitchen); no dependency on talar_jax.

On a CPU, MJX needs ``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`` set before JAX starts (deep
kinematic chains otherwise compile into exponentially slow code); the project's entry points set it.
"""

from envs.base import ActionSpec, Env, EnvConfig, State
from envs.physics import PHYSICS_BACKENDS, CPhysics, MjxPhysics, Physics, PhysicsState, default_backend, make_physics
from envs.registry import get_default_config, make, register_environment, registered_names
from envs.wrappers import (
    AutoResetWrapper,
    EpisodeWrapper,
    VmapWrapper,
    Wrapper,
    wrap_for_brax_training,
    wrap_for_training,
)

# Env packages register themselves on import.
from envs import clevr as _clevr  # noqa: E402,F401  isort: skip
from envs import kitchen as _kitchen  # noqa: E402,F401  isort: skip

ALL_ENVS: tuple[str, ...] = registered_names()

__all__ = [
    "ALL_ENVS",
    "PHYSICS_BACKENDS",
    "ActionSpec",
    "AutoResetWrapper",
    "CPhysics",
    "Env",
    "EnvConfig",
    "EpisodeWrapper",
    "MjxPhysics",
    "Physics",
    "PhysicsState",
    "State",
    "VmapWrapper",
    "Wrapper",
    "default_backend",
    "get_default_config",
    "make",
    "make_physics",
    "register_environment",
    "wrap_for_brax_training",
    "wrap_for_training",
]
