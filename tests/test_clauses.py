"""Compound instructions and the clause parser: the data's labels, the decoding, and the shipped parser on held-out
compound sentences and plain instructions."""

from __future__ import annotations

import numpy as np
import pytest

from talar_jax.clauses import (
    BEGINS,
    CONTINUES,
    SHIFTS,
    Clause,
    merge_repeated_tasks,
    piece_offsets,
    piece_targets,
    read_clauses,
)
from talar_jax.language.compound import compound_set
from talar_jax.language.instructions import load_instructions


@pytest.mark.parametrize("env", ["kitchen", "clevr"])
def test_compound_sentences_know_their_clauses(env):
    sentences = compound_set(env, held_out=False, count=60, seed=3)
    assert sentences == compound_set(env, held_out=False, count=60, seed=3)  # deterministic
    assert {len(s.goals) for s in sentences} >= {1, 2, 3}
    for s in sentences:
        assert len(set(s.goals)) == len(s.goals)
        assert sorted(s.order) == list(range(len(s.goals)))
        spans = sorted(s.spans)
        assert all(end <= next_start for (_, end), (next_start, _) in zip(spans, spans[1:]))
        assert all(s.text[start:end].strip() for start, end in s.spans)
    reversed_order = [s for s in sentences if list(s.order) != sorted(s.order)]
    assert reversed_order, "some templates put the task done first after the other"


def test_held_out_half_uses_only_test_instructions():
    test = set(load_instructions("kitchen", "test").sentences)
    train = set(load_instructions("kitchen", "train").sentences)
    clauses = [c for s in compound_set("kitchen", held_out=True, count=200, seed=0) for c in s.clauses()]
    whole = [c for c in clauses if c.endswith((".", "?")) and c in test | train]
    assert whole and all(c in test for c in whole)


ROLE_WORDS = ("quartz", "harbor", "lilac")


def test_role_joins_are_random_words_where_a_clause_begins():
    plain = compound_set("kitchen", held_out=False, count=60, seed=3)
    assert compound_set("kitchen", held_out=False, count=60, seed=3, words=ROLE_WORDS) == plain  # share 0: as before
    role = compound_set("kitchen", held_out=False, count=60, seed=3, words=ROLE_WORDS, role_share=0.5)
    assert role == compound_set("kitchen", held_out=False, count=60, seed=3, words=ROLE_WORDS, role_share=0.5)
    assert role != plain
    with_words = [s for s in role if any(w in s.text.lower() for w in ROLE_WORDS)]
    several = [s for s in with_words if len(s.goals) > 1]
    assert several and any(len(s.goals) == 1 for s in with_words)  # joins, and one clause padded
    for s in several:  # a random word between two clauses belongs to the later one, never to a task's own words
        own = " ".join(s.clauses()).lower()
        assert not any(w in own.split() for w in ROLE_WORDS)
    with pytest.raises(ValueError):
        compound_set("kitchen", held_out=True, count=5, words=ROLE_WORDS, role_share=0.5)


def test_trimmed_connectives_lose_their_first_words_only_in_the_written_order():
    from talar_jax.language.compound import SLOT, UNIT, trimmed

    rng = np.random.default_rng(0)
    seen = {trimmed(rng, "<a>, and afterwards <b>", UNIT) for _ in range(40)}
    assert seen == {"<a>, afterwards <b>", "<a>, <b>"}
    assert {trimmed(rng, "<1.> After that, <2>", SLOT) for _ in range(40)} == {"<1.> That, <2>", "<1.> <2>"}
    # the clause done first written second: its connective says the order, and is kept whole
    assert trimmed(rng, "<2> after you <1:do>", SLOT) == "<2> after you <1:do>"
    trimmed_set = compound_set("kitchen", held_out=False, count=60, seed=3, trim_share=0.5)
    assert trimmed_set != compound_set("kitchen", held_out=False, count=60, seed=3)
    with pytest.raises(ValueError):
        compound_set("kitchen", held_out=True, count=5, trim_share=0.5)


