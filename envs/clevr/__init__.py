"""CLEVR-Robot: ``clevr`` (80 push goals, TALAR's semantics) and ``clevr-arrangement`` (Appendix D.1.3)."""

from envs.clevr.env import ClevrConfig, ClevrEnv, ClevrTask
from envs.registry import register_environment

register_environment("clevr", ClevrEnv)
register_environment("clevr-arrangement", ClevrEnv, task="arrangement")

__all__ = ["ClevrConfig", "ClevrEnv", "ClevrTask"]
