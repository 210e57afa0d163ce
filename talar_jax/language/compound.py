"""Compound instructions: one sentence that asks for several tasks in an order, with where each clause is.

Built from ``data/compound.json``: templates that join two clauses in either written order ("before you <2:do>,
<1>" asks for <1> first) and joins that place one unit after another, filled with the env's instructions and the
polarity sets' verb phrases. Each sentence records the character span of every clause in written order and the
order in which the clauses are to be done, which is what the clause parser (``talar_jax.clauses``) learns to read.
A few clauses are negations or opposites of their task (from the polarity sets): the parser must keep a "don't" or a
"close" inside its clause, so that the agent refuses the chain rather than doing the task.

The ``train`` half uses the train templates, joins, training instructions and train phrases; the ``held_out`` half
the held-out ones and the env's test instructions, so it measures constructions and phrasings the parser never read.
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Sequence
from functools import cache
from pathlib import Path

import numpy as np

from talar_jax.language.instructions import load_instructions
from talar_jax.language.polarity import LABELS, polarity_set, task_verb_phrases

COMPOUND_FILE = Path(__file__).resolve().parent / "data" / "compound.json"
SLOT = re.compile(r"<(\d)(\.|:do|:doing)?>")
UNIT = re.compile(r"<([ab])>")
CLAUSE_COUNTS = (1, 2, 2, 2, 3, 3, 4, 5, 6)
"""Clauses per sentence, drawn uniformly from this list: mostly pairs, single instructions kept so that a plain
sentence stays one clause, up to the kitchen's six tasks."""
NEGATED_SHARE = 0.1
"""Share of clauses filled with a negation or an opposite of their task."""
ROLE_SEPARATORS = (", ", ". ", "; ", " ")
"""What may stand between a clause and the connective of a role join (``role_join``)."""
ROLE_WORDS = (0, 1, 1, 2, 2, 3)
"""Words in a role join's connective, drawn uniformly from this list (0: the next clause simply follows)."""


@dataclasses.dataclass(frozen=True)
class CompoundSentence:
    """One compound instruction.

    Attributes:
        text: the sentence.
        spans: (start, end) character span of each clause, in written order.
        order: the written index of each clause, in the order the clauses are to be done.
        goals: the goal of each clause, in the order they are to be done.
        positive: per clause (in the order to be done), True when it asks for its goal, False for a negation or an
            opposite (an agent must then refuse the whole sentence).
    """

    text: str
    spans: tuple[tuple[int, int], ...]
    order: tuple[int, ...]
    goals: tuple[int, ...]
    positive: tuple[bool, ...]

    def clauses(self) -> tuple[str, ...]:
        """The clauses' text in the order they are to be done."""
        return tuple(self.text[slice(*self.spans[i])] for i in self.order)

    def segments(self) -> tuple[str, ...]:
        """The sentence cut where each clause begins, a clause keeping the words that join it to the one before
        ("then ...", "before you ..."), in the order the clauses are to be done: what the clause parser returns."""
        begins = clause_begins(self.text, self.spans)
        ends = [*begins[1:], len(self.text)]
        return tuple(self.text[begins[i] : ends[i]].strip(" ,;:.!?") for i in self.order)


def clause_begins(text: str, spans: Sequence[tuple[int, int]]) -> list[int]:
    """The character at which each clause (``spans``, in written order) begins, the words that join it to the clause
    before included: the first word after the previous clause (punctuation right after a clause stays with it, so
    "open it. Then ..." and "open it, then ..." are cut alike)."""
    begins = [0]
    for _, end in spans[:-1]:
        word = re.search(r"\w", text[end:])
        begins.append(end + word.start() if word else end)
    return begins


@cache
def _ingredients() -> dict:
    return json.loads(COMPOUND_FILE.read_text())


def _lowered(text: str) -> str:
    """The first letter in lower case (the pronoun "I" keeps its capital)."""
    return text if text[:2] in ("I ", "I'") else text[:1].lower() + text[1:]


