"""The one registry of environments: names -> (env class, config overrides).

How an env's instructions are read is registered in ``envs.instructions``, and the Gymnasium ids in
``envs.gymnasium_registration``.
"""

from __future__ import annotations

import functools
import hashlib
import warnings
from collections.abc import Callable
from typing import Any

from envs.base import Env, EnvConfig, replace_config
from envs.physics import PHYSICS_NAMES

_REGISTRY: dict[str, tuple[type[Env], dict[str, Any]]] = {}
_LISTENERS: list[Callable[[str], None]] = []  # called with each name registered (the Gymnasium registration)


def register_environment(name: str, env_class: type[Env], **config_overrides: Any) -> None:
    """Registers ``env_class`` under ``name``; ``config_overrides`` are applied to its default config. Once ``envs``
    is imported with Gymnasium installed, the env is also registered with Gymnasium (``gymnasium_id(name)``)."""
    if name in _REGISTRY:
        raise ValueError(f"environment {name!r} is already registered")
    replace_config(env_class.config_class(), config_overrides)  # fail early on bad overrides
    _REGISTRY[name] = (env_class, dict(config_overrides))
    for listener in _LISTENERS:
        listener(name)


def on_register(listener: Callable[[str], None]) -> None:
    """Calls ``listener(name)`` for every env registered from now on (once per listener)."""
    if listener not in _LISTENERS:
        _LISTENERS.append(listener)


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
            ``envs.default_physics()``, the rule the experiment commands and the Gymnasium adapters follow too:
            C where JAX has only a CPU, MJX on an accelerator. An explicit value always wins; MJX on a CPU sets
            (or, once JAX has started, warns about) the XLA flag it needs (``envs.runtime``).
        **overrides: fields of the env's config (see ``get_default_config(name)``).
    """
    env_class, _ = _lookup(name)
    if physics is not None and physics not in PHYSICS_NAMES:
        raise ValueError(f"unknown physics {physics!r}; choose one of {', '.join(PHYSICS_NAMES)}")
    config = replace_config(get_default_config(name), overrides)
    return env_class(config, physics=physics)


def goal_names(name: str, **overrides: Any) -> tuple[str, ...]:
    """Deprecated: ``envs.make(name, **overrides).goal_names``."""
    warnings.warn("envs.goal_names(name) is deprecated; use envs.make(name).goal_names", DeprecationWarning, 2)
    return make(name, physics="c", **overrides).goal_names


_MOVED = {
    "register_instruction_format": "envs.instructions",
    "instruction_envs": "envs.instructions",
    "instruction_format": "envs.instructions",
    "GYMNASIUM_NAMESPACE": "envs.gymnasium_registration",
    "gymnasium_id": "envs.gymnasium_registration",
    "register_with_gymnasium": "envs.gymnasium_registration",
}


def __getattr__(name: str):
    """Names that moved to modules of their own, with a warning (``envs.<name>`` still has each of them)."""
    if name in _MOVED:
        import importlib

        warnings.warn(f"envs.registry.{name} moved to {_MOVED[name]}", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
