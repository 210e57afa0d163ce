"""Test configuration: CPU XLA flags and a persistent compile cache, set before JAX starts."""

from talar_jax.runtime import configure

configure()

import pytest  # noqa: E402


def pytest_addoption(parser):
    parser.addoption("--all", action="store_true", default=False, help="also run tests marked slow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--all"):
        return
    skip = pytest.mark.skip(reason="slow: run with --all")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
