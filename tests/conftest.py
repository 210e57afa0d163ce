"""Test configuration: CPU XLA flags and a persistent compile cache, set when pytest loads this file (before it
imports any test module, and so before JAX starts)."""

from pathlib import Path

import pytest

from talar_jax.runtime import configure

configure()

TINY_BERT = str(Path(__file__).parent / "data" / "tiny_bert_mlm")
QUICK = ["--quick", "--seeds", "2", "--no-progress", "--no-deployment-strip", "--encoder", TINY_BERT]
"""A ``--quick`` experiment run with the small BERT folder shipped with the tests (caches build in seconds)."""


@pytest.fixture(scope="session")
def clevr_run(tmp_path_factory):
    """A finished two-seed ``--quick`` CLEVR TALAR run (shared by the experiment and agent tests): (folder, summary)."""
    from experiments import clevr

    out = tmp_path_factory.mktemp("clevr")
    summary = clevr.run_command([*QUICK, "--out", str(out)])
    return out, summary


@pytest.fixture(scope="session")
def kitchen_run(tmp_path_factory):
    """A finished two-seed ``--quick`` kitchen TALAR run with its deployment strip (shared by the experiment and HRL
    tests): (folder, printed output)."""
    import contextlib
    import io

    from experiments import kitchen

    out = tmp_path_factory.mktemp("kitchen")
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        kitchen.run_command([*[a for a in QUICK if a != "--no-deployment-strip"], "--out", str(out)])
    return out, printed.getvalue()


@pytest.fixture
def point_env_registered(monkeypatch):
    """The point env of tests/point_env.py registered as a third env package would be, removed afterwards."""
    import envs
    from envs import instructions, registry
    from tests import point_env

    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    monkeypatch.setattr(instructions, "_FORMATS", dict(instructions._FORMATS))
    point_env.register()
    yield envs
    monkeypatch.undo()
    assert "point" not in envs.registered_names() and "point" not in envs.instruction_envs()


def pytest_addoption(parser):
    parser.addoption("--all", action="store_true", default=False, help="also run tests marked slow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--all"):
        return
    skip = pytest.mark.skip(reason="slow: run with --all")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
