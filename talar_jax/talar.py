"""TALAR's two supervised stages (Algorithms 1 and 2), jitted and vmapped over seeds.

1. ``train_task_language``: the TL generator and the receiver play the referential game (Eq. 2) on the task
   dataset, reading precomputed BERT prefix embeddings from the language cache (BERT is never called).
2. ``train_translator``: the translator learns to reproduce the frozen generator's TL from the sentence
   embedding of the tuple's instruction (Eq. 3).
``translate_instructions`` then turns every instruction of the cache into its TL: the lookup table the
instruction-following policy is conditioned on (Algorithm 3, via PPO's table conditioner).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from talar_jax.optim import AdamFit
from talar_jax.task_language import (
    Receiver,
    TaskLanguageGenerator,
    TaskLanguageSpec,
    Translator,
    decode_translation,
    receiver_logits_per_prefix,
    receiver_logits_per_token,
    referential_game_loss,
    translator_loss,
    translator_nll,
)


@dataclasses.dataclass(frozen=True)
class TalarConfig:
    """Hyper-parameters of the referential game and the translator. The class defaults are the paper's Table 2; the
    experiment commands start from their env recipe's values."""

    spec: TaskLanguageSpec = TaskLanguageSpec()
    """Task-language shape: N_pn predicates, N_a arguments, each argument a one-hot of arg_size."""
    generator_hidden: tuple[int, ...] = (128, 128)
    """Hidden layers of each argument and predicate network (Table 2: [128, 128, out], relu)."""
    receiver_hidden: tuple[int, ...] = (256,)
    """Hidden layers of the receiver on [L_T, BERT prefix embedding] (the paper: a fully-connected layer)."""
    receiver_prefix_dims: int | None = None
    """The receiver reads the prefix embedding's first ``receiver_prefix_dims`` principal components over the task
    dataset's prefixes (a fixed linear projection, ``prepare_referential_data``) instead of all D entries: a
    rank-limited first layer, several times cheaper. None: the whole embedding (the paper's)."""
    translator_hidden: tuple[int, ...] = (256, 256, 256, 256)
    """Translator MLP (Table 2: [256, 256, 256, 256, |L_T|], relu)."""
    gumbel_temperature: float = 1.0
    """Temperature of the straight-through Gumbel-softmax."""
    rg_learning_rate: float = 3e-4
    """LR for L_RG (Table 2)."""
    translator_learning_rate: float = 3e-4
    """LR for L_T (Table 2)."""
    batch_size: int = 256
    """Tuples per gradient step of the translator (and of the referential game unless rg_batch_size is set)."""
    rg_batch_size: int | None = None
    """Tuples per referential-game step (None: batch_size)."""
    rg_steps: int = 20_000
    """Gradient steps of the referential game."""
    rg_all_tokens: bool = False
    """Eq. 2's expectation over T_i computed exactly (every token of each tuple's instruction, one message per
    tuple) instead of one sampled token per tuple: same objective, lower-variance gradient."""
    rg_token_slots: int | None = None
    """With ``rg_all_tokens``: at most this many of a tuple's tokens per step instead of the longest instruction's
    count. Instructions with more tokens contribute a systematic sample of them (K evenly spaced positions from a
    random start, each token drawn with probability K / count), shorter ones every token, so the per-tuple mean NLL
    stays an unbiased estimate of Eq. 2's expectation over T_i while padding slots (and their receiver rows) go.
    None: every token slot of the longest instruction."""
    translator_steps: int = 10_000
    """Gradient steps of the translator."""
    behaviour_cloning_steps: int | None = None
    """Gradient steps of the pre-trained BERT-* baselines' behaviour cloning (None: ``translator_steps``)."""
    behaviour_cloning_learning_rate: float | None = None
    """Adam LR of that behaviour cloning (None: ``translator_learning_rate``). A recipe that shortens its translator
    pins these two so that the baselines keep their budget."""
    translator_full_batch: bool = False
    """Each translator step takes the exact expected loss over the whole task dataset instead of a ``batch_size``
    sample of tuples: one row per distinct instruction (and per paraphrase), whose target is the mean TL of the
    instruction's tuples, weighted by their share (Eq. 3 is linear in the target, so this is the same objective
    without sampling noise; ``batch_size`` is then unused by the translator). False: the paper's sampled batches."""
    translator_paraphrases: int = 0
    """Paraphrases per training instruction the translator also learns from (``talar_jax.language.augment``: edits
    of function words, word order and splices of same-goal training sentences; 0: the paper's translator)."""
    paraphrase_probability: float = 0.5
    """Chance that a translator batch row reads one of its instruction's paraphrases instead of the instruction."""
    paraphrase_seed: int = 0
    """Seed of the paraphrases (the same seed gives the same sentences)."""
    paraphrase_unknown_words: bool = False
    """Paraphrases may also replace a function word by a word of the encoder's vocabulary no instruction uses."""
    paraphrase_front_phrases: bool = False
    """Paraphrases may also move the sentence's closing phrase to its front ("Behind the blue ball, push the red
    ball."), so the translator meets the reference named before the ball to move."""
    translator_tokens: bool = False
    """The translator reads the encoder's state of every word piece (``TOKEN_READOUT``) through attention pooling
    instead of the experiment's one-vector sentence readout (the paper's BERT embedding -> MLP). Baselines that feed
    NL encodings to the policy keep the sentence readout."""
    finetuned_bert_first_layer: int = 0
    """The fine-tuned BERT-* baselines (Appendix E.5) train BERT's encoder layers from this one up, and its
    embeddings when 0 (the paper's: all of BERT); the layers below keep their pre-trained weights and run once."""

    @property
    def bc_steps(self) -> int:
        """Behaviour-cloning steps: ``behaviour_cloning_steps``, else ``translator_steps``."""
        return self.behaviour_cloning_steps or self.translator_steps

    @property
    def bc_learning_rate(self) -> float:
        """Behaviour-cloning LR: ``behaviour_cloning_learning_rate``, else ``translator_learning_rate``."""
        return self.behaviour_cloning_learning_rate or self.translator_learning_rate

    @property
    def referential_batch_size(self) -> int:
        """Tuples per referential-game step: ``rg_batch_size``, else ``batch_size``."""
        return self.rg_batch_size or self.batch_size

    def referential_game_fields(self) -> dict[str, Any]:
        """Every setting the referential game reads (the generator's included): its stage key's share."""
        return {
            "spec": self.spec,
            "generator_hidden": self.generator_hidden,
            "receiver_hidden": self.receiver_hidden,
            **({"receiver_prefix_dims": self.receiver_prefix_dims} if self.receiver_prefix_dims else {}),
            "gumbel_temperature": self.gumbel_temperature,
            "rg_learning_rate": self.rg_learning_rate,
            "referential_batch_size": self.referential_batch_size,
            "rg_steps": self.rg_steps,
            "rg_all_tokens": self.rg_all_tokens,
            **({"rg_token_slots": self.rg_token_slots} if self.rg_token_slots else {}),
        }

    def translator_fields(self) -> dict[str, Any]:
        """Every setting a translator reads (its target spec comes with the targets): its stage key's share."""
        return {
            "translator_hidden": self.translator_hidden,
            "translator_learning_rate": self.translator_learning_rate,
            **({"translator_full_batch": True} if self.translator_full_batch else {"batch_size": self.batch_size}),
            "translator_steps": self.translator_steps,
            **({"translator_tokens": True} if self.translator_tokens else {}),
            **(
                {
                    "translator_paraphrases": self.translator_paraphrases,
                    "paraphrase_probability": self.paraphrase_probability,
                    "paraphrase_seed": self.paraphrase_seed,
                    **({"paraphrase_unknown_words": True} if self.paraphrase_unknown_words else {}),
                    **({"paraphrase_front_phrases": True} if self.paraphrase_front_phrases else {}),
                }
                if self.translator_paraphrases
                else {}
            ),
        }

    def __post_init__(self):
        for name in (
            "batch_size",
            "rg_steps",
            "translator_steps",
            "rg_batch_size",
            "receiver_prefix_dims",
            "rg_token_slots",
            "behaviour_cloning_steps",
        ):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"TalarConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.translator_paraphrases < 0 or not 0.0 <= self.paraphrase_probability <= 1.0:
            raise ValueError(
                "TalarConfig.translator_paraphrases must be >= 0 and paraphrase_probability in [0, 1], got "
                f"{self.translator_paraphrases}, {self.paraphrase_probability}"
            )


