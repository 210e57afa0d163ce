"""The clause parser: a sentence that asks for several tasks becomes its clauses, in the order they are to be done.

A sentence-similarity encoder gives one vector per sentence, so "open the microwave, then switch on the light"
becomes one code and the agent does one thing. ``ClauseTagger`` reads the encoder's state of every word piece
instead and labels each piece twice: whether it begins a new clause (a clause keeps the words that join it to the
one before: ", then ...", "before you ...") and whether its clause is done where it is written, one place later
("before you switch on the light, open the microwave") or one place earlier ("... once you open the microwave").
The pieces' states are contextual, so "and" inside "fill the kettle and put it on the stove" reads differently
from "and" between two tasks. It is fitted on the project's compound instructions (``talar_jax.language.compound``)
and judged on their held-out half: templates, joins and phrasings it never read.

Arrays in, arrays out, plus ``parse_clauses`` for sentences; the agent loader reads the shipped parameters.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from talar_jax.language.bert import BertConfig, EncoderTop, top_and_head, with_pretrained_top
from talar_jax.language.compound import clause_begins

CONTINUES, BEGINS = range(2)
"""Whether a piece begins a new clause or continues the one before it."""
ASKS, JOINS = range(2)
"""Whether a piece is one of the words that ask for the clause's task or one that joins the clause to the others
("and then", "before you", "but ... first")."""
SHIFTS = (0, 1, -1)
"""What a clause's place in the order to be done is, against its written place: the same, one later, one earlier."""
LENGTH_BUCKET = 32
MIN_CLAUSE_PIECES = 3
"""The fewest word pieces a clause has (a task needs at least a verb and what it acts on)."""
STRIPPED = " ,;:.!?"
"""Punctuation and spaces around a clause's words, left out of its text."""


@dataclasses.dataclass(frozen=True)
class ClauseParserConfig:
    """How the tagger is built and fitted (chosen on the train half only: the held-out half measures it)."""

    tuned_layers: int = 1
    """The encoder's top layers fitted with the tagger, starting from the encoder's weights (0: the tagger reads the
    frozen last-layer states). The states were trained for sentence similarity, which says what a sentence is about
    rather than where one request ends: frozen, a tagger over them does not even fit its own train half."""
    hidden: int = 128
    """Width of the per-piece layers."""
    heads: int = 4
    """Self-attention heads of the attention layer over the pieces."""
    attention: bool = False
    """Add one trained attention layer over the pieces (False: each piece is labelled from its own state, which is
    already contextual; with tuned encoder layers the attention is theirs)."""
    dropout: float = 0.1
    """Dropout on the piece states while fitting."""
    steps: int = 1600
    """Adam steps."""
    batch_size: int = 32
    learning_rate: float = 1e-3
    """Of the tagger's own layers."""
    tuned_learning_rate: float = 2e-4
    """Of the tuned encoder layers: small, so that they move from what the encoder knows rather than forget it."""
    weight_decay: float = 1e-2
    seed: int = 0
    role_share: float = 0.3
    """Share of the train sentences' templates and joins replaced by connectives of random words of the encoder's
    vocabulary (``talar_jax.language.compound.role_join``; a sentence of one clause: padded with them). The train
    half spells a few dozen connectives, and a tagger fitted on them alone learns those words, then misses a cut at
    "Subsequently" or "Lastly"; joined by words that mean nothing, a cut is only found from the words' role: a new
    request begins after a finished one."""
    trim_share: float = 0.0
    """Share of the other templates and joins (where the clause done first is written first) whose connective loses
    its first words (``talar_jax.language.compound.trimmed``: "<a>, and afterwards <b>" -> "<a>, afterwards <b>"),
    so that a word like "afterwards" is also seen where a clause begins rather than only after "and" (the fitted
    parser gives ". Afterwards," a cut probability of 0.2 to 0.4, a random word 0.9). Not yet measured: 0 keeps the
    default the fit that was."""


