"""FrankaKitchen: ``kitchen`` (one TALAR sub-task per episode) and ``kitchen-all`` (all six at once)."""

from envs.kitchen.env import KitchenConfig, KitchenEnv, KitchenTask
from envs.registry import register_environment

register_environment("kitchen", KitchenEnv)
register_environment("kitchen-all", KitchenEnv, all_tasks=True)

__all__ = ["KitchenConfig", "KitchenEnv", "KitchenTask"]
