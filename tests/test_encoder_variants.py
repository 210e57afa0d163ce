"""The encoder experiment's family: one BERT network read out in several ways, or with random weights. Each readout
is what it says, the default readout is unchanged, and each has its own cache key."""

from __future__ import annotations

import numpy as np
import pytest

from talar_jax.language import BertEncoder
from talar_jax.language.bert import BertModel, mean_pool
from talar_jax.language.encoder import ENCODER_VARIANTS, EncoderError
from tests.conftest import TINY_BERT

SENTENCES = ["push the red ball to the left", "open the microwave door please"]


def encoder(**kwargs) -> BertEncoder:
    return BertEncoder(TINY_BERT, **kwargs)


def inputs(model: BertEncoder):
    ids, mask = model.pad([model.with_specials(t) for t in model.tokenize(SENTENCES)])
    return ids, mask


def test_the_mean_readout_is_the_plain_network_mean_pooled():
    model = encoder()
    ids, mask = inputs(model)
    expected = mean_pool(BertModel(model.config).apply(model.params, ids, mask), mask)
    np.testing.assert_allclose(model.encode(SENTENCES), np.asarray(expected), atol=1e-6)


def test_each_readout_reads_what_it_names():
    base = encoder()
    ids, mask = inputs(base)
    last = np.asarray(BertModel(base.config).apply(base.params, ids, mask))
    cls = encoder(readout="cls").encode(SENTENCES)
    np.testing.assert_allclose(cls, last[:, 0] / np.linalg.norm(last[:, 0], axis=1, keepdims=True), atol=1e-6)
    layer = encoder(readout="layer-1")
    first = np.asarray(BertModel(base.config, layers=(0, 1)).apply(base.params, ids, mask))
    np.testing.assert_allclose(layer.hidden_states(ids, mask), first, atol=1e-6)
    pieces = encoder(readout="word-pieces")
    table = np.asarray(base.params["params"]["embeddings"]["word_embeddings"]["embedding"])
    np.testing.assert_array_equal(pieces.hidden_states(ids, mask), table[ids])
    keys = {encoder(readout=r).cache_key for r in ("mean", "cls", "layer-1", "word-pieces")}
    assert len(keys) == 4


def test_random_weights_are_seeded_and_not_the_folders():
    first, again, other = (encoder(random_weights_seed=s) for s in (0, 0, 1))
    np.testing.assert_array_equal(first.encode(SENTENCES), again.encode(SENTENCES))
    assert first.weights_sha256 == again.weights_sha256 != other.weights_sha256
    assert not np.allclose(first.encode(SENTENCES), encoder().encode(SENTENCES), atol=1e-3)
    assert first.cache_key != encoder().cache_key


@pytest.mark.parametrize("readout", ["max", "layer-0", "layer-x", "layer-99"])
def test_an_unknown_readout_is_an_encoder_error(readout):
    with pytest.raises(EncoderError, match="unknown encoder readout"):
        encoder(readout=readout)


def test_the_named_variants_are_the_default_network():
    assert set(ENCODER_VARIANTS) == {"minilm-cls", "minilm-layer3", "minilm-word-pieces", "random-bert"}
    assert all(set(options) <= {"readout", "random_weights_seed"} for options in ENCODER_VARIANTS.values())


def test_the_lead_is_talar_over_the_best_finished_baseline(tmp_path, monkeypatch):
    import json

    from experiments.analysis import encoder_lead

    monkeypatch.setattr(encoder_lead, "agreement", lambda name, env="clevr": 0.5)
    for method, rates in (("talar", [0.9, 1.0]), ("bert-binary", [0.8, 0.8]), ("bert-continuous", [0.6, 0.7])):
        (tmp_path / "done" / method).mkdir(parents=True)
        summary = {"final_success": {"test": rates, "train": rates}}
        (tmp_path / "done" / method / "summary.json").write_text(json.dumps(summary))
    finished = encoder_lead.encoder_row("minilm-cls", tmp_path / "done", onehot=50.0)
    assert finished["lead"] == pytest.approx(95.0 - 80.0)
    assert finished["success_test"]["onehot"] == 50.0
    waiting = encoder_lead.encoder_row("random-bert", tmp_path / "missing", onehot=50.0)
    assert waiting["lead"] is None and waiting["agreement"] == 0.5
    table = encoder_lead.lead_table([finished, waiting])
    assert "| minilm-cls | 50.0 | 95.0 | 80.0 | 65.0 | 50.0 | +15.0 |" in table and "not finished" in table


def test_a_pretrained_encoder_top_over_the_states_below_it_is_the_whole_network():
    import flax.linen as nn
    import jax

    from talar_jax.language.bert import EncoderTop, with_pretrained_top

    model = encoder()
    sequences = [model.with_specials(t) for t in model.tokenize(SENTENCES)]
    last = model.token_states(sequences, 16)
    first = model.config.num_hidden_layers - 1
    below = model.token_states(sequences, 16, below_layer=first)
    mask = np.any(last != 0, axis=-1).astype(np.int32)

    class Head(nn.Module):
        @nn.compact
        def __call__(self, states, mask):
            return EncoderTop(model.config, first, name="top")(states, mask)

    head = Head()
    params = head.init(jax.random.key(0), below, mask)
    fresh = np.asarray(head.apply(params, below, mask)) * mask[..., None]
    assert np.abs(fresh - last).max() > 1e-3  # a fresh top is not the encoder's
    params = with_pretrained_top(params, model.params, first, ("top",))
    np.testing.assert_allclose(np.asarray(head.apply(params, below, mask)) * mask[..., None], last, atol=1e-5)
    with pytest.raises(ValueError, match="below_layer"):
        model.token_states(sequences, 16, below_layer=model.config.num_hidden_layers)