class TaskLanguageData(NamedTuple):
    """Device arrays of the task dataset joined with the language cache (shared by all seeds).

    Attributes:
        states: (N, obs) s_i.
        final_states: (N, obs) s_T of the same episode.
        sentence_ids: (N,) row of the instruction L_N in the cache.
        sentence_embeddings: (S, F) the translator's input per cached sentence (``cache.sentence_features``).
        prefix_embeddings: (P, D) BERT embedding of every prefix T_1..T_{i-1}.
        prefix_next_token: (P,) index of T_i in the task vocabulary.
        sentence_prefix_start: (S,) first prefix row of each sentence.
        sentence_prefix_count: (S,) number of prefixes (tokens) of each sentence.
        dataset_sentences: (U,) the distinct cache rows the tuples' instructions use.
        tuple_sentence: (N,) row of each tuple's instruction in ``dataset_sentences``.
        prefix_table: (Q, D) the distinct prefix embeddings of the ``dataset_sentences``.
        prefix_table_index: (P,) row of each prefix in ``prefix_table`` (0 for prefixes of unused sentences).
        sentence_variants: None, or (S, K) rows of ``sentence_embeddings`` holding K paraphrases of each sentence
            (``with_paraphrases``; a sentence without paraphrases lists its own row), read by the translator only.

    The last four let a step compute a layer once per distinct sentence or prefix instead of once per sampled
    row when that is fewer rows (the kitchen's 60 training instructions against 256-tuple batches): the same
    numbers, less work.
    """

    states: jax.Array
    final_states: jax.Array
    sentence_ids: jax.Array
    sentence_embeddings: jax.Array
    prefix_embeddings: jax.Array
    prefix_next_token: jax.Array
    sentence_prefix_start: jax.Array
    sentence_prefix_count: jax.Array
    dataset_sentences: jax.Array
    tuple_sentence: jax.Array
    prefix_table: jax.Array
    prefix_table_index: jax.Array
    sentence_variants: jax.Array | None = None


