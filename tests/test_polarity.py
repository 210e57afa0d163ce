"""Polarity: the sets are built as documented (halves split by frame and phrase), the shipped classifier reads the
held-out half well enough, and an agent refuses a sentence that asks not to do a task, or to undo it, naming it."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from talar_jax.language import polarity as sets
from talar_jax.language.polarity import LABELS, polarity_set


@pytest.mark.parametrize("env", ["kitchen", "clevr"])
def test_the_sets_are_deterministic_and_hold_every_label_in_both_halves(env):
    first, again = polarity_set(env), polarity_set(env)
    assert first.sentences == again.sentences and len(set(first.sentences)) == len(first.sentences)
    for held in (False, True):
        half = first.half(held)
        assert set(half.labels.tolist()) == {0, 1, 2}
    assert first.goals.min() >= 0 and first.goals.max() < (6 if env == "kitchen" else 80)


def test_every_train_sentence_comes_from_a_train_frame_and_a_train_phrase():
    from talar_jax.language import load_instructions

    data = json.loads(sets.POLARITY_FILE.read_text())
    fills = [fill for label in LABELS for task in data["kitchen"].values() for fill in sets._fills(label, task)]
    train_only = {sets._sentence(frame, phrase) for frame, phrase, held, _ in fills if not held}
    assert {sets._sentence(frame, phrase) for frame, phrase, held, _ in fills if held} - train_only  # a held-out half
    made = set(polarity_set("kitchen").half(False).sentences) - set(load_instructions("kitchen", "train").sentences)
    assert made and made <= train_only


def test_env_instructions_are_positive_training_ones_in_the_train_half():
    from talar_jax.language import load_instructions

    polar = polarity_set("kitchen")
    rows = {s: i for i, s in enumerate(polar.sentences)}
    for split, held in (("train", False), ("test", True)):
        for sentence in load_instructions("kitchen", split).sentences:
            assert polar.labels[rows[sentence]] == 0 and polar.held_out[rows[sentence]] == held


@pytest.mark.parametrize("env", ["kitchen", "clevr"])
def test_the_development_split_divides_the_train_half_by_frame_and_phrase(env):
    development, train = polarity_set(env, development=True), polarity_set(env).half(False)
    assert development.sentences == train.sentences and (development.labels == train.labels).all()
    for held in (False, True):
        assert set(development.half(held).labels.tolist()) == {0, 1, 2}
    data = json.loads(sets.POLARITY_FILE.read_text())
    frames = data["frames"]["negated"]["train"]
    developing = {frame for i, frame in enumerate(frames) if i % sets.DEVELOPMENT_FRAMES == sets.DEVELOPMENT_FRAMES - 1}
    if env == "kitchen":  # a developing frame's sentences are all in the development share
        made = {sets._sentence(f, p) for f in developing for p in data["kitchen"]["microwave"]["do"]["train"]}
        rows = {s: i for i, s in enumerate(development.sentences)}
        assert made and all(development.held_out[rows[s]] for s in made if s in rows)
        assert not development.held_out[rows["Don't open the microwave door."]]  # a first frame, a first phrase


def test_task_phrases_name_the_goal():
    assert sets.task_phrase("kitchen", sets.kitchen_goal_names().index("microwave")) == "open the microwave door"
    assert sets.task_phrase("clevr", 0).startswith("push the ") and sets.task_phrase("clevr", 0).endswith(" ball")


@pytest.fixture(scope="module")
def kitchen_agent():
    from talar_jax import agent

    return agent.load("kitchen")


def test_the_shipped_classifier_reads_the_held_out_half(kitchen_agent):
    """Thresholds below what the shipped classifier measured on its held-out half (results/abstention/polarity.md),
    so that a classifier that stopped reading polarity fails."""
    half = polarity_set("kitchen").half(True)
    probabilities = kitchen_agent.polarity(list(half.sentences))
    acted = probabilities[:, 0] >= 0.5
    assert acted[half.labels == 0].mean() >= 0.9
    assert acted[half.labels != 0].mean() <= 0.15


def test_an_opposite_is_refused_naming_the_task_and_a_positive_with_a_negative_word_is_acted_on(kitchen_agent):
    refused = kitchen_agent.understand("Close the microwave door.")
    assert not refused.acts and refused.polarity == "opposite"
    assert refused.reason == 'asks for the opposite of "open the microwave door"'
    assert "asks for the opposite of" in refused.describe(kitchen_agent.env.goal_names)
    assert refused.to_json()["reason"] == refused.reason
    negated = kitchen_agent.understand("Don't turn on the light.")
    assert not negated.acts and negated.polarity == "negated" and "turn on the light" in negated.reason
    kept = kitchen_agent.understand("Don't forget to open the microwave.")
    assert kept.acts and kitchen_agent.env.goal_names[kept.goal] == "microwave" and kept.reason is None


def test_no_classifier_is_read_for_another_encoder(kitchen_agent, tmp_path):
    from talar_jax.agent import POLARITY_PARAMS, POLARITY_RECORD, SHIPPED_AGENTS_DIR, AgentError, load_polarity

    assert load_polarity(kitchen_agent.encoder) is not None
    record = json.loads((SHIPPED_AGENTS_DIR / POLARITY_RECORD).read_text())
    (tmp_path / POLARITY_RECORD).write_text(json.dumps({**record, "encoder_cache_key": "another"}))
    (tmp_path / POLARITY_PARAMS).write_bytes((SHIPPED_AGENTS_DIR / POLARITY_PARAMS).read_bytes())
    assert load_polarity(kitchen_agent.encoder, tmp_path) is None
    (tmp_path / POLARITY_RECORD).write_text(json.dumps(record))
    (tmp_path / POLARITY_PARAMS).write_bytes(b"\x00\x01")
    with pytest.raises(AgentError, match="polarity.msgpack is damaged"):
        load_polarity(kitchen_agent.encoder, tmp_path)


def test_the_shipped_classifier_round_trips_and_is_read_only_as_its_record_describes(kitchen_agent, tmp_path):
    import flax.serialization

    from talar_jax.agent import POLARITY_PARAMS, POLARITY_RECORD, SHIPPED_AGENTS_DIR, AgentError, load_polarity
    from talar_jax.confidence.polarity import polarity_probabilities, shipped_params

    params, config = load_polarity(kitchen_agent.encoder)
    assert sorted(params["params"]) == sorted(
        [f"head_{m}" for m in range(config.members)] + (["top"] if config.tuned_layers else [])
    )
    again = flax.serialization.msgpack_restore(
        flax.serialization.msgpack_serialize(flax.serialization.to_state_dict(shipped_params(params)))
    )
    states = np.random.default_rng(0).normal(size=(3, 6, kitchen_agent.encoder.embedding_dim)).astype(np.float32)
    encoder = kitchen_agent.encoder.config if config.tuned_layers else None
    np.testing.assert_array_equal(
        polarity_probabilities(params, states, config, encoder), polarity_probabilities(again, states, config, encoder)
    )
    assert (SHIPPED_AGENTS_DIR / POLARITY_PARAMS).stat().st_size < 8 * 2**20  # the shipped files live in git
    record = json.loads((SHIPPED_AGENTS_DIR / POLARITY_RECORD).read_text())
    record["config"]["tuned_layers"] = 0 if config.tuned_layers else 1  # a record that does not describe the file
    (tmp_path / POLARITY_RECORD).write_text(json.dumps(record))
    (tmp_path / POLARITY_PARAMS).write_bytes((SHIPPED_AGENTS_DIR / POLARITY_PARAMS).read_bytes())
    with pytest.raises(AgentError, match="not the classifier its record describes"):
        load_polarity(kitchen_agent.encoder, tmp_path)


def test_fine_tuned_parameters_ship_with_the_top_in_float16():
    from talar_jax.confidence.polarity import shipped_params

    params = {"params": {"top": {"bert": {"layer_5": {"w": np.ones(3, np.float32)}}}, "head_0": {"w": np.ones(2)}}}
    shipped = shipped_params(params)["params"]
    assert shipped["top"]["bert"]["layer_5"]["w"].dtype == np.float16 and shipped["head_0"]["w"].dtype == np.float32


def test_a_fine_tuned_top_moves_from_the_encoders_weights_only_at_its_own_learning_rate(kitchen_agent):
    import jax

    from talar_jax.confidence.polarity import PolarityConfig, fit_polarity, polarity_states

    encoder = kitchen_agent.encoder
    sentences = ["Open the microwave.", "Don't open the microwave.", "Close the microwave."] * 4
    labels = np.arange(len(sentences)) % 3
    config = PolarityConfig(hidden=8, steps=3, batch_size=4, members=2, tuned_layers=1)
    states = polarity_states(encoder, sentences, config)
    last = f"layer_{encoder.config.num_hidden_layers - 1}"
    for rate, moves in ((1e-3, True), (0.0, False)):
        top = fit_polarity(states, labels, dataclasses.replace(config, top_learning_rate=rate), encoder)
        pairs = zip(
            jax.tree_util.tree_leaves(top["params"]["top"]["bert"][last]),
            jax.tree_util.tree_leaves(encoder.params["params"][last]),
        )
        assert any(np.abs(np.asarray(a) - b).max() > 1e-6 for a, b in pairs) == moves


def test_fitting_is_deterministic():
    from talar_jax.confidence.polarity import PolarityConfig, fit_polarity, polarity_probabilities

    rng = np.random.default_rng(0)
    tokens = rng.normal(size=(24, 5, 8)).astype(np.float32)
    labels = np.arange(24) % 3
    tokens[np.arange(24), :, labels] += 4.0  # a learnable cue in every piece
    config = PolarityConfig(hidden=16, steps=150, batch_size=8, members=2, dropout=0.0, tuned_layers=0)
    first = polarity_probabilities(fit_polarity(tokens, labels, config), tokens, config)
    again = polarity_probabilities(fit_polarity(tokens, labels, config), tokens, config)
    np.testing.assert_array_equal(first, again)
    assert (first.argmax(1) == labels).mean() > 0.9