class ClauseTagger(nn.Module):
    """(B, T, D) piece states, zero after a sentence's last piece -> (B, T, 2) boundary logits over (``CONTINUES``,
    ``BEGINS``), (B, T, 3) shift logits over ``SHIFTS`` and (B, T, 2) logits over (``ASKS``, ``JOINS``). With
    ``config.tuned_layers`` = k the states are those entering the encoder's last k layers, which run here as an
    ``EncoderTop`` (``encoder``: the encoder's config) fitted with the rest."""

    config: ClauseParserConfig
    encoder: BertConfig | None = None

    @nn.compact
    def __call__(self, pieces: jax.Array, train: bool = False) -> tuple[jax.Array, jax.Array]:
        mask = jnp.any(pieces != 0, axis=-1)  # (B, T)
        x = pieces
        if self.config.tuned_layers:
            first = self.encoder.num_hidden_layers - self.config.tuned_layers
            x = EncoderTop(self.encoder, first, name="top")(x, mask.astype(jnp.int32))
        x = nn.Dropout(self.config.dropout, deterministic=not train)(x)
        x = nn.gelu(nn.Dense(self.config.hidden)(x))
        # one attention layer over the pieces: a clause's shift is said by a word before it ("before you ...") or
        # after it ("... first"), possibly a clause away
        if self.config.attention:
            attended = nn.MultiHeadDotProductAttention(num_heads=self.config.heads)(
                nn.LayerNorm()(x), mask=nn.make_attention_mask(mask, mask)
            )
            x = x + attended
        x = x + nn.Dense(self.config.hidden)(nn.gelu(nn.Dense(self.config.hidden)(nn.LayerNorm()(x))))
        return nn.Dense(2)(x), nn.Dense(len(SHIFTS))(x), nn.Dense(2)(x)


@dataclasses.dataclass(frozen=True)
class Clause:
    """One clause of a sentence: its text and character span, its written index, where it goes in the order to be
    done (``rank``: its written index moved by its shift; clauses are done by increasing rank) and the tagger's
    probability that a clause begins where it begins (1 for the first); ``task``: its words that ask for its task,
    without those that join it to the others (None: all of them)."""

    text: str
    start: int
    end: int
    written: int
    rank: float = 0.0
    begins: float = 1.0
    task: str | None = None

    @property
    def asks(self) -> str:
        """What the agent translates: the clause without its joining words ("open the microwave" of "and then open
        the microwave"), which read as the single instructions the translator learned from."""
        return self.task or self.text


def piece_offsets(encoder, sentences: Sequence[str]) -> tuple[list[list[int]], list[list[tuple[int, int]]]]:
    """Word-piece ids (without [CLS]/[SEP]) and the character span of each piece, per sentence."""
    encodings = encoder.tokenizer.encode_batch(list(sentences), add_special_tokens=False)
    return [e.ids for e in encodings], [list(e.offsets) for e in encodings]


def piece_targets(encoder, sentences: Sequence) -> tuple[list[list[int]], np.ndarray, np.ndarray, np.ndarray]:
    """The model inputs (ids with [CLS]/[SEP]) and per-piece targets of ``CompoundSentence`` s: (N, T) boundary,
    (N, T) shift index and (N, T) ``ASKS`` / ``JOINS``, T = longest input; -1 on [CLS], [SEP] and padding. A piece
    joins when it lies outside its clause's own words (the instruction or phrase a template was filled with).

    A clause owns the words between it and the clause before it ("then", "before you", "once you"): each clause
    begins right after the previous one ends, so every piece belongs to one clause and no word is labelled as
    belonging to no clause (whether "Can you" of "Can you open it and then ..." belongs to the first task or to
    neither has no answer; that it does not begin a second one has)."""
    ids, offsets = piece_offsets(encoder, [s.text for s in sentences])
    length = max(len(row) for row in ids) + 2
    boundary = np.full((len(sentences), length), -1, np.int32)
    shift = np.full((len(sentences), length), -1, np.int32)
    joins = np.full((len(sentences), length), -1, np.int32)
    for row, (sentence, spans) in enumerate(zip(sentences, offsets, strict=True)):
        rank = {written: done for done, written in enumerate(sentence.order)}
        begins = clause_begins(sentence.text, sentence.spans)
        for piece, (start, _) in enumerate(spans):
            clause = int(np.searchsorted(begins, start, side="right")) - 1
            first = piece == 0 or spans[piece - 1][0] < begins[clause]
            boundary[row, piece + 1] = BEGINS if first else CONTINUES
            shift[row, piece + 1] = SHIFTS.index(int(np.clip(rank[clause] - clause, -1, 1)))
            own_start, own_end = sentence.spans[clause]
            joins[row, piece + 1] = ASKS if own_start <= start < own_end else JOINS
    return [encoder.with_specials(row) for row in ids], boundary, shift, joins