def make_task_language_data(dataset: Any, cache: Any, readout: str = "sentence") -> TaskLanguageData:
    """Joins a ``TaskDataset`` (states, final_states, instruction_ids) with an ``EmbeddingCache``.

    ``readout`` picks the sentence features translators read (``EmbeddingCache.sentence_features``).
    """
    sentence_ids = np.asarray(dataset.instruction_ids, np.int32)
    if sentence_ids.size == 0:
        raise ValueError("the task dataset is empty")
    if sentence_ids.min() < 0 or sentence_ids.max() >= len(cache.sentences):
        raise ValueError(
            f"task dataset instruction ids span [{sentence_ids.min()}, {sentence_ids.max()}] but the language cache "
            f"has {len(cache.sentences)} sentences: dataset and cache come from different instruction sets"
        )
    return build_task_language_data(
        states=dataset.states,
        final_states=dataset.final_states,
        sentence_ids=sentence_ids,
        sentence_embeddings=cache.sentence_features(readout),
        prefix_embeddings=cache.prefix_embeddings,
        prefix_next_token=cache.prefix_next_token_compact,
        sentence_prefix_start=cache.sentence_prefix_start,
        sentence_prefix_count=cache.sentence_prefix_count,
    )


def build_task_language_data(
    states,
    final_states,
    sentence_ids,
    sentence_embeddings,
    prefix_embeddings,
    prefix_next_token,
    sentence_prefix_start,
    sentence_prefix_count,
) -> TaskLanguageData:
    """``TaskLanguageData`` on the device from its first eight fields (numpy); the lookup tables are derived."""
    sentence_ids = np.asarray(sentence_ids, np.int32)
    prefix_embeddings = np.asarray(prefix_embeddings, np.float32)
    sentence_prefix_start = np.asarray(sentence_prefix_start, np.int32)
    sentence_prefix_count = np.asarray(sentence_prefix_count, np.int32)
    dataset_sentences, tuple_sentence = np.unique(sentence_ids, return_inverse=True)
    starts, counts = sentence_prefix_start[dataset_sentences], sentence_prefix_count[dataset_sentences]
    used_prefixes = np.concatenate([np.arange(start, start + count) for start, count in zip(starts, counts)])
    prefix_table, table_rows = np.unique(prefix_embeddings[used_prefixes], axis=0, return_inverse=True)
    prefix_table_index = np.zeros(len(prefix_embeddings), np.int32)
    prefix_table_index[used_prefixes] = table_rows.reshape(-1)
    return TaskLanguageData(
        states=jnp.asarray(states, jnp.float32),
        final_states=jnp.asarray(final_states, jnp.float32),
        sentence_ids=jnp.asarray(sentence_ids),
        sentence_embeddings=jnp.asarray(sentence_embeddings, jnp.float32),
        prefix_embeddings=jnp.asarray(prefix_embeddings),
        prefix_next_token=jnp.asarray(prefix_next_token, jnp.int32),
        sentence_prefix_start=jnp.asarray(sentence_prefix_start),
        sentence_prefix_count=jnp.asarray(sentence_prefix_count),
        dataset_sentences=jnp.asarray(dataset_sentences, jnp.int32),
        tuple_sentence=jnp.asarray(tuple_sentence.reshape(-1), jnp.int32),
        prefix_table=jnp.asarray(prefix_table, jnp.float32),
        prefix_table_index=jnp.asarray(prefix_table_index),
    )


