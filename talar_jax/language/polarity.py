"""The polarity sets: sentences that ask for one of an env's tasks, ask not to do it, or ask for its opposite.

Built from ``data/polarity.json`` (frames such as "Don't {do}." or "Leave {state}." filled with each task's phrases)
and the env's own training and test instructions, which all ask for their task. Each sentence is in the ``train`` or
the ``held_out`` half: held out when its frame or its phrase is, so the held-out half measures phrasings and
constructions the polarity classifier never read. CLEVR's phrases name the balls of a goal; every frame and phrase is
filled for a few seeded goals rather than all 80, to keep the sets near the kitchen's size.
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections import Counter
from collections.abc import Sequence
from functools import cache
from pathlib import Path

import numpy as np

from talar_jax.language.instructions import load_instructions

POLARITY_FILE = Path(__file__).resolve().parent / "data" / "polarity.json"
LABELS: tuple[str, ...] = ("positive", "negated", "opposite")
"""What a sentence asks of its task: to do it, not to do it, or to undo it."""
UNKNOWN = "unknown"
CLASSES: tuple[str, ...] = (*LABELS, UNKNOWN)
"""What the polarity classifier tells apart: the three ``LABELS``, and a sentence that names something the env does
not have (``unknown_set``): another object, a colour no ball has, or one ball twice."""
UNKNOWN_HELD_OUT_WORDS = 3
"""Every third word of the swap vocabulary (in a seeded order) is held out: the held-out half of ``unknown_set``
swaps in words the classifier never read in that place."""
HALVES: tuple[str, ...] = ("train", "held_out")
DEVELOPMENT_FRAMES, DEVELOPMENT_PHRASES, DEVELOPMENT_INSTRUCTIONS = 5, 4, 5
"""The development split (``polarity_set(env, development=True)``) holds out every fifth train frame, every fourth
train phrase and every fifth training instruction: settings are compared there, so that the held-out half is read
once, by the classifier that ships."""
CLEVR_GOALS_PER_FILL = 3


@dataclasses.dataclass(frozen=True)
class PolaritySet:
    """Labelled sentences of one env.

    Attributes:
        env: the env.
        sentences: (S,) the sentences.
        labels: (S,) int32 index into ``LABELS``.
        goals: (S,) int32 the goal each sentence is about.
        held_out: (S,) bool, True for the held-out half.
    """

    env: str
    sentences: tuple[str, ...]
    labels: np.ndarray
    goals: np.ndarray
    held_out: np.ndarray

    def half(self, held_out: bool) -> PolaritySet:
        """The rows of one half."""
        rows = np.flatnonzero(self.held_out == held_out)
        return PolaritySet(
            self.env, tuple(self.sentences[i] for i in rows), self.labels[rows], self.goals[rows], self.held_out[rows]
        )


@cache
def _ingredients() -> dict:
    return json.loads(POLARITY_FILE.read_text())


def _sentence(frame: str, phrase: tuple[str, str] | str) -> str:
    """A frame filled with a verb phrase [base, gerund] or a state phrase; the first letter capitalised."""
    if isinstance(phrase, str):
        text = frame.replace("{state}", phrase)
    else:
        text = frame.replace("{do}", phrase[0]).replace("{doing}", phrase[1])
    return text[0].upper() + text[1:]


def _fills(label: str, task: dict) -> list[tuple[str, tuple[str, str] | str, bool, bool]]:
    """(frame, phrase, held out, developing) for every frame of ``label`` and every phrase it takes: held out when
    the frame or the phrase is in the held-out half; developing when it is in the train half and the frame or the
    phrase is in the development split's held-out share (``_developing``)."""
    frames = _ingredients()["frames"][label]
    verbs = task["do"] if label != "opposite" else task["undo"]
    out = []
    for frame_half, frame_list in frames.items():
        for frame_index, frame in enumerate(frame_list):
            # a state frame names the state the sentence is about: the task done for "Leave {state}." (positive) and
            # "Don't leave {state}." (negated), undone for the opposite's "Leave {state}."
            phrases = (task["undone"] if label == "opposite" else task["done"]) if "{state}" in frame else verbs
            for phrase_half, phrase_list in phrases.items():
                held = "held_out" in (frame_half, phrase_half)
                for phrase_index, p in enumerate(phrase_list):
                    developing = _developing(frame_index, DEVELOPMENT_FRAMES) or _developing(
                        phrase_index, DEVELOPMENT_PHRASES
                    )
                    out.append((frame, tuple(p) if isinstance(p, list) else p, held, not held and developing))
    return out


def _developing(index: int, every: int) -> bool:
    """Whether the train half's ``index``-th frame, phrase or instruction is in the development split's held-out
    share: every ``every``-th one, starting from the ``every``-th (so that the first phrase of a task, the one a
    verdict names, is always trained on)."""
    return index % every == every - 1