def _fragment(sentence: str) -> str:
    """An instruction as a clause inside a longer sentence: no final punctuation, lower-case first letter."""
    return _lowered(sentence.strip().rstrip(".!?").rstrip())


class _Fillers:
    """Clause texts of one env and half, per goal: instructions (sentence slots), verb phrases (<k:do>, <k:doing>)
    and their negated / opposite versions."""

    def __init__(self, env: str, held_out: bool):
        instructions = load_instructions(env, "test" if held_out else "train")
        polarity = polarity_set(env).half(held_out)
        goals = sorted({int(g) for g in instructions.goal_ids})
        self.goals = goals
        self.sentences = {g: [] for g in goals}
        for sentence, goal in zip(instructions.sentences, instructions.goal_ids, strict=True):
            self.sentences[int(goal)].append(sentence)
        self.refusals = {g: [] for g in goals}
        for sentence, label, goal in zip(polarity.sentences, polarity.labels, polarity.goals, strict=True):
            if LABELS[label] != "positive" and int(goal) in self.refusals:
                self.refusals[int(goal)].append(sentence)
            elif not held_out and int(goal) in self.sentences and sentence not in self.sentences[int(goal)]:
                # the train half reads the polarity sets' positive sentences too ("Don't forget to ..."): more ways
                # a clause is worded than the env's training instructions alone; the held-out half keeps to the
                # env's test instructions, so that what it measures is the parser on the env's own phrasings
                self.sentences[int(goal)].append(sentence)
        self.verbs = {g: task_verb_phrases(env, g, undo=False, held_out=held_out) for g in goals}
        self.undo = {g: task_verb_phrases(env, g, undo=True, held_out=held_out) for g in goals}

    def clause(self, rng: np.random.Generator, goal: int, form: str, positive: bool) -> str:
        """A clause asking for ``goal`` (or, ``positive=False``, for not doing it / its opposite) in ``form``: '' (a
        fragment), '.' (a whole sentence) or ':do' / ':doing' (a verb phrase)."""
        if form in (":do", ":doing"):
            phrases = self.verbs[goal] if positive or not self.undo[goal] else self.undo[goal]
            base, gerund = phrases[rng.integers(len(phrases))]
            return base if form == ":do" else gerund
        pool = self.sentences[goal] if positive or not self.refusals[goal] else self.refusals[goal]
        sentence = pool[rng.integers(len(pool))]
        return sentence if form == "." else _fragment(sentence)


def _capitalised(text: str) -> str:
    return text[:1].upper() + text[1:]


def _fill(template: str, pattern: re.Pattern, values: dict[str, tuple[str, list]]) -> tuple[str, list]:
    """``template`` with each slot replaced by ``values[slot] = (text, clause spans inside text)``: the filled text
    and the clause spans shifted to their place, as (start, end, clause id)."""
    out, spans, position = [], [], 0
    for match in pattern.finditer(template):
        out.append(template[position : match.start()])
        offset = sum(len(part) for part in out)
        text, inner = values[match.group(0)]
        # a sentence starts with a capital, a clause inside one does not (whatever its source sentence had)
        text = _capitalised(text) if offset == 0 or out[-1].rstrip().endswith((".", "?", "!")) else _lowered(text)
        out.append(text)
        spans += [(offset + start, offset + end, clause) for start, end, clause in inner]
        position = match.end()
    out.append(template[position:])
    return "".join(out), spans


def role_join(rng: np.random.Generator, words: Sequence[str], first: str = "<a>", second: str = "<b>") -> str:
    """A join of ``first`` and ``second`` (done in that order) by a connective of random ``words``: a separator
    (``ROLE_SEPARATORS``) and ``ROLE_WORDS`` words, or nothing but the separator. It carries no meaning, so a parser
    fitted on it learns where a clause begins from the role of the words (a new request follows a finished one)
    rather than from the few connectives the templates spell; ``words`` are whole words of the encoder's own
    vocabulary, so nothing in it is a list of connectives."""
    separator = ROLE_SEPARATORS[rng.integers(len(ROLE_SEPARATORS))]
    count = int(rng.choice(ROLE_WORDS)) if len(words) else 0
    connective = " ".join(words[i] for i in rng.integers(len(words), size=count))
    if not connective:
        return f"{first}{separator}{second}"
    if separator.startswith("."):
        connective = _capitalised(connective)
    comma = "," if rng.random() < 0.5 else ""
    return f"{first}{separator}{connective}{comma} {second}"