def prepare_referential_data(config: TalarConfig, data: TaskLanguageData) -> TaskLanguageData:
    """The referential game's view of ``data``: with ``config.receiver_prefix_dims = k``, every prefix embedding is
    replaced by its coordinates on the first k principal axes of ``data.prefix_table`` (the distinct prefixes of the
    task dataset's instructions, so only training sentences shape it), centred on their mean. The receiver's first
    layer then multiplies k inputs instead of D (k is capped at the number of distinct prefixes and at D, where the
    projection is a rotation). Without ``receiver_prefix_dims`` ``data`` is returned unchanged."""
    if not config.receiver_prefix_dims:
        return data
    table = np.asarray(data.prefix_table, np.float64)
    dims = min(config.receiver_prefix_dims, *table.shape)  # no more axes than distinct prefixes or entries
    mean = table.mean(0)
    _, _, axes = np.linalg.svd(table - mean, full_matrices=False)
    basis = axes[:dims].T
    basis *= np.where(basis[np.abs(basis).argmax(0), np.arange(dims)] < 0, -1.0, 1.0)  # a fixed sign per axis

    def project(x):
        return jnp.asarray((np.asarray(x, np.float64) - mean) @ basis, jnp.float32)

    return data._replace(prefix_embeddings=project(data.prefix_embeddings), prefix_table=project(data.prefix_table))


def sample_referential_batch(
    rng_rows: jax.Array, rng_prefix: jax.Array, data: TaskLanguageData, batch_size: int
) -> tuple[jax.Array, jax.Array]:
    """(rows, prefix): random tuples and, per tuple, one prefix row T_1..T_{i-1} of its instruction.

    T_i is drawn uniformly from the tokens of the instruction (paper: "randomly sampled").
    """
    rows = jax.random.randint(rng_rows, (batch_size,), 0, data.states.shape[0])
    sentences = data.sentence_ids[rows]
    offset = jax.random.randint(rng_prefix, rows.shape, 0, data.sentence_prefix_count[sentences])
    return rows, data.sentence_prefix_start[sentences] + offset


