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


def _swap_words() -> list[str]:
    """Made-up words no env uses, and a few each env's instructions use (which must never be swapped in)."""
    return [a + b + "zq" for a in "bcdfg" for b in "aeiou"] + ["microwave", "kettle", "red", "ball", "open", "push"]


@pytest.mark.parametrize("env", ["kitchen", "clevr"])
def test_the_unknown_set_is_deterministic_and_swaps_in_only_words_the_env_never_uses(env):
    import re

    from talar_jax.language import load_instructions

    words = _swap_words()
    first, again = sets.unknown_set(env, words), sets.unknown_set(env, words)
    assert first.sentences == again.sentences and (first.held_out == again.held_out).all()
    assert (
        (first.labels == sets.CLASSES.index(sets.UNKNOWN)).all() and first.held_out.any() and not first.held_out.all()
    )
    train_words, held_words = sets.swap_vocabulary(env, words)
    used = {w for s in load_instructions(env, "train").sentences for w in re.findall(r"[a-z]+", s.lower())}
    assert not used & (set(train_words) | set(held_words)) and not set(train_words) & set(held_words)
    polar = polarity_set(env)
    rows = zip(polar.sentences, polar.labels, polar.goals, polar.held_out, strict=True)
    positives = {s: (g, h) for s, label, g, h in rows if label == 0}
    by_shape = {}
    for sentence in positives:
        by_shape.setdefault(len(sentence.split()), []).append(sentence)
    twice = 0
    for sentence, goal, held in zip(first.sentences, first.goals, first.held_out, strict=True):
        assert sentence not in positives
        # made from a positive sentence of its own half by changing one word that names its goal's objects
        tokens = sentence.split()
        sources = [s for s in by_shape[len(tokens)] if sum(a != b for a, b in zip(s.split(), tokens)) == 1]
        changes = [
            next(
                (re.sub(r"\W", "", a).lower(), re.sub(r"\W", "", b).lower())
                for a, b in zip(s.split(), tokens)
                if a != b
            )
            for s in sources
            if positives[s] == (goal, held)
        ]
        assert any(old in sets.object_words(env)[goal] for old, _ in changes)
        new = changes[0][1]
        if new in (held_words if held else train_words):
            continue
        twice += 1  # CLEVR: the second ball given the first one's colour
        assert env == "clevr" and new == sets.clevr_slots()[goal]["{subject}"]
    assert (twice > 0) == (env == "clevr")


def test_object_words_name_what_a_goal_acts_on():
    kitchen = dict(zip(sets.kitchen_goal_names(), sets.object_words("kitchen"), strict=True))
    assert (
        "microwave" in kitchen["microwave"] and "kettle" in kitchen["kettle"] and "cabinet" in kitchen["slide cabinet"]
    )
    assert not any("the" in words for words in kitchen.values())
    assert sets.object_words("clevr")[0] == {sets.clevr_slots()[0]["{subject}"], sets.clevr_slots()[0]["{object}"]}


def test_the_shipped_agents_refuse_held_out_sentences_naming_what_they_do_not_have(kitchen_agent):
    """Held-out swapped sentences (never read in fitting) are refused, saying why; thresholds below what the shipped
    classifier measured (results/abstention/polarity.md)."""
    from talar_jax import agent

    for name, loaded in (("kitchen", kitchen_agent), ("clevr", agent.load("clevr"))):
        half = sets.unknown_set(name, loaded.encoder.whole_words()).half(True)
        picked = list(half.sentences[:: max(1, len(half.sentences) // 60)])
        verdicts = loaded.judge(picked)
        assert np.mean([not v.acts for v in verdicts]) >= 0.9
        unknown = [v for v in verdicts if v.polarity == "unknown"]
        assert len(unknown) >= 0.7 * len(picked) and all(not v.acts for v in unknown)
        # said so where the agent would otherwise have acted or asked; one refused as naming no goal keeps that reason
        refused = [v for v in unknown if v.reason is not None]
        assert refused and all(v.reason == "names something this agent does not know" for v in refused)
        assert "does not know" in refused[0].describe(loaded.env.goal_names) and refused[0].to_json()["reason"]


def test_a_classifier_recorded_before_the_unknown_class_is_read_with_three(kitchen_agent, tmp_path):
    from talar_jax.agent import POLARITY_PARAMS, POLARITY_RECORD, SHIPPED_AGENTS_DIR, load_polarity

    record = json.loads((SHIPPED_AGENTS_DIR / POLARITY_RECORD).read_text())
    record["config"].pop("classes", None)
    record["labels"] = list(LABELS)
    (tmp_path / POLARITY_RECORD).write_text(json.dumps(record))
    (tmp_path / POLARITY_PARAMS).write_bytes((SHIPPED_AGENTS_DIR / POLARITY_PARAMS).read_bytes())
    assert load_polarity(kitchen_agent.encoder, tmp_path)[1].classes == len(LABELS)


def test_a_class_count_the_classifier_cannot_have_is_one_usage_error(capsys):
    from experiments import polarity as command
    from tests.helpers import one_line_error

    assert "--classes must be 3" in one_line_error(capsys, command.main, ["--classes", "5"])


def test_an_agent_refuses_as_unknown_only_past_its_own_threshold():
    from talar_jax.confidence.polarity import (
        NEGATED,
        OPPOSITE,
        POSITIVE,
        UNKNOWN,
        PolarityConfig,
        judged_classes,
    )

    config = PolarityConfig(act_threshold=0.5, unknown_threshold=0.9)
    four = np.array(
        [
            [0.6, 0.1, 0.1, 0.2],  # acted on
            [0.2, 0.1, 0.0, 0.7],  # unknown below its threshold counts with positive: acted on
            [0.05, 0.0, 0.0, 0.95],  # refused as unknown
            [0.3, 0.5, 0.1, 0.1],  # refused as negated
            [0.2, 0.1, 0.6, 0.1],  # refused as opposite
        ]
    )
    assert judged_classes(four, config).tolist() == [POSITIVE, POSITIVE, UNKNOWN, NEGATED, OPPOSITE]
    three = np.array([[0.5, 0.3, 0.2], [0.49, 0.3, 0.21], [0.1, 0.2, 0.7]])  # a classifier before the unknown class
    assert judged_classes(three, config).tolist() == [POSITIVE, NEGATED, OPPOSITE]
