"""A method written outside the package runs through the whole project: it is one ``Method`` and, for an agent to
read it back, one encoding kind, both registered here; no project file names it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from experiments import compare
from experiments.config import default_config
from experiments.methods import Method, MethodContext, get_method, method_names, register_method
from experiments.methods.base import _METHODS
from experiments.methods.translation import frozen_table_setup
from experiments.pipeline import run
from talar_jax import encodings
from talar_jax.checkpoint import save_tree
from talar_jax.encodings import EncodingArtifact, ParamsSource
from talar_jax.stages import stable_hash
from tests.conftest import TINY_BERT

CODE_BITS = 6
KIND = "toy-sign-projection"


def _projection_setup(ctx: MethodContext):
    """Per seed, a fixed random projection of the sentence features, thresholded at 0: a binary code per sentence."""
    features = np.asarray(ctx.data.sentence_embeddings, np.float32)
    weights = np.stack(
        [np.random.default_rng(seed).normal(size=(features.shape[1], CODE_BITS)) for seed in range(ctx.seeds)]
    ).astype(np.float32)
    ((stage, key),) = ctx.stage_keys().items()
    folder = ctx.config.out / stage
    folder.mkdir(parents=True, exist_ok=True)
    save_tree(folder / "params.msgpack", {"weights": weights})
    tables = (np.einsum("sf,nfc->nsc", features, weights) > 0).astype(np.float32)
    return frozen_table_setup(ctx, tables, key)


TOY = Method(
    name="toy-projection",
    label="Toy projection",
    stage_keys=lambda config, upstream, cache: {"toy-projection/code": stable_hash("toy", upstream, cache)},
    setup=_projection_setup,
    encoding=lambda config, num_goals: EncodingArtifact(
        KIND,
        config.sentence_readout,
        CODE_BITS,
        binary=True,
        params=ParamsSource.file("toy-projection/code/params.msgpack"),
    ),
)


@pytest.fixture
def toy_method():
    register_method(TOY)
    encodings.register_encoding_kind(
        KIND, lambda artifact, params: lambda features: (features @ params["weights"] > 0).astype(jnp.float32)
    )
    yield TOY
    _METHODS.pop(TOY.name)
    encodings._KINDS.pop(KIND)


def test_a_method_registered_from_outside_runs_compares_and_loads_as_an_agent(toy_method, clevr_run, tmp_path):
    from talar_jax.agent import load

    quick_run, _ = clevr_run
    assert get_method("toy-projection") is toy_method and "toy-projection" in method_names()
    config = default_config(
        "clevr",
        method="toy-projection",
        quick=True,
        seeds=1,
        encoder=TINY_BERT,
        progress=False,
        deployment_strip=False,
        out=tmp_path / "run",
        reuse_stages=(Path(quick_run),),  # the oracle stage, as any second method of a folder would
    )
    summary = run(config)
    assert summary["method"] == "toy-projection"
    assert len(summary["final_success"]["train"]) == 1
    assert (tmp_path / "run" / "oracle" / "stage.json").is_file()

    args = compare.CompareArgs(experiment=dataclasses.replace(config, method="talar"), methods=("toy-projection",))
    final = compare.compare(args)
    assert list(final) == ["Toy projection"]
    assert "Toy projection" in (tmp_path / "run" / "compare.md").read_text()

    agent = load(tmp_path / "run" / "toy-projection", seed=0)
    sentence = agent.cache.sentences[0]
    code = agent.translate(sentence)[0]
    weights = np.random.default_rng(0).normal(size=(agent.encode(sentence).shape[1], CODE_BITS)).astype(np.float32)
    np.testing.assert_array_equal(code, (agent.encode(sentence)[0] @ weights > 0).astype(np.float32))
    assert agent.nearest_goal(code) is not None  # a training instruction's own code decodes to a goal
    episode = agent.rollout(sentence, jax.random.key(0), goal=int(agent.cache.goal_ids[0]))
    assert episode.length > 0