def referential_token_rows(
    rows: jax.Array, data: TaskLanguageData, max_tokens: int, rng: jax.Array | None = None, slots: int | None = None
) -> tuple[jax.Array, jax.Array]:
    """(prefix, mask), both (B, T): prefix rows T_1..T_{i-1} of each tuple's instruction, and which of the T slots
    are real tokens (instructions shorter than T are padded).

    Without ``slots`` (or with ``slots >= max_tokens``) T = ``max_tokens`` and every token is listed. With
    ``slots = K < max_tokens`` T = K: an instruction of c > K tokens lists the systematic sample
    ``floor((k + u) c / K)``, k = 0..K-1, u ~ U[0, 1) per tuple (``rng``), which draws each token with probability
    K / c, so the mean over the K slots is an unbiased estimate of the mean over the c tokens; c <= K lists all."""
    sentences = data.sentence_ids[rows]
    counts = data.sentence_prefix_count[sentences][:, None]
    width = min(slots or max_tokens, max_tokens)
    offsets = jnp.arange(width)[None, :]
    positions = offsets
    if width < max_tokens:
        if rng is None:
            raise ValueError("referential_token_rows with slots needs rng for the systematic sample")
        start = jax.random.uniform(rng, counts.shape)
        sampled = jnp.floor((offsets + start) * counts / width).astype(jnp.int32)
        # float32 rounding can reach c itself when u is within 2^-24 of 1
        positions = jnp.where(counts > width, jnp.minimum(sampled, counts - 1), offsets)
    mask = offsets < counts  # every slot of an instruction longer than ``width`` is real
    return data.sentence_prefix_start[sentences][:, None] + jnp.where(mask, positions, 0), mask


def decodable_fraction(codes: np.ndarray, labels: np.ndarray, vote: np.ndarray, score: np.ndarray) -> float:
    """Fraction of the ``score`` rows whose code names their label: the label most ``vote`` rows with that code have.

    Args:
        codes: (N, |L|) discrete codes; labels: (N,) int; vote, score: (N,) bool row masks.
    """
    keys = [row.tobytes() for row in np.asarray(codes).round().astype(np.int8)]
    votes: dict[bytes, Counter] = {}
    for i in np.flatnonzero(vote):
        votes.setdefault(keys[i], Counter())[int(labels[i])] += 1
    named = {key: counter.most_common(1)[0][0] for key, counter in votes.items()}
    hits = [named.get(keys[i]) == int(labels[i]) for i in np.flatnonzero(score)]
    return float(np.mean(hits)) if hits else float("nan")


def _generator(config: TalarConfig) -> TaskLanguageGenerator:
    return TaskLanguageGenerator(config.spec, config.generator_hidden, config.gumbel_temperature)


def make_train_task_language(config: TalarConfig, vocab_size: int, max_tokens: int | None = None) -> AdamFit:
    """The referential game as an ``AdamFit`` over ``data``: ``fit(rng, data) -> (params, losses)`` (vmap over seeds).

    ``data`` is ``prepare_referential_data(config, data)`` (the same as ``data`` unless ``receiver_prefix_dims``).

    ``params = {"generator": ..., "receiver": ...}``; ``losses``: (rg_steps,) L_RG per step. ``max_tokens``
    (the longest instruction's token count) is needed with ``config.rg_all_tokens``.
    """
    init_params, loss_and_rows = _referential_game(config, vocab_size, max_tokens)

    def loss_fn(params, rng, data: TaskLanguageData):
        return loss_and_rows(params, rng, data)[0]

    return AdamFit(init_params, loss_fn, config.rg_learning_rate, config.rg_steps)


