"""Test configuration: CPU XLA flags and a persistent compile cache, set before JAX starts."""

import os

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")
if "--xla_cpu_use_fusion_emitters=false" not in os.environ["XLA_FLAGS"]:
    os.environ["XLA_FLAGS"] += " --xla_cpu_use_fusion_emitters=false"

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_compilation_cache_dir", os.path.expanduser("~/.cache/talar-jax/jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def pytest_addoption(parser):
    parser.addoption("--all", action="store_true", default=False, help="also run tests marked slow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--all"):
        return
    skip = pytest.mark.skip(reason="slow: run with --all")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
