"""Polarity: the sets are built as documented (halves split by frame and phrase), the shipped classifier reads the
held-out half well enough, and an agent refuses a sentence that asks not to do a task, or to undo it, naming it."""

from __future__ import annotations

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
    train_only = {sets._sentence(frame, phrase) for frame, phrase, held in fills if not held}
    assert {sets._sentence(frame, phrase) for frame, phrase, held in fills if held} - train_only  # a held-out half
    made = set(polarity_set("kitchen").half(False).sentences) - set(load_instructions("kitchen", "train").sentences)
    assert made and made <= train_only


def test_env_instructions_are_positive_training_ones_in_the_train_half():
    from talar_jax.language import load_instructions

    polar = polarity_set("kitchen")
    rows = {s: i for i, s in enumerate(polar.sentences)}
    for split, held in (("train", False), ("test", True)):
        for sentence in load_instructions("kitchen", split).sentences:
            assert polar.labels[rows[sentence]] == 0 and polar.held_out[rows[sentence]] == held


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


def test_fitting_is_deterministic():
    from talar_jax.confidence.polarity import PolarityConfig, fit_polarity, polarity_probabilities

    rng = np.random.default_rng(0)
    tokens = rng.normal(size=(24, 5, 8)).astype(np.float32)
    labels = np.arange(24) % 3
    tokens[np.arange(24), :, labels] += 4.0  # a learnable cue in every piece
    config = PolarityConfig(hidden=16, steps=150, batch_size=8, members=2, dropout=0.0)
    first = polarity_probabilities(fit_polarity(tokens, labels, config), tokens, config)
    again = polarity_probabilities(fit_polarity(tokens, labels, config), tokens, config)
    np.testing.assert_array_equal(first, again)
    assert (first.argmax(1) == labels).mean() > 0.9