def _referential_game(config: TalarConfig, vocab_size: int, max_tokens: int | None):
    """``(init_params(rng, data), loss_and_rows(params, rng, data) -> (L_RG, the tuples the step drew))``."""
    generator, receiver = _generator(config), Receiver(vocab_size, config.receiver_hidden)
    if config.rg_all_tokens and (max_tokens is None or max_tokens < 1):
        raise ValueError("rg_all_tokens needs max_tokens, the token count of the longest instruction")

    def loss_and_rows(params, rng, data: TaskLanguageData) -> tuple[jax.Array, jax.Array]:
        rng_batch, rng_prefix, rng_gumbel = jax.random.split(rng, 3)
        rows, prefix = sample_referential_batch(rng_batch, rng_prefix, data, config.referential_batch_size)
        task_language = generator.apply(params["generator"], data.states[rows], data.final_states[rows], rng_gumbel)
        if not config.rg_all_tokens:
            logits = receiver.apply(params["receiver"], task_language, data.prefix_embeddings[prefix])
            return referential_game_loss(logits, data.prefix_next_token[prefix]), rows
        # rng_prefix drew the one-token prefix above, unused here: it draws the systematic sample's start instead
        prefix, mask = referential_token_rows(rows, data, max_tokens, rng_prefix, config.rg_token_slots)
        if data.prefix_table.shape[0] < prefix.size:  # fewer distinct prefixes than rows: first layer per prefix
            logits = receiver_logits_per_prefix(
                params["receiver"], task_language, data.prefix_table, data.prefix_table_index[prefix]
            )
        else:
            logits = receiver_logits_per_token(params["receiver"], task_language, data.prefix_embeddings[prefix])
        return referential_game_loss(logits, data.prefix_next_token[prefix], mask), rows

    def init_params(rng: jax.Array, data: TaskLanguageData):
        if config.receiver_prefix_dims and data.prefix_embeddings.shape[-1] > config.receiver_prefix_dims:
            raise ValueError(
                f"receiver_prefix_dims={config.receiver_prefix_dims} but the prefix embeddings have "
                f"{data.prefix_embeddings.shape[-1]} entries: pass prepare_referential_data(config, data)"
            )
        rng_generator, rng_receiver = jax.random.split(rng)
        obs = data.states[:1]
        return {
            "generator": generator.init(rng_generator, obs, obs, None),
            "receiver": receiver.init(rng_receiver, jnp.zeros((1, config.spec.size)), data.prefix_embeddings[:1]),
        }

    return init_params, loss_and_rows


def make_train_end_to_end(config: TalarConfig, vocab_size: int, max_tokens: int | None = None) -> AdamFit:
    """End-to-end TALAR (paper Appendix E.6, Fig. 15): the generator, the receiver and the translator in one fit.

    Each step adds to the referential game's L_RG the translator's Eq. 3 loss on the same tuples, whose target is the
    generator's current deterministic TL of the tuple: the translator chases the language while the game shapes it.
    The target's gradient is stopped: letting Eq. 3 reach the generator too collapsed its code to one constant on the
    toy task of ``tests/test_task_language.py`` (a constant is what a translator predicts best), so the generator
    learns from the game alone, as in the two-stage TALAR. One Adam at ``rg_learning_rate`` for ``rg_steps``.
    ``params = {"generator", "receiver", "translator"}``; the two-stage TALAR is ``make_train_task_language`` then
    ``make_train_translator``.
    """
    game_init, game_loss_and_rows = _referential_game(config, vocab_size, max_tokens)
    generator, translator = (
        _generator(config),
        Translator(config.spec, config.translator_hidden, config.translator_tokens),
    )

    def loss_fn(params, rng, data: TaskLanguageData):
        rg_loss, rows = game_loss_and_rows(params, rng, data)
        target = generator.apply(params["generator"], data.states[rows], data.final_states[rows], None)
        target = jax.lax.stop_gradient(target)
        logits = translator.apply(params["translator"], data.sentence_embeddings[data.sentence_ids[rows]])
        return rg_loss + translator_loss(config.spec, logits, target)

    def init_params(rng: jax.Array, data: TaskLanguageData):
        rng_game, rng_translator = jax.random.split(rng)
        params = game_init(rng_game, data)
        return {**params, "translator": translator.init(rng_translator, data.sentence_embeddings[:1])}

    return AdamFit(init_params, loss_fn, config.rg_learning_rate, config.rg_steps)