def test_measuring_a_folder_without_a_parser_is_one_usage_error(tmp_path, capsys):
    from experiments.clauses import main

    assert main(["--parser", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "holds no clauses.json" in err and "Traceback" not in err


def test_the_role_joins_draw_whole_words():
    from talar_jax.language import load_encoder

    words = load_encoder(None).whole_words(min_length=2)  # what experiments.clauses joins clauses with
    assert len(words) > 10_000 and "microwave" in words
    assert all(w.isalpha() and len(w) > 1 for w in words) and not any(w.startswith("##") for w in words)


@pytest.mark.parametrize("share", [0.0, 0.5])
def test_piece_targets_mark_each_clause_and_its_shift(share):
    from talar_jax.language import load_encoder

    encoder = load_encoder(None)
    sentences = compound_set(
        "kitchen", held_out=False, count=40, seed=1, words=ROLE_WORDS, role_share=share, trim_share=share
    )
    sequences, boundary, shift, joins = piece_targets(encoder, sentences)
    for row, s in enumerate(sentences):
        pieces = len(sequences[row]) - 2
        labels = boundary[row, 1 : pieces + 1]
        assert labels[0] == BEGINS and np.sum(labels == BEGINS) == len(s.goals)
        assert boundary[row, 0] == -1 and np.all(boundary[row, pieces + 1 :] == -1)
        begun = np.flatnonzero(labels == BEGINS)
        written_shift = [SHIFTS[shift[row, 1 + p]] for p in begun]
        # the order to be done is the written order with each clause moved by its shift
        assert sorted(range(len(s.goals)), key=lambda i: (i + written_shift[i], i)) == list(s.order)
        # reading the targets back gives the sentence's own segments
        _, offsets = piece_offsets(encoder, [s.text])
        asks = joins[row, 1 : pieces + 1]
        clauses = read_clauses(
            s.text, offsets[0], _one_hot(labels, 2), _one_hot(shift[row, 1 : pieces + 1]), _one_hot(asks, 2)
        )
        assert tuple(c.text for c in clauses) == s.segments()
        # each clause's own words are what was put into the template, without the words that join it
        assert tuple(c.asks for c in clauses) == tuple(own.strip(" ,;:.!?") for own in s.clauses())


def _one_hot(labels, size=3):
    return np.eye(size)[np.maximum(labels, 0)]


def test_read_clauses_orders_by_shift_and_keeps_spans():
    from talar_jax.language import load_encoder

    sentence = "Before you switch on the light, open the microwave."
    _, offsets = piece_offsets(load_encoder(None), [sentence])
    offsets = offsets[0]
    words = [sentence[a:b] for a, b in offsets]
    second = words.index("open")
    boundary = [BEGINS if index in (0, second) else CONTINUES for index in range(len(words))]
    shift = [SHIFTS.index(1) if index < second else SHIFTS.index(-1) for index in range(len(words))]
    clauses = read_clauses(sentence, offsets, _one_hot(boundary, 2), _one_hot(shift))
    assert [c.text for c in clauses] == ["open the microwave", "Before you switch on the light"]
    assert [c.written for c in clauses] == [1, 0]
    assert sentence[clauses[0].start : clauses[0].end] == "open the microwave"
    whole = read_clauses(sentence, offsets, _one_hot([CONTINUES] * len(words), 2), _one_hot([0] * len(words)))
    assert [c.text for c in whole] == ["Before you switch on the light, open the microwave"]


def test_repeated_task_next_to_itself_is_one_clause():
    sentence = "I need some hot water. Can you put the kettle on? Then switch on the light."
    parts = ["I need some hot water", "Can you put the kettle on", "Then switch on the light"]
    clauses = [Clause(p, sentence.index(p), sentence.index(p) + len(p), k) for k, p in enumerate(parts)]
    merged = merge_repeated_tasks(sentence, clauses, [1, 1, 2])
    assert [c.text for c in merged] == ["I need some hot water. Can you put the kettle on", parts[2]]
    assert len(merge_repeated_tasks(sentence, clauses, [1, 2, 1])) == 3  # not next to each other: two asks
    assert len(merge_repeated_tasks(sentence, clauses, [None, None, 2])) == 3  # naming nothing is not one task


def _verdict(sentence, verdict, goal, reason=None):
    from talar_jax.confidence import Verdict

    return Verdict(sentence, verdict, goal, 0.9, ((goal if goal is not None else 0, 0.9),), 0.8, goal, reason=reason)


def test_plan_acts_only_when_every_clause_is_understood():
    from talar_jax.confidence import Plan

    names = ("microwave", "kettle", "light switch")
    acted = Plan("s", (_verdict("open the microwave", "understood", 0), _verdict("then the light", "understood", 2)))
    assert acted.acts and acted.goals == (0, 2) and acted.blocking is None
    record = acted.to_json(names, reached=[12, None])
    assert record["acted"] is True
    assert [(p["clause"], p["goal"], p["verdict"], p["reached_step"]) for p in record["plan"]] == [
        ("open the microwave", "microwave", "understood", 12),
        ("then the light", "light switch", "understood", None),
    ]
    refused = Plan(
        "s",
        (
            _verdict("open the microwave", "understood", 0),
            _verdict("but don't touch the kettle", "not understood", None, 'asks not to "move the kettle"'),
        ),
    )
    assert not refused.acts and refused.blocking == 1
    first_line = refused.describe(names).splitlines()[0]
    assert "clause 2 of 2" in first_line and "but don't touch the kettle" in first_line
    assert refused.to_json(names)["acted"] is False


def test_an_agent_without_a_parser_plans_one_clause_as_understand_judges_it():
    from talar_jax.agent import load

    agent = load("clevr")
    agent.clause_parser = None  # as for an encoder no shipped parser reads
    sentence = "Push the red ball behind the blue ball, then push the green ball in front of the cyan ball."
    assert agent.plan(sentence).steps == (agent.understand(sentence),)


def test_instruct_runs_a_chain_and_records_its_plan(tmp_path, capsys, monkeypatch):
    import json

    from experiments import instruct
    from talar_jax.agent import Agent
    from talar_jax.confidence import Plan

    clauses = ("Push the red ball behind the blue ball", "then push the green ball in front of the cyan ball")

    def two_clauses(agent, sentences):  # the chain path, whatever the parser makes of the sentence
        return [Plan(s, tuple(agent.judge(list(clauses)))) for s in sentences]

    monkeypatch.setattr(Agent, "plans", two_clauses)
    out = tmp_path / "chain.json"
    instruct.run_command(["clevr", " ".join(clauses), "--episodes", "3", "--json", str(out)])
    printed = capsys.readouterr().out
    record = json.loads(out.read_text())
    assert "plan: 2 tasks" in printed and record["acted"] is True
    assert [p["goal"] for p in record["plan"]] == [
        "red ball behind the blue ball",
        "green ball in front of the cyan ball",
    ]
    assert all(p["verdict"] == "understood" for p in record["plan"])
    assert all(p["reached_step"] is None or 0 < p["reached_step"] <= 100 for p in record["plan"])
    assert record["chains"]["length"] == 2 and record["chains"]["chains"] == 3


def test_a_clause_is_cut_once_where_the_tagger_hesitates_between_neighbouring_words():
    from talar_jax.clauses import MIN_CLAUSE_PIECES

    sentence = "open the microwave but before that switch on the light"
    words = sentence.split()
    offsets, position = [], 0
    for word in words:
        offsets.append((position, position + len(word)))
        position += len(word) + 1
    begins = np.full(len(words), 0.05)
    begins[0] = 1.0
    begins[words.index("but")] = 0.7  # both "but" and "before" look like the start of the second clause
    begins[words.index("before")] = 0.8
    boundary = np.stack([1 - begins, begins], axis=-1)
    clauses = read_clauses(sentence, offsets, boundary, _one_hot([0] * len(words)))
    assert [c.text for c in clauses] == ["open the microwave but", "before that switch on the light"]
    # a surer cut MIN_CLAUSE_PIECES words after "but" takes the place of "before", and "but" is far enough from both
    begins[words.index("but") + MIN_CLAUSE_PIECES] = 0.9
    clauses = read_clauses(sentence, offsets, np.stack([1 - begins, begins], axis=-1), _one_hot([0] * len(words)))
    cut = words.index("but") + MIN_CLAUSE_PIECES
    assert [c.text for c in clauses] == [
        "open the microwave",
        " ".join(words[words.index("but") : cut]),
        " ".join(words[cut:]),
    ]


def test_a_clause_is_judged_by_its_asking_words_unless_the_whole_clause_is_refused():
    from types import SimpleNamespace

    from talar_jax.agent import Agent

    refusal = 'asks not to "open the microwave"'
    verdicts = {
        "and then open the microwave": _verdict("and then open the microwave", "ambiguous", None),
        "open the microwave": _verdict("open the microwave", "understood", 0),
        "but don't open the microwave": _verdict("but don't open the microwave", "not understood", None, refusal),
        "switch on the light": _verdict("switch on the light", "understood", 2),
    }
    judged = []

    def judge(texts):
        judged.append(list(texts))
        return [verdicts[text] for text in texts]

    clauses = [
        Clause("and then open the microwave", 0, 27, 0, task="open the microwave"),
        Clause("but don't open the microwave", 28, 56, 1, task="open the microwave"),  # "don't" taken for joining
        Clause("switch on the light", 57, 76, 2),
    ]
    out = Agent._clause_verdicts(SimpleNamespace(judge=judge), clauses)
    assert [v.goal for v in out] == [0, None, 2]
    assert out[0].sentence == "open the microwave" and out[1].reason == refusal
    assert len(judged) == 1  # one batch: the whole clauses and their asking words together
