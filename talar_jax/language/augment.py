"""Paraphrase augmentation of training instructions for the translator, built from the training sentences alone.

The translator sees few distinct sentences (CLEVR: 720, kitchen: 60) and learns to map exactly those embeddings to a
task-language code; a phrasing it never saw (a polite request, a question, another word order) lands elsewhere in
embedding space and may translate to another code. ``paraphrase_variants`` makes new sentences that keep a training
sentence's meaning, using only the words of the training set:

* *function words* are the words that occur in the sentences of most goals (``function_fraction``): "please", "can",
  "you", "the", "is"; every other word (a colour, a relation, "microwave") is a *content word* and is never dropped,
  inserted or substituted, so a variant names the same goal as its source;
* each variant applies 1 to ``max_edits`` random edits: drop a function word, insert a function word, substitute a
  function word by another one seen in the same context (same left or right neighbour), swap two adjacent words,
  splice the sentence's opening function words onto another training sentence of the same goal from its first content
  word on, when both start their content with the same word ("Is there any" + "red ball is pushed behind the blue
  ball."), and, when given
  ``unknown_words`` (the encoder's vocabulary), replace a function word by a word no instruction uses, and, with
  ``front_phrases``, move the sentence's closing phrase (from the first content word of its second run of content
  words to the end) to its front: "Push the red ball behind the blue ball." -> "Behind the blue ball, push the red
  ball." (topicalisation: the same words, the reference named first).

Everything is a pure function of (sentences, goal ids, seed, excluded sentences): the same seed gives the same
variants. Test and development sentences never serve as material: the caller passes the training sentences only, and
the held-out ones only as ``exclude``, so that no variant happens to equal one (``tests/test_language.py``).
"""

from __future__ import annotations

import re
from collections import defaultdict
from collections.abc import Sequence

import numpy as np

_WORD = re.compile(r"\w+(?:'\w+)?|[^\w\s]")
EDITS: tuple[str, ...] = ("drop", "insert", "substitute", "swap", "splice", "replace", "front")


def words(sentence: str) -> list[str]:
    """The sentence split into lower-case words and punctuation marks."""
    return [w.lower() for w in _WORD.findall(sentence)]


def join_words(tokens: Sequence[str]) -> str:
    """Words back to a sentence (no space before punctuation; the first letter capitalised)."""
    text = ""
    for token in tokens:
        text += token if (not text or not token[0].isalnum() and token not in "(\"'") else " " + token
    return text[:1].upper() + text[1:]


def function_words(sentences: Sequence[str], goal_ids: Sequence[int], function_fraction: float = 0.5) -> set[str]:
    """Words (not punctuation) that occur in the sentences of more than ``function_fraction`` of the goals."""
    goals_of: dict[str, set[int]] = defaultdict(set)
    for sentence, goal in zip(sentences, goal_ids, strict=True):
        for word in words(sentence):
            goals_of[word].add(int(goal))
    num_goals = len(set(int(g) for g in goal_ids))
    return {w for w, goals in goals_of.items() if w[0].isalnum() and len(goals) > function_fraction * num_goals}


def _function_word_neighbours(tokenised: Sequence[list[str]], function: set[str]) -> dict[tuple[str, str], set[str]]:
    """("L", left word) / ("R", right word) -> the function words seen with that neighbour ("^" / "$": none)."""
    neighbours: dict[tuple[str, str], set[str]] = defaultdict(set)
    for tokens in tokenised:
        for i, word in enumerate(tokens):
            if word in function:
                neighbours["L", tokens[i - 1] if i else "^"].add(word)
                neighbours["R", tokens[i + 1] if i + 1 < len(tokens) else "$"].add(word)
    return neighbours


