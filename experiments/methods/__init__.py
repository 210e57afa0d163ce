"""The methods an experiment can run (``--method``): TALAR and the paper's baselines, one registry.

``get_method(name)`` gives a ``Method`` (label, stage keys, setup, how an agent reads it back); a new method is a
module that builds a ``Method`` and calls ``register_method`` (see ``experiments/methods/base.py``).
"""

from experiments.methods.base import (
    FIT_CHECKPOINT,
    Method,
    MethodContext,
    MethodSetup,
    get_method,
    method_label,
    method_names,
    register_method,
    stage_seed_keys,
    translator_readout,
)
from experiments.methods.bert import ALIGNED_METHODS, BERT_METHODS, FINETUNED_METHODS
from experiments.methods.goal_codes import GLA, HANDCRAFTED, ONEHOT
from experiments.methods.talar import END_TO_END, TALAR
from experiments.methods.translation import paraphrased_data

PAPER_COMPARISON: tuple[str, ...] = (
    "talar",
    "onehot",
    "bert-binary",
    "bert-continuous",
    "pretrained-bert-binary",
    "pretrained-bert-continuous",
    "gla",
    "handcrafted",
)
"""The eight methods of the paper's Fig. 4 (the Aligned baselines belong to Appendix E.3)."""

# The paper's comparison first, then the appendix variants: the order figures and tables list methods in.
for _method in (TALAR, ONEHOT, *BERT_METHODS, GLA, HANDCRAFTED, *ALIGNED_METHODS, END_TO_END, *FINETUNED_METHODS):
    register_method(_method)


def method_stage_keys(config, upstream_key: str, cache_key: str) -> dict[str, str]:
    """Stage folder -> key of every stage of ``config.method`` (resolved); the last is what the IFP builds on."""
    return get_method(config.method).stage_keys(config, upstream_key, cache_key)


__all__ = [
    "FIT_CHECKPOINT",
    "PAPER_COMPARISON",
    "Method",
    "MethodContext",
    "MethodSetup",
    "get_method",
    "method_label",
    "method_names",
    "method_stage_keys",
    "paraphrased_data",
    "register_method",
    "stage_seed_keys",
    "translator_readout",
]