def make_generate_task_language(config: TalarConfig):
    """Returns ``generate(generator_params, states, final_states) -> (N, |L_T|)``, deterministic (no noise)."""
    generator = _generator(config)

    def generate(generator_params, states: jax.Array, final_states: jax.Array) -> jax.Array:
        return generator.apply(generator_params, states, final_states, None)

    return generate


def make_train_translator(config: TalarConfig, spec: TaskLanguageSpec | None = None) -> AdamFit:
    """The translator as an ``AdamFit``: ``fit(rng, targets, data) -> (translator_params, losses)`` (vmap over seeds).

    ``targets`` (N, |L|) is the language each tuple's instruction must translate to: for TALAR the frozen
    generator's deterministic TL of the tuple (Algorithm 2, see ``make_generate_task_language``); baselines
    pass other targets (a goal one-hot, a latent-action code) with their own ``spec``.
    """
    spec = spec if spec is not None else config.spec
    translator = Translator(spec, config.translator_hidden, config.translator_tokens)

    def init_params(rng: jax.Array, targets: jax.Array, data: TaskLanguageData):
        del targets
        return translator.init(rng, data.sentence_embeddings[:1])

    def sampled_loss(params, rng_step, targets: jax.Array, data: TaskLanguageData):
        rows = jax.random.randint(rng_step, (config.batch_size,), 0, data.states.shape[0])
        if data.sentence_variants is not None:  # some rows read a paraphrase of their instruction
            rng_pick, rng_use = jax.random.split(jax.random.fold_in(rng_step, 1))
            sentences = data.sentence_ids[rows]
            pick = jax.random.randint(rng_pick, rows.shape, 0, data.sentence_variants.shape[1])
            use = jax.random.uniform(rng_use, rows.shape) < config.paraphrase_probability
            sentences = jnp.where(use, data.sentence_variants[sentences, pick], sentences)
            logits = translator.apply(params, data.sentence_embeddings[sentences])
        elif data.dataset_sentences.shape[0] < config.batch_size:  # fewer sentences than tuples: one pass per sentence
            per_sentence = translator.apply(params, data.sentence_embeddings[data.dataset_sentences])
            logits = per_sentence[data.tuple_sentence[rows]]
        else:
            logits = translator.apply(params, data.sentence_embeddings[data.sentence_ids[rows]])
        return translator_loss(spec, logits, jax.lax.stop_gradient(targets[rows]))

    def full_batch_loss(params, rng_step, targets: jax.Array, data: TaskLanguageData):
        del rng_step
        distinct = data.dataset_sentences.shape[0]
        share = jnp.zeros(distinct).at[data.tuple_sentence].add(1.0) / data.tuple_sentence.shape[0]
        mean_target = jax.ops.segment_sum(targets, data.tuple_sentence, distinct) / (share[:, None] * targets.shape[0])
        mean_target = jax.lax.stop_gradient(mean_target)
        logits = translator.apply(params, data.sentence_embeddings[data.dataset_sentences])
        nll = translator_nll(spec, logits, mean_target)
        if data.sentence_variants is None:
            return (share * nll).sum()
        variants = data.sentence_variants[data.dataset_sentences]  # (U, K)
        variant_logits = translator.apply(params, data.sentence_embeddings[variants])
        variant_nll = translator_nll(spec, variant_logits, mean_target[:, None, :]).mean(-1)
        p = config.paraphrase_probability
        return (share * ((1.0 - p) * nll + p * variant_nll)).sum()

    loss_fn = full_batch_loss if config.translator_full_batch else sampled_loss

    return AdamFit(init_params, loss_fn, config.translator_learning_rate, config.translator_steps)