class _Editor:
    """The edits of ``paraphrase_variants`` over one set of training sentences; each draws from the caller's rng.

    An edit that does not apply (no function word to drop, no same-goal sentence to splice, ...) returns the tokens
    unchanged.
    """

    def __init__(
        self,
        tokenised: list[list[str]],
        goal_ids: list[int],
        function: set[str],
        unknown_words: Sequence[str],
        front_phrases: bool,
    ):
        self.tokenised = tokenised
        self.goal_ids = goal_ids
        self.function = function
        self.function_list = sorted(function)
        self.neighbours = _function_word_neighbours(tokenised, function)
        self.same_goal: dict[int, list[int]] = defaultdict(list)
        for row, goal in enumerate(goal_ids):
            self.same_goal[goal].append(row)
        self.unknown = sorted(set(unknown_words) - {w for tokens in tokenised for w in tokens})
        self.edits = tuple(e for e in EDITS if (e != "replace" or self.unknown) and (e != "front" or front_phrases))

    def is_content(self, word: str) -> bool:
        return word[0].isalnum() and word not in self.function and word not in self.unknown

    def edit(self, tokens: list[str], row: int, rng: np.random.Generator) -> list[str]:
        """One random edit of ``tokens`` (a variant of training sentence ``row``)."""
        kind = self.edits[rng.integers(len(self.edits))]
        apply = {
            "drop": self._drop,
            "insert": self._insert,
            "substitute": self._substitute,
            "swap": self._swap,
            "splice": self._splice,
            "replace": self._replace,
            "front": self._front,
        }[kind]
        return apply(tokens, row, rng)

    def _function_spots(self, tokens: list[str]) -> list[int]:
        return [i for i, w in enumerate(tokens) if w in self.function]

    def _drop(self, tokens: list[str], row: int, rng: np.random.Generator) -> list[str]:
        spots = self._function_spots(tokens)
        if len(spots) > 1:
            i = spots[rng.integers(len(spots))]
            return tokens[:i] + tokens[i + 1 :]
        return tokens

    def _insert(self, tokens: list[str], row: int, rng: np.random.Generator) -> list[str]:
        if self.function_list:
            i = int(rng.integers(len(tokens) + 1))
            return tokens[:i] + [self.function_list[rng.integers(len(self.function_list))]] + tokens[i:]
        return tokens

    def _substitute(self, tokens: list[str], row: int, rng: np.random.Generator) -> list[str]:
        spots = self._function_spots(tokens)
        if spots:
            i = spots[rng.integers(len(spots))]
            left, right = tokens[i - 1] if i else "^", tokens[i + 1] if i + 1 < len(tokens) else "$"
            options = sorted((self.neighbours["L", left] | self.neighbours["R", right]) - {tokens[i]})
            if options:
                return tokens[:i] + [options[rng.integers(len(options))]] + tokens[i + 1 :]
        return tokens

    def _swap(self, tokens: list[str], row: int, rng: np.random.Generator) -> list[str]:
        if len(tokens) > 2:
            i = int(rng.integers(len(tokens) - 1))
            if tokens[i][0].isalnum() and tokens[i + 1][0].isalnum():
                return tokens[:i] + [tokens[i + 1], tokens[i]] + tokens[i + 2 :]
        return tokens

    def _replace(self, tokens: list[str], row: int, rng: np.random.Generator) -> list[str]:
        spots = self._function_spots(tokens)
        if spots:
            i = spots[rng.integers(len(spots))]
            return tokens[:i] + [self.unknown[rng.integers(len(self.unknown))]] + tokens[i + 1 :]
        return tokens

    def _front(self, tokens: list[str], row: int, rng: np.random.Generator) -> list[str]:
        if "," in tokens:  # a fronted sentence has its comma: never front twice
            return tokens
        end = len(tokens) - (1 if tokens and not tokens[-1][0].isalnum() else 0)
        content = [i for i in range(end) if self.is_content(tokens[i])]
        starts = [i for i in content[1:] if not self.is_content(tokens[i - 1])]  # later runs of content words
        if starts:
            return tokens[starts[0] : end] + [","] + tokens[: starts[0]] + tokens[end:]
        return tokens

    def _splice(self, tokens: list[str], row: int, rng: np.random.Generator) -> list[str]:
        """This sentence's opening function words + a same-goal sentence from its first content word."""
        rows = self.same_goal[self.goal_ids[row]]
        other = self.tokenised[rows[rng.integers(len(rows))]]
        first, other_first = (next((i for i, w in enumerate(t) if self.is_content(w)), None) for t in (tokens, other))
        if first is not None and other_first is not None and tokens[first] == other[other_first]:
            return tokens[:first] + other[other_first:]
        return tokens


def _variants_of_row(
    editor: _Editor, row: int, num_variants: int, max_edits: int, held_out: set[tuple[str, ...]], seed: int
) -> list[str]:
    """The ``num_variants`` paraphrases of training sentence ``row``, drawn from its own rng ``[seed, row]``."""
    tokens = editor.tokenised[row]
    rng = np.random.default_rng([seed, row])
    out = []
    for _ in range(num_variants):
        for _attempt in range(20):
            current = list(tokens)
            for _ in range(int(rng.integers(1, max_edits + 1))):
                current = editor.edit(current, row, rng)
            if tuple(w for w in current if w[0].isalnum()) not in held_out:
                break
        else:
            current = tokens
        out.append(join_words(current))
    return out


def paraphrase_variants(
    sentences: Sequence[str],
    goal_ids: Sequence[int],
    num_variants: int,
    seed: int = 0,
    max_edits: int = 3,
    function_fraction: float = 0.5,
    exclude: Sequence[str] = (),
    unknown_words: Sequence[str] = (),
    front_phrases: bool = False,
) -> list[list[str]]:
    """``num_variants`` paraphrases of each training sentence (see the module docstring).

    Args:
        sentences: the training sentences (and only those).
        goal_ids: goal of each sentence (splices join sentences of the same goal only).
        num_variants: variants per sentence.
        seed: the augmentation's seed.
        max_edits: most edits per variant (each variant makes 1 to ``max_edits``).
        function_fraction: a word in the sentences of more than this fraction of goals is a function word.
        exclude: held-out sentences (test, development) no variant may equal, compared word by word: edits of
            training words can rebuild a test phrasing ("was moved" -> "was pushed"), which would then no longer be
            unseen. Such a variant is drawn again (up to 20 times; then the source sentence is used).
        unknown_words: words outside the instructions (e.g. ``BertEncoder.whole_words()``); if given, a sixth edit
            replaces a function word by one of them, so that the translator learns to ignore a word it has never
            seen in a function position ("nudging", "sphere"). Empty: that edit is never drawn.
        front_phrases: also draw the edit that moves the closing phrase to the front (module docstring).

    Returns:
        One list of ``num_variants`` sentences per input sentence (a variant may repeat its source when no edit
        applies, e.g. a one-word sentence).
    """
    if num_variants < 0 or max_edits < 1:
        raise ValueError(f"num_variants must be >= 0 and max_edits >= 1, got {num_variants}, {max_edits}")
    tokenised = [words(s) for s in sentences]
    goal_ids = [int(g) for g in goal_ids]
    function = function_words(sentences, goal_ids, function_fraction)
    editor = _Editor(tokenised, goal_ids, function, unknown_words, front_phrases)
    held_out = {tuple(w for w in words(s) if w[0].isalnum()) for s in exclude}
    return [_variants_of_row(editor, row, num_variants, max_edits, held_out, seed) for row in range(len(tokenised))]
