"""Stage keys of every method on every env stay what they were when recorded runs were made: a finished run
folder is reused and reported by later code only while its keys hold (``tests/data/stage_keys.json`` holds the keys
of the default, ``--quick``, other-seed and per-env variants, computed by the code that made the recorded runs). The
policy stage's keys follow its evaluation schedule and the env's reward, so they were recorded again when the
curve's evaluations shrank and the kitchen's microwave reward changed; every other stage's key is the original."""

import dataclasses
import json
from pathlib import Path

import pytest

from experiments.config import default_config, resolve
from experiments.methods import method_names
from experiments.pipeline import stage_keys, stage_oracle_key

RECORDED = json.loads((Path(__file__).parent / "data" / "stage_keys.json").read_text())
VARIANTS = {
    "default": {},
    "quick": {"quick": True},
    "seeds2": {"seeds": 2, "seed": 3},
    "patterns5": {"num_patterns": 5},
    "patterns9": {"num_patterns": 9},
    "tuples": {"num_tuples": 50_000},
}


def _recorded_cases():
    return sorted({tuple(name.split("/")[:2]) for name in RECORDED})


@pytest.mark.parametrize(("env", "variant"), _recorded_cases())
def test_every_methods_stage_keys_are_the_recorded_ones(env, variant):
    base = default_config(env, **VARIANTS[variant])
    assert stage_oracle_key(resolve(base)) == RECORDED[f"{env}/{variant}/oracle"]
    recorded_methods = {name.split("/")[2] for name in RECORDED if name.startswith(f"{env}/{variant}/")} - {"oracle"}
    assert recorded_methods <= set(method_names())
    for method in sorted(recorded_methods):
        keys = stage_keys(resolve(dataclasses.replace(base, method=method)), "oracle-key", "cache-key")
        assert keys == RECORDED[f"{env}/{variant}/{method}"], method