def trimmed(rng: np.random.Generator, template: str, pattern: re.Pattern) -> str:
    """``template`` with one or more of the first words of the connective between its two slots left out ("<a>, and
    afterwards <b>" -> "<a>, afterwards <b>"), when the clause done first is written first (what is left of a
    connective in the order the clauses are done still keeps that order, or means nothing); else unchanged. The
    data's connectives put their telling word after "and" or "but": "afterwards" always continues a clause begun by
    "and", and a parser fitted on them alone does not cut at ". Afterwards," either."""
    slots = list(pattern.finditer(template))
    if len(slots) != 2 or slots[0].group(1) not in ("1", "a"):
        return template
    between = template[slots[0].end() : slots[1].start()]
    lead = between[: len(between) - len(between.lstrip(" ,;:.!?"))]
    words = between[len(lead) :].split()
    if not words:
        return template
    rest = " ".join(words[int(rng.integers(1, len(words) + 1)) :])
    sentence_slot = pattern is SLOT and slots[0].group(2) == "."  # "<1.>": the slot brings its own full stop
    if lead.strip().endswith((".", "?", "!")) or (sentence_slot and not lead.strip()):
        rest = _capitalised(rest)
    between = lead + rest + " " if rest else (lead if lead.endswith(" ") else lead + " ")
    return template[: slots[0].end()] + between + template[slots[1].start() :]


def _padded(rng: np.random.Generator, words: Sequence[str]) -> str:
    """A one-clause template with random ``words`` before or after the clause (which stays one clause: words that
    ask for nothing never begin one)."""
    filler = " ".join(words[i] for i in rng.integers(len(words), size=int(rng.integers(1, 3))))
    return f"{_capitalised(filler)}, <1>" if rng.random() < 0.5 else f"<1>, {filler}"


def _pair(
    rng,
    fillers: _Fillers,
    templates: list[str],
    clauses: list[tuple[int, bool]],
    first: int,
    words: Sequence[str] = (),
    role_share: float = 0.0,
    trim_share: float = 0.0,
):
    """A filled template for the clauses ``first`` (done first) and ``first + 1`` (or one clause alone); with
    ``role_share`` > 0, that share of them joined by ``role_join`` of ``words`` (one clause: padded with them), and
    ``trim_share`` of the others ``trimmed``."""
    role = role_share > 0 and rng.random() < role_share
    if len(clauses) == 1:
        goal, positive = clauses[0]
        form = "." if rng.random() < 0.5 else ""
        text = fillers.clause(rng, goal, form, positive)
        if not role:
            return text, [(0, len(text), first)]
        return _fill(_padded(rng, words), SLOT, {"<1>": (_fragment(text), [(0, len(_fragment(text)), first)])})
    if role:
        template = role_join(rng, words, "<1>", "<2>")
    else:
        template = templates[rng.integers(len(templates))]
        if trim_share > 0 and rng.random() < trim_share:
            template = trimmed(rng, template, SLOT)
    values = {}
    for match in SLOT.finditer(template):
        index = int(match.group(1)) - 1
        goal, positive = clauses[index]
        text = fillers.clause(rng, goal, match.group(2) or "", positive)
        values[match.group(0)] = (text, [(0, len(text), first + index)])
    return _fill(template, SLOT, values)


