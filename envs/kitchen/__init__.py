"""FrankaKitchen: ``kitchen`` (one TALAR sub-task per episode) and ``kitchen-all`` (all six at once)."""

from envs.instructions import register_instruction_format
from envs.kitchen.env import KitchenConfig, KitchenEnv, KitchenTask
from envs.kitchen.instructions import INSTRUCTION_FORMAT
from envs.registry import register_environment

register_environment("kitchen", KitchenEnv)
register_environment("kitchen-all", KitchenEnv, all_tasks=True)
register_instruction_format("kitchen", INSTRUCTION_FORMAT)  # "kitchen-all" shares it (its alias)

__all__ = ["KitchenConfig", "KitchenEnv", "KitchenTask"]
