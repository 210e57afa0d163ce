"""The Gymnasium ids of the registered envs (``talar_jax/Clevr-v0``, ...), registered with Gymnasium when it is there.

Gymnasium 1.x has no plugin mechanism: its registry knows an id once the package that registers it is imported.
``import envs`` does that (``register_with_gymnasium``), and Gymnasium's module prefix does it from the id itself:
``gymnasium.make("envs:talar_jax/Kitchen-v0")`` imports ``envs`` first, so it works in a fresh interpreter with no
other import. The entry points are strings, so the adapters (and Gymnasium's vector module) load at the first
``gymnasium.make``, not here.
"""

from __future__ import annotations

from typing import Any

from envs.registry import on_register, registered_names

GYMNASIUM_NAMESPACE = "talar_jax"
GYMNASIUM_MODULE = "envs"
"""The module Gymnasium imports for an id written ``"envs:talar_jax/Kitchen-v0"``."""

_gymnasium_registry: Any = None  # gymnasium's registration module once register_with_gymnasium found it


def gymnasium_id(name: str) -> str:
    """The Gymnasium id of a registered env: ``"clevr-arrangement"`` -> ``"talar_jax/ClevrArrangement-v0"``.
    ``f"envs:{gymnasium_id(name)}"`` is the form that needs no ``import envs`` before ``gymnasium.make``."""
    return f"{GYMNASIUM_NAMESPACE}/{''.join(part.capitalize() for part in name.split('-'))}-v0"


def _register_id(name: str) -> None:
    env_id = gymnasium_id(name)
    if env_id in _gymnasium_registry.registry:  # e.g. envs reloaded: Gymnasium would warn about overriding it
        return
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
    for name in registered_names():
        _register_id(name)
    on_register(_register_id)  # an env registered later gets its id too
    return True