def compound_sentence(
    rng: np.random.Generator,
    fillers: _Fillers,
    half: str,
    goals: list[int],
    positive: list[bool],
    words: Sequence[str] = (),
    role_share: float = 0.0,
    trim_share: float = 0.0,
):
    """One sentence asking for ``goals`` in this order (``positive`` per clause); ``role_share`` of its templates and
    joins are ``role_join`` s of ``words`` and ``trim_share`` of the others ``trimmed`` (0: only the data's own,
    drawn exactly as before)."""
    ingredients = _ingredients()
    pairs, joins = ingredients["pairs"][half], ingredients["joins"][half]
    units, index = [], 0
    while index < len(goals):  # group the clauses into units of one or two, in the order they are done
        size = 2 if index + 1 < len(goals) and rng.random() < 0.6 else 1
        clauses = list(zip(goals[index : index + size], positive[index : index + size], strict=True))
        # a clause alone in a unit of a longer sentence is never padded: words after it would read as the next
        # clause's connective, and words before it as the end of the clause before
        share = role_share if size == 2 or len(goals) == 1 else 0.0
        units.append(_pair(rng, fillers, pairs, clauses, index, words, share, trim_share))
        index += size
    text, spans = units[0]
    for unit in units[1:]:
        if role_share > 0 and rng.random() < role_share:
            join = role_join(rng, words)
        else:
            join = joins[rng.integers(len(joins))]
            if trim_share > 0 and rng.random() < trim_share:
                join = trimmed(rng, join, UNIT)
        text = text.rstrip(".!?")  # the join brings its own punctuation
        spans = [(start, min(end, len(text)), clause) for start, end, clause in spans]
        text, spans = _fill(join, UNIT, {"<a>": (text, spans), "<b>": unit})
    text = _capitalised(text.strip())
    if not text.endswith((".", "?", "!")):
        text += "."
    spans = sorted(spans)
    written = [clause for _, _, clause in spans]
    return CompoundSentence(
        text=text,
        spans=tuple((start, end) for start, end, _ in spans),
        order=tuple(written.index(k) for k in range(len(goals))),
        goals=tuple(goals),
        positive=tuple(positive),
    )


def compound_sentences(env: str, goal_rows, held_out: bool = True, seed: int = 0) -> list[CompoundSentence]:
    """One sentence per row of ``goal_rows`` asking for its goals in that order, every clause positive, from one half
    (default: the held-out one: test instructions, held-out templates and joins). Deterministic for a seed."""
    rng = np.random.default_rng(seed)
    fillers = _Fillers(env, held_out)
    half = "held_out" if held_out else "train"
    return [compound_sentence(rng, fillers, half, [int(g) for g in row], [True] * len(row)) for row in goal_rows]


def compound_set(
    env: str,
    held_out: bool,
    count: int,
    seed: int = 0,
    negated_share: float = NEGATED_SHARE,
    words: Sequence[str] = (),
    role_share: float = 0.0,
    trim_share: float = 0.0,
):
    """``count`` compound sentences of ``env`` from one half (deterministic for a seed): distinct goals per sentence
    in random order, ``CLAUSE_COUNTS`` clauses each (at most the env's number of goals). With ``role_share`` > 0
    (the train half only), that share of the templates and joins are ``role_join`` s of ``words`` instead, and that
    share of the sentences of one clause are padded with ``words``; ``trim_share`` of the other templates and joins
    are ``trimmed``."""
    if (role_share and not len(words)) or (held_out and (role_share or trim_share)):
        raise ValueError("role joins and trimmed connectives are for the train half; role joins need words")
    rng = np.random.default_rng(seed)
    fillers = _Fillers(env, held_out)
    half = "held_out" if held_out else "train"
    out = []
    for _ in range(count):
        length = min(int(rng.choice(CLAUSE_COUNTS)), len(fillers.goals))
        goals = [int(g) for g in rng.choice(fillers.goals, length, replace=False)]
        positive = [bool(rng.random() >= negated_share) for _ in goals]
        out.append(compound_sentence(rng, fillers, half, goals, positive, words, role_share, trim_share))
    return out