def polarity_set(env: str, development: bool = False) -> PolaritySet:
    """The env's polarity sentences (deterministic): the frames filled per task, and the env's training instructions
    (train half) and test instructions (held-out half) as ``positive``. With ``development``, the train half alone,
    its ``held_out`` marking the development split's held-out share (``DEVELOPMENT_FRAMES``)."""
    rows: list[tuple[str, int, int, bool, bool]] = []
    if env == "clevr":
        slots = clevr_slots()
        rng = np.random.default_rng(0)
        task = _ingredients()["clevr"]
        for label_index, label in enumerate(LABELS):
            for frame, phrase, held, developing in _fills(label, task):
                for goal in rng.choice(len(slots), CLEVR_GOALS_PER_FILL, replace=False):
                    text = _filled(_sentence(frame, phrase), slots[goal])
                    rows.append((text, label_index, int(goal), held, developing))
    else:
        names = kitchen_goal_names()
        for label_index, label in enumerate(LABELS):
            for name, task in _ingredients()[env].items():
                rows += [(_sentence(f, p), label_index, names.index(name), h, d) for f, p, h, d in _fills(label, task)]
    for split, held in (("train", False), ("test", True)):
        instructions = load_instructions(env, split)
        pairs = enumerate(zip(instructions.sentences, instructions.goal_ids, strict=True))
        rows += [(s, 0, int(g), held, not held and _developing(i, DEVELOPMENT_INSTRUCTIONS)) for i, (s, g) in pairs]
    trained = set(load_instructions(env, "train").sentences)
    unique = {}
    for row in rows:  # a sentence made twice keeps its first label; both halves: held out, but for a training
        first = unique.setdefault(row[0], row)  # instruction (the agent itself was trained on it)
        if row[3] and not first[3] and row[0] not in trained:
            unique[row[0]] = (*first[:3], True, False)
        elif row[0] in trained and first[3]:
            unique[row[0]] = (*first[:3], False, row[4])
        elif row[4] and not first[4] and not unique[row[0]][3]:  # developing when any of its makings is
            unique[row[0]] = (*unique[row[0]][:4], True)
    kept = [row for row in unique.values() if not (development and row[3])]
    sentences, labels, goals, held_out, developing = zip(*kept, strict=True)
    return PolaritySet(
        env,
        sentences,
        np.array(labels, np.int32),
        np.array(goals, np.int32),
        np.array(developing if development else held_out),
    )


def task_phrase(env: str, goal: int, goal_names: Sequence[str] | None = None) -> str:
    """A short verb phrase that asks for ``goal`` (the first phrase of its task in the polarity sets), for telling a
    person which task a sentence contradicts. ``goal_names``: the env's, when the caller already has its env."""
    if env == "clevr":
        return _filled(_ingredients()["clevr"]["do"]["train"][0][0], clevr_slots()[goal])
    name = (goal_names if goal_names is not None else kitchen_goal_names())[goal]
    return _ingredients()[env][name]["do"]["train"][0][0]


@cache
def clevr_slots() -> tuple[dict[str, str], ...]:
    """Per CLEVR goal id, the words its placeholders take ({subject}, {relation}, {object}), read through the env's
    public instruction format (a user pattern holding only the placeholders)."""
    import envs

    marker = "{subject}|{relation}|{object}"
    sentences, goals = envs.instruction_format("clevr").read_user({"clevr_patterns": [marker]}, POLARITY_FILE)
    slots = {
        int(g): dict(zip(("{subject}", "{relation}", "{object}"), s.split("|"), strict=True))
        for s, g in zip(sentences, goals, strict=True)
    }
    return tuple(slots[goal] for goal in range(len(slots)))


@cache
def kitchen_goal_names() -> tuple[str, ...]:
    """The kitchen's goal names by goal id, as its env lists them."""
    import envs

    return tuple(envs.make("kitchen").goal_names)


def _filled(text: str, slots: dict[str, str]) -> str:
    for slot, word in slots.items():
        text = text.replace(slot, word)
    return text


def task_verb_phrases(env: str, goal: int, undo: bool = False, held_out: bool = False) -> list[tuple[str, str]]:
    """The polarity sets' ``[base, gerund]`` verb phrases that do (``undo=False``) or undo ``goal`` in one half, for
    building sentences around a task (the compound instructions)."""
    if env == "clevr":
        phrases = _ingredients()["clevr"]["undo" if undo else "do"]["held_out" if held_out else "train"]
        return [(_filled(base, clevr_slots()[goal]), _filled(gerund, clevr_slots()[goal])) for base, gerund in phrases]
    task = _ingredients()[env][kitchen_goal_names()[goal]]
    return [tuple(p) for p in task["undo" if undo else "do"]["held_out" if held_out else "train"]]