def with_paraphrases(data: TaskLanguageData, features: np.ndarray, sources: np.ndarray) -> TaskLanguageData:
    """``data`` whose translator also reads paraphrases: ``features`` (A, F) of A paraphrases, ``sources`` (A,) the
    sentence row each paraphrases (every source the same number K of times). Appends the features after the
    sentences' own and fills ``sentence_variants``; rows of ``sentence_embeddings`` below S keep their meaning."""
    sources = np.asarray(sources, np.int64)
    num_sentences = data.sentence_embeddings.shape[0]
    variants = np.repeat(np.arange(num_sentences)[:, None], 1, axis=1)
    if len(sources):
        distinct, counts = np.unique(sources, return_counts=True)
        if len(set(counts.tolist())) != 1:
            raise ValueError("with_paraphrases: every source sentence needs the same number of paraphrases")
        variants = np.repeat(variants, counts[0], axis=1)
        order = np.argsort(sources, kind="stable")
        variants[distinct] = (num_sentences + order).reshape(len(distinct), counts[0])
    embeddings = jnp.concatenate([data.sentence_embeddings, jnp.asarray(features, jnp.float32)])
    return data._replace(sentence_embeddings=embeddings, sentence_variants=jnp.asarray(variants, jnp.int32))


def trim_token_padding(data: TaskLanguageData) -> TaskLanguageData:
    """``data`` whose token-state translator input (S, T, D) keeps only the slots some sentence fills: the same
    translations (padding never changes them), less work per step. Sentence-vector inputs are returned as they are."""
    features = data.sentence_embeddings
    if features.ndim != 3:
        return data
    filled = np.flatnonzero(np.asarray(jnp.any(features != 0, axis=(0, 2))))
    return data._replace(sentence_embeddings=features[:, : int(filled.max()) + 1])


def make_translate(config: TalarConfig, spec: TaskLanguageSpec | None = None):
    """Returns ``translate(translator_params, sentence_embeddings (S, D)) -> (S, |L|)`` hard language codes (token
    states (S, T, D) with ``config.translator_tokens``)."""
    spec = spec if spec is not None else config.spec
    translator = Translator(spec, config.translator_hidden, config.translator_tokens)

    def translate(translator_params, sentence_embeddings: jax.Array) -> jax.Array:
        return decode_translation(spec, translator.apply(translator_params, sentence_embeddings))

    return translate


def task_language_quality(table: np.ndarray, goal_ids: np.ndarray, is_train: np.ndarray) -> dict[str, float]:
    """How well translated TL identifies goals.

    Args:
        table: (S, |L_T|) translated TL of every instruction.
        goal_ids: (S,) goal of each instruction.
        is_train: (S,) True for training instructions.

    Returns:
        ``test_matches_train``: fraction of test instructions whose TL equals the most common TL of the
        training instructions of the same goal; ``train_consistency``: fraction of training instructions
        equal to their goal's most common TL; ``distinct_goal_codes``: fraction of goals whose most common
        training TL no other goal shares; ``decodable_train`` / ``decodable_test``: fraction of instructions
        whose TL names their goal, i.e. the goal most training instructions with that TL have (what a policy
        conditioned on the TL can know at best; 1 / num_goals for an uninformative table).
    """
    table = np.asarray(table).round().astype(np.int8)
    goal_ids, is_train = np.asarray(goal_ids), np.asarray(is_train, bool)
    codes = {}
    for goal in np.unique(goal_ids[is_train]):
        rows, counts = np.unique(table[is_train & (goal_ids == goal)], axis=0, return_counts=True)
        codes[int(goal)] = rows[np.argmax(counts)]

    def matches(mask):
        hits = [np.array_equal(table[i], codes.get(int(goal_ids[i]))) for i in np.flatnonzero(mask)]
        return float(np.mean(hits)) if hits else float("nan")

    code_list = [tuple(c) for c in codes.values()]
    distinct = np.mean([code_list.count(c) == 1 for c in code_list]) if code_list else float("nan")
    return {
        "test_matches_train": matches(~is_train),
        "train_consistency": matches(is_train),
        "distinct_goal_codes": float(distinct),
        "decodable_train": decodable_fraction(table, goal_ids, is_train, is_train),
        "decodable_test": decodable_fraction(table, goal_ids, is_train, ~is_train),
    }
