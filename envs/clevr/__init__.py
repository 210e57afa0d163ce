"""CLEVR-Robot: ``clevr`` (80 push goals, TALAR's semantics) and ``clevr-arrangement`` (Appendix D.1.3)."""

from envs.clevr.env import ClevrConfig, ClevrEnv, ClevrTask
from envs.clevr.instructions import INSTRUCTION_FORMAT
from envs.instructions import register_instruction_format
from envs.registry import register_environment

register_environment("clevr", ClevrEnv)
register_environment("clevr-arrangement", ClevrEnv, task="arrangement")
register_instruction_format("clevr", INSTRUCTION_FORMAT)  # "clevr-arrangement" shares it (its alias)

__all__ = ["ClevrConfig", "ClevrEnv", "ClevrTask"]