def object_words(env: str) -> tuple[frozenset[str], ...]:
    """Per goal, the words that name what it acts on, found from the polarity data. CLEVR: the colours of the goal's
    two balls (``clevr_slots``). Kitchen: the words a task's done and undone states share (what stays when a task is
    undone is the thing it acts on: "the microwave open" / "the microwave closed"), less the words the states of half
    the tasks or more share ("the", "switched"), which name no one task's object."""
    if env == "clevr":
        return tuple(frozenset((slots["{subject}"], slots["{object}"])) for slots in clevr_slots())
    shared = []
    for name in kitchen_goal_names():
        task = _ingredients()[env][name]
        done, undone = (_words(" ".join(task[key]["train"])) for key in ("done", "undone"))
        shared.append(done & undone)
    counts = Counter(word for words in shared for word in words)
    return tuple(frozenset(w for w in words if 2 * counts[w] < len(shared)) for words in shared)


def swap_vocabulary(env: str, words: Sequence[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(train, held out) words to name something ``env`` does not have: ``words`` (e.g. the encoder's whole words,
    ``BertEncoder.whole_words``) less every word of the env's polarity sentences (its training and test instructions
    among them), split by a seeded order (every ``UNKNOWN_HELD_OUT_WORDS``-th held out)."""
    known = set().union(*(_words(s) for s in polarity_set(env).sentences))
    pool = sorted({w.lower() for w in words} - known)
    order = np.random.default_rng(0).permutation(len(pool))
    held = {pool[i] for i in order[::UNKNOWN_HELD_OUT_WORDS]}
    return tuple(w for w in pool if w not in held), tuple(w for w in pool if w in held)


def unknown_set(env: str, words: Sequence[str], development: bool = False) -> PolaritySet:
    """Sentences that name something ``env`` does not have, all labelled ``UNKNOWN`` (deterministic): every positive
    sentence of ``polarity_set`` with one word naming its goal's objects (``object_words``) swapped for a word of
    ``swap_vocabulary(env, words)`` of the sentence's half, and for CLEVR also the same sentence with its second ball
    given the first one's colour (no goal puts a ball beside itself). ``goals``: the goal of the sentence it was made
    from. With ``development``, the train half alone, its ``held_out`` marking the development share: sentences
    made from ``polarity_set``'s development share, or swapping in every fifth train word."""
    polar, developing_rows = polarity_set(env), polarity_set(env, development=True)
    developing = {s for s, d in zip(developing_rows.sentences, developing_rows.held_out, strict=True) if d}
    train_words, held_words = swap_vocabulary(env, words)
    objects = object_words(env)
    rng = np.random.default_rng(1)
    rows: dict[str, tuple[int, bool, bool]] = {}
    for sentence, label, goal, held in zip(polar.sentences, polar.labels, polar.goals, polar.held_out, strict=True):
        if label != 0:
            continue
        found = [m for m in re.finditer(r"[A-Za-z]+", sentence) if m.group().lower() in objects[goal]]
        if not found:
            continue
        pool = held_words if held else train_words
        index = int(rng.integers(len(pool)))
        word = pool[index]
        spot = found[int(rng.integers(len(found)))]
        made = [_replaced(sentence, spot, word)]
        if env == "clevr":
            first, second = clevr_slots()[goal]["{subject}"], clevr_slots()[goal]["{object}"]
            seconds = [m for m in found if m.group().lower() == second]
            if seconds and any(m.group().lower() == first for m in found):
                made.append(_replaced(sentence, seconds[-1], first))
        for text in made:
            developing_word = not held and index % DEVELOPMENT_FRAMES == DEVELOPMENT_FRAMES - 1
            rows.setdefault(text, (int(goal), bool(held), sentence in developing or developing_word))
    kept = [(s, g, h, d) for s, (g, h, d) in rows.items() if not (development and h)]
    return PolaritySet(
        env,
        tuple(s for s, *_ in kept),
        np.full(len(kept), CLASSES.index(UNKNOWN), np.int32),
        np.array([g for _, g, _, _ in kept], np.int32),
        np.array([d if development else h for _, _, h, d in kept], bool),
    )


def _words(text: str) -> set[str]:
    return set(re.findall(r"[a-z]+", text.lower()))


def _replaced(sentence: str, spot: re.Match, word: str) -> str:
    """``sentence`` with the word at ``spot`` replaced by ``word``, capitalised as it was."""
    word = word.capitalize() if spot.group()[0].isupper() else word
    return sentence[: spot.start()] + word + sentence[spot.end() :]