def piece_states(
    encoder, sequences: Sequence[Sequence[int]], dtype=np.float32, config: ClauseParserConfig | None = None
) -> np.ndarray:
    """(N, T, D) encoder states of every piece (zero after a sequence's end), T the longest sequence rounded up to
    ``LENGTH_BUCKET``; sequences of similar length are run together so that long ones do not pad short ones. With a
    ``config`` that tunes the encoder's top layers, the states entering them (what its tagger reads); else the last
    layer's."""
    below = None
    if config is not None and config.tuned_layers:
        below = encoder.config.num_hidden_layers - config.tuned_layers
    lengths = np.array([len(s) for s in sequences])
    width = -(-int(lengths.max()) // LENGTH_BUCKET) * LENGTH_BUCKET
    out = np.zeros((len(sequences), width, encoder.embedding_dim), dtype)
    buckets = -(-lengths // LENGTH_BUCKET) * LENGTH_BUCKET
    for bucket in np.unique(buckets):
        rows = np.flatnonzero(buckets == bucket)
        states = encoder.token_states([sequences[i] for i in rows], int(bucket), below_layer=below)
        out[rows, : int(bucket)] = states.astype(dtype)
    return out


def fit_clause_parser(
    states: np.ndarray,
    boundary: np.ndarray,
    shift: np.ndarray,
    joins: np.ndarray,
    config: ClauseParserConfig = ClauseParserConfig(),
    encoder=None,
    progress=None,
):
    """The tagger's parameters fitted on (N, T, D) piece states (``piece_states`` with this ``config``) and their
    (N, T') boundary, shift and joins targets (-1: no target; T' <= T); ``encoder`` gives the tuned layers' config and
    starting weights. ``progress(step, loss)`` is called every 100 steps when given. Deterministic for given
    inputs."""
    model = ClauseTagger(config, encoder.config if config.tuned_layers else None)
    width = states.shape[1]
    boundary = np.pad(boundary, ((0, 0), (0, width - boundary.shape[1])), constant_values=-1)
    shift = np.pad(shift, ((0, 0), (0, width - shift.shape[1])), constant_values=-1)
    joins = np.pad(joins, ((0, 0), (0, width - joins.shape[1])), constant_values=-1)

    def schedule(rate):
        return optax.warmup_cosine_decay_schedule(0.0, rate, max(config.steps // 20, 1), config.steps)

    optimizer = top_and_head(
        optax.adamw(schedule(config.tuned_learning_rate), weight_decay=config.weight_decay),
        optax.adamw(schedule(config.learning_rate), weight_decay=config.weight_decay),
    )

    def masked_mean(logits, targets):
        valid = targets >= 0
        loss = optax.softmax_cross_entropy_with_integer_labels(logits, jnp.maximum(targets, 0))
        return jnp.sum(loss * valid) / jnp.maximum(jnp.sum(valid), 1)

    @jax.jit
    def step(params, state, pieces, boundary_targets, shift_targets, joins_targets, key):
        def loss(p):
            boundary_logits, shift_logits, joins_logits = model.apply(p, pieces, train=True, rngs={"dropout": key})
            return (
                masked_mean(boundary_logits, boundary_targets)
                + masked_mean(shift_logits, shift_targets)
                + masked_mean(joins_logits, joins_targets)
            )

        value, grads = jax.value_and_grad(loss)(params)
        updates, state = optimizer.update(grads, state, params)
        return optax.apply_updates(params, updates), state, value

    key = jax.random.key(config.seed)
    params = model.init(key, jnp.asarray(states[:2], jnp.float32))
    if config.tuned_layers:
        first = encoder.config.num_hidden_layers - config.tuned_layers
        params = with_pretrained_top(params, encoder.params, first, ("top",))
    opt_state = optimizer.init(params)
    order = np.random.default_rng(config.seed)
    # each batch is drawn from sentences of one length bucket (the bucket drawn in proportion to its size, so every
    # sentence is as likely as before): a batch is then as long as its sentences, not as the longest one in it,
    # which matters when an encoder layer is fitted
    lengths = np.array([np.max(np.flatnonzero(row >= 0), initial=0) + 2 for row in boundary])
    buckets = np.minimum(-(-lengths // LENGTH_BUCKET) * LENGTH_BUCKET, width)
    sizes = np.unique(buckets)
    members = [np.flatnonzero(buckets == size) for size in sizes]
    weights = np.array([len(rows) for rows in members]) / len(buckets)
    for index in range(config.steps):
        bucket = int(order.choice(len(sizes), p=weights))
        rows = np.sort(
            order.choice(members[bucket], config.batch_size, replace=len(members[bucket]) < config.batch_size)
        )
        used = int(sizes[bucket])  # few shapes: few compilations
        params, opt_state, value = step(
            params,
            opt_state,
            jnp.asarray(states[rows, :used], jnp.float32),
            jnp.asarray(boundary[rows, :used]),
            jnp.asarray(shift[rows, :used]),
            jnp.asarray(joins[rows, :used]),
            jax.random.fold_in(key, index),
        )
        if progress is not None and (index + 1) % 100 == 0:
            progress(index + 1, float(value))
    return params


def stored(params):
    """The parameters as shipped: float16 (a tuned encoder layer is 7 MB in float32, half that in float16; the tagger
    is measured with the stored values, so what is shipped is what was measured)."""
    return jax.tree.map(lambda x: np.asarray(x, np.float16), params)


@functools.cache
def _tagger(config: ClauseParserConfig, encoder: BertConfig | None):
    model = ClauseTagger(config, encoder if config.tuned_layers else None)

    @jax.jit
    def probabilities(params, states):
        params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), params)
        return tuple(jax.nn.softmax(logits, -1) for logits in model.apply(params, states))

    return probabilities


def tag_pieces(params, states: np.ndarray, config: ClauseParserConfig = ClauseParserConfig(), encoder=None):
    """(N, T, 2) boundary, (N, T, 3) shift and (N, T, 2) joins probabilities of (N, T, D) piece states
    (``encoder``: its config when ``config`` tunes its top layers)."""
    probabilities = _tagger(config, encoder.config if encoder is not None and config.tuned_layers else None)
    return tuple(np.asarray(p) for p in probabilities(params, jnp.asarray(states, jnp.float32)))


def read_clauses(
    sentence: str,
    offsets: Sequence[tuple[int, int]],
    boundary: np.ndarray,
    shift: np.ndarray,
    joins: np.ndarray | None = None,
) -> list[Clause]:
    """The clauses of one sentence in the order they are to be done, from its pieces' character ``offsets`` and their
    (P, 2) boundary and (P, 3) shift probabilities (pieces only: no [CLS]/[SEP]). The first piece always begins a
    clause; a clause's text keeps its connective words and drops the punctuation around it. With (P, 2) ``joins``
    probabilities, each clause's ``task`` is its text from its first to its last piece more likely to ask than to
    join."""
    if not len(offsets):
        return [Clause(sentence.strip(), 0, len(sentence), 0)]
    starts = _cuts(boundary)
    clauses = []
    for written, (first, end) in enumerate(zip(starts, [*starts[1:], len(offsets)], strict=True)):
        rank = written + SHIFTS[int(np.argmax(shift[first:end].mean(axis=0)))]
        chance = 1.0 if first == 0 else float(boundary[first][BEGINS])
        clause = _clause(sentence, offsets[first][0], offsets[end - 1][1], written, rank, chance)
        asking = [] if joins is None else [p for p in range(first, end) if joins[p][ASKS] >= joins[p][JOINS]]
        if asking:
            task = _clause(sentence, offsets[asking[0]][0], offsets[asking[-1]][1], written, rank, chance).text
            clause = dataclasses.replace(clause, task=task if task and task != clause.text else None)
        clauses.append(clause)
    kept = [clause for clause in clauses if clause.text]
    return in_order(kept) or [Clause(sentence.strip(), 0, len(sentence), 0)]


def _cuts(boundary: np.ndarray) -> list[int]:
    """The pieces at which the clauses begin: the first piece, and each piece the tagger thinks more likely to begin
    a clause than not, taken from the surest down, unless a cut already taken lies fewer than
    ``MIN_CLAUSE_PIECES`` pieces away. Where the tagger is unsure which of two neighbouring words a clause begins
    at ("but | before that ...", "and | next ..."), it then cuts once, at the likelier one, instead of leaving a
    clause of one connective word."""
    pieces = len(boundary)
    likely = [p for p in range(1, pieces) if boundary[p][BEGINS] > boundary[p][CONTINUES]]
    starts = [0]
    for piece in sorted(likely, key=lambda p: -boundary[p][BEGINS]):
        if pieces - piece >= MIN_CLAUSE_PIECES and all(abs(piece - s) >= MIN_CLAUSE_PIECES for s in starts):
            starts.append(piece)
    return sorted(starts)


def _clause(sentence: str, start: int, stop: int, written: int, rank: float, begins: float) -> Clause:
    """The clause of ``sentence[start:stop]`` without the punctuation and spaces around it."""
    text = sentence[start:stop]
    stripped = text.strip(STRIPPED)
    start += len(text) - len(text.lstrip(STRIPPED))
    return Clause(stripped, start, start + len(stripped), written, rank, begins)


def in_order(clauses: Sequence[Clause]) -> list[Clause]:
    """``clauses`` in the order they are to be done: by rank, then as written."""
    return sorted(clauses, key=lambda clause: (clause.rank, clause.written))


def join_fragments(
    sentence: str, clauses: Sequence[Clause], names_nothing: Sequence[bool], below: float
) -> list[Clause] | None:
    """``clauses`` (in the order to be done) with one clause that names nothing (``names_nothing``, by the agent's
    verdict) joined to the written neighbour it is least sure to be cut from, when the tagger's probability of that
    cut is under ``below``: "Can you" cut from "start heating the water" is a piece of one request, while "make me
    a sandwich" after a confident cut stays a clause of its own (and the agent refuses the chain). None when there
    is nothing to join."""
    written = sorted(range(len(clauses)), key=lambda i: clauses[i].written)
    ordered = [clauses[i] for i in written]
    empty = [names_nothing[i] for i in written]
    for index, clause in enumerate(ordered):
        if not empty[index]:
            continue
        cuts = []  # (the tagger's probability of the cut, the neighbour's index) for each neighbour
        if index > 0:
            cuts.append((clause.begins, index - 1))
        if index + 1 < len(ordered):
            cuts.append((ordered[index + 1].begins, index + 1))
        if not cuts or min(cuts)[0] >= below:
            continue
        chance, other = min(cuts)
        first, last = sorted((index, other))
        partner = ordered[other]
        joined = _clause(
            sentence,
            ordered[first].start,
            ordered[last].end,
            ordered[first].written,
            partner.rank,
            ordered[first].begins,
        )
        merged = ordered[:first] + [joined] + ordered[last + 1 :]
        return in_order(merged)
    return None


def parse_clauses(
    params, encoder, sentences: Sequence[str], config: ClauseParserConfig = ClauseParserConfig()
) -> list[list[Clause]]:
    """Each sentence's clauses in the order they are to be done."""
    ids, offsets = piece_offsets(encoder, sentences)
    states = piece_states(encoder, [encoder.with_specials(row) for row in ids], config=config)
    boundary, shift, joins = tag_pieces(params, states, config, encoder)
    pieces = [slice(1, len(spans) + 1) for spans in offsets]
    return [
        read_clauses(sentence, spans, boundary[row, pieces[row]], shift[row, pieces[row]], joins[row, pieces[row]])
        for row, (sentence, spans) in enumerate(zip(sentences, offsets, strict=True))
    ]


def merge_repeated_tasks(sentence: str, clauses: Sequence[Clause], goals: Sequence[int | None]) -> list[Clause]:
    """``clauses`` (in the order to be done) with each run of clauses that are next to each other in the sentence and
    name the same task (``goals``, None: no task) joined into one: a chain never asks for one task twice in a row, so
    "I need some hot water. Can you put the kettle on?" cut in two is one task said twice."""
    out: list[Clause] = []
    last_goal, written = None, (-2, -2)  # the goal and the written indices (first, last) of the clause before
    for clause, goal in zip(clauses, goals, strict=True):
        if out and goal is not None and goal == last_goal and clause.written in (written[0] - 1, written[1] + 1):
            start, end = min(clause.start, out[-1].start), max(clause.end, out[-1].end)
            out[-1] = dataclasses.replace(
                out[-1],
                text=sentence[start:end],
                start=start,
                end=end,
                written=min(clause.written, written[0]),
                task=None,
            )
            written = (min(clause.written, written[0]), max(clause.written, written[1]))
        else:
            out.append(clause)
            written = (clause.written, clause.written)
        last_goal = goal
    return out
