"""The one registry of environments: names -> (env class, config overrides), and how their instructions are read."""

from __future__ import annotations

import functools
import hashlib
from typing import Any

from envs.base import Env, EnvConfig, replace_config
from envs.instructions import InstructionFormat
from envs.physics import PHYSICS_BACKENDS

_REGISTRY: dict[str, tuple[type[Env], dict[str, Any]]] = {}
_INSTRUCTION_FORMATS: dict[str, InstructionFormat] = {}
GYMNASIUM_NAMESPACE = "talar_jax"
_gymnasium_registry: Any = None  # gymnasium's registry module once register_with_gymnasium found it


def register_environment(name: str, env_class: type[Env], **config_overrides: Any) -> None:
    """Registers ``env_class`` under ``name``; ``config_overrides`` are applied to its default config. Once ``envs``
    is imported with Gymnasium installed, the env is also registered with Gymnasium (``gymnasium_id(name)``)."""
    if name in _REGISTRY:
        raise ValueError(f"environment {name!r} is already registered")
    replace_config(env_class.config_class(), config_overrides)  # fail early on bad overrides
    _REGISTRY[name] = (env_class, dict(config_overrides))
    if _gymnasium_registry is not None:
        _register_gymnasium_id(name)


def gymnasium_id(name: str) -> str:
    """The Gymnasium id of a registered env: ``"clevr-arrangement"`` -> ``"talar_jax/ClevrArrangement-v0"``."""
    return f"{GYMNASIUM_NAMESPACE}/{''.join(part.capitalize() for part in name.split('-'))}-v0"


def _register_gymnasium_id(name: str) -> None:
    env_id = gymnasium_id(name)
    if env_id in _gymnasium_registry.registry:  # e.g. envs reloaded: Gymnasium would warn about overriding it
        return
    # Entry points are strings, so the adapters (and Gymnasium's vector module) load at the first gymnasium.make.
    _gymnasium_registry.register(
        id=env_id,
        entry_point="envs.gymnasium_adapter:to_gymnasium",
        vector_entry_point="envs.gymnasium_adapter:to_gymnasium_vector",
        kwargs={"name_or_env": name},
    )


def register_with_gymnasium() -> bool:
    """Registers every env with Gymnasium (``gymnasium.make(gymnasium_id(name), **options)`` builds
    ``envs.to_gymnasium(name, **options)``; ``gymnasium.make_vec`` the vector adapter), and every env registered
    later. ``import envs`` calls it; without Gymnasium (an optional dependency) it does nothing and returns False.
    """
    global _gymnasium_registry
    try:
        from gymnasium.envs import registration
    except ImportError:
        return False
    _gymnasium_registry = registration
    for name in _REGISTRY:
        _register_gymnasium_id(name)
    return True


def registered_names() -> tuple[str, ...]:
    return tuple(sorted(_REGISTRY))


def _lookup(name: str) -> tuple[type[Env], dict[str, Any]]:
    if name not in _REGISTRY:
        raise ValueError(f"unknown environment {name!r}; registered environments: {', '.join(registered_names())}")
    return _REGISTRY[name]


def get_default_config(name: str) -> EnvConfig:
    """The resolved default config of a registered env (a frozen dataclass)."""
    env_class, overrides = _lookup(name)
    return replace_config(env_class.config_class(), overrides)


@functools.cache
def model_fingerprint(name: str) -> str:
    """A short sha256 of the MJCF file a registered env compiles. Caches of results made on an env (task datasets,
    policies) put it in their keys, so that editing a model invalidates what was made with the old one."""
    env_class, _ = _lookup(name)
    return hashlib.sha256(env_class.xml_path.read_bytes()).hexdigest()[:16]


def make(name: str, *, physics: str | None = None, **overrides: Any) -> Env:
    """Builds a registered env.

    Args:
        name: one of ``envs.ALL_ENVS``.
        physics: ``"mjx"`` (pure JAX: jit-, vmap- and grad-able, the fast choice on a GPU/TPU) or ``"c"`` (MuJoCo's
            C engine through a batched callback: the fast choice on a CPU). None (default) asks
            ``envs.default_backend()``, the rule the experiment commands and the Gymnasium adapters follow too:
            C where JAX has only a CPU, MJX on an accelerator. An explicit value always wins; MJX on a CPU sets
            (or, once JAX has started, warns about) the XLA flag it needs (``envs.runtime``).
        **overrides: fields of the env's config (see ``get_default_config(name)``).
    """
    env_class, _ = _lookup(name)
    if physics is not None and physics not in PHYSICS_BACKENDS:
        raise ValueError(f"unknown physics backend {physics!r}; choose one of {', '.join(PHYSICS_BACKENDS)}")
    config = replace_config(get_default_config(name), overrides)
    return env_class(config, physics=physics)


def goal_names(name: str, **overrides: Any) -> tuple[str, ...]:
    """The name of each goal id of a registered env with ``overrides`` (``Env.goal_names``, without building the
    env); pair with ``envs.resolve_goal`` to read a goal a person typed."""
    env_class, _ = _lookup(name)
    return env_class.goal_names_of(replace_config(get_default_config(name), overrides))


def register_instruction_format(env: str, instruction_format: InstructionFormat) -> None:
    """Makes ``env`` (and the variants named in ``instruction_format.aliases``) read its instructions this way.

    An env package calls it beside its ``register_environment`` calls; calling it again for ``env`` replaces the
    format (e.g. to read another layout of instruction file).
    """
    _INSTRUCTION_FORMATS[env] = instruction_format


def instruction_envs() -> dict[str, str]:
    """Every env or variant name with instructions -> the env whose instructions it uses."""
    names = {env: env for env in _INSTRUCTION_FORMATS}
    names.update({alias: env for env, fmt in _INSTRUCTION_FORMATS.items() for alias in fmt.aliases})
    return names


def instruction_format(env: str) -> InstructionFormat:
    """The instruction format of an env or of one of its variants, or one clear error."""
    names = instruction_envs()
    if env not in names:
        raise ValueError(f"unknown env {env!r} for instructions; valid: {', '.join(sorted(names))}")
    return _INSTRUCTION_FORMATS[names[env]]
