"""On-disk cache of sentence and prefix embeddings for an (env, encoder), as arrays ready to index inside jit.

Layout (S sentences of ``load_instructions(env, "all")``, train first; P prefixes):
  * sentence_embeddings (S, D): mean of BERT's last hidden state over the non-pad tokens of
    ``[CLS] T_1..T_n [SEP]`` ([CLS]/[SEP] included), L2-normalised (sentence-transformers' all-MiniLM-L6-v2 readout).
  * prefixes (paper Eq. 2): for sentence s with word pieces T_1..T_n and i = 1..n, prefix row
    ``sentence_prefix_start[s] + i - 1`` holds b(T_1..T_{i-1}) = the pooled embedding of ``[CLS] T_1..T_{i-1} [SEP]``
    (i = 1: the empty prefix) and its target T_i (``prefix_next_token``; ``prefix_next_token_compact`` indexes
    ``token_vocab``, the sorted distinct targets, so a receiver has ``len(token_vocab)`` outputs).

Files live in ``cache_dir`` / ``$TALAR_JAX_CACHE`` / ``~/.cache/talar-jax/language``, named by env, encoder and a
digest of (format, encoder weights + tokenizer, sentences, goal ids); a changed key gives a new file. Writes go to a
temporary file renamed into place, so an interrupted build leaves nothing that is trusted later.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import tempfile
import warnings
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from talar_jax.language.encoder import BertEncoder, load_encoder
from talar_jax.language.instructions import canonical_env, goal_lookup, load_instructions

CACHE_ENV_VAR = "TALAR_JAX_CACHE"
CACHE_FORMAT = 2
_ARRAY_FIELDS = (
    "goal_ids",
    "is_train",
    "sentence_embeddings",
    "token_ids",
    "token_lengths",
    "prefix_sentence",
    "prefix_next_token",
    "prefix_next_token_compact",
    "token_vocab",
    "sentence_prefix_start",
    "sentence_prefix_count",
)


SENTENCE_READOUTS: tuple[str, ...] = ("sentence", "sentence+prefixes")
"""What an experiment's translators and NL-encoding policies read of a sentence: one vector (S, F) per sentence."""
TOKEN_READOUT = "tokens"
"""A translator-only readout: the encoder's last hidden state of each word piece, (S, TOKEN_SLOTS, D), zero after
the sentence's [SEP]; the translator pools it with attention (``Translator(reads_tokens=True)``)."""
TOKEN_SLOTS = 32
"""Word pieces the token readout holds per sentence, [CLS] and [SEP] included (CLEVR and kitchen instructions have at
most 24). A batch holding a longer sentence is read at that sentence's width instead (the translator's attention
pooling masks padding, so width does not change what it reads); only the encoder's position limit bounds a sentence."""
TRANSLATOR_READOUTS: tuple[str, ...] = (*SENTENCE_READOUTS, TOKEN_READOUT)


@dataclasses.dataclass(frozen=True, eq=False)
class EmbeddingCache:
    """Embeddings and token data of every sentence of an env for one encoder (numpy arrays; move to device once).

    Attributes:
        env: "clevr" or "kitchen".
        encoder_name: display name of the encoder.
        weights_sha256: sha256 of the encoder's weights file.
        key: digest the file is keyed by.
        embedding_dim: D.
        num_goals: goals of the env.
        sentences: (S,) the sentences, train first (rows of ``load_instructions(env, "all")``).
        goal_ids: (S,) int32.
        is_train: (S,) bool.
        sentence_embeddings: (S, D) float32 pooled, unit-norm.
        token_ids: (S, T) int32 BERT input ``[CLS] T_1..T_n [SEP]``, 0-padded.
        token_lengths: (S,) int32 n + 2.
        prefix_embeddings: (P, D) float32 pooled embedding of ``[CLS] T_1..T_{i-1} [SEP]``.
        prefix_sentence: (P,) int32 sentence row of each prefix.
        prefix_next_token: (P,) int32 vocabulary id of T_i.
        prefix_next_token_compact: (P,) int32 index of T_i in ``token_vocab``.
        token_vocab: (V,) int32 sorted distinct target token ids.
        sentence_prefix_start: (S,) int32 first prefix row of each sentence.
        sentence_prefix_count: (S,) int32 n, the number of prefixes (= word pieces) of each sentence.
        goal_sentences: (num_goals, max_per_goal) int32 rows of each goal's sentences, padded with -1.
        goal_sentence_counts: (num_goals,) int32.
    """

    env: str
    encoder_name: str
    weights_sha256: str
    key: str
    embedding_dim: int
    num_goals: int
    sentences: tuple[str, ...]
    goal_ids: np.ndarray
    is_train: np.ndarray
    sentence_embeddings: np.ndarray
    token_ids: np.ndarray
    token_lengths: np.ndarray
    prefix_embeddings: np.ndarray
    prefix_sentence: np.ndarray
    prefix_next_token: np.ndarray
    prefix_next_token_compact: np.ndarray
    token_vocab: np.ndarray
    sentence_prefix_start: np.ndarray
    sentence_prefix_count: np.ndarray
    goal_sentences: np.ndarray
    goal_sentence_counts: np.ndarray

    def sentence_features(self, readout: str = "sentence") -> np.ndarray:
        """(S, F) what translators and NL-encoding policies read of each sentence.

        ``"sentence"``: the pooled sentence embedding (F = D). ``"sentence+prefixes"``: that embedding
        concatenated with the mean of the sentence's prefix embeddings b(T_1..T_{i-1}), i = 1..n (F = 2D), the
        vectors the referential game already reads: each prefix embeds only the words so far, so their mean keeps
        the word order a mean-pooled sentence embedding blurs (which colour is pushed, which is the reference).
        """
        if readout == "sentence":
            return self.sentence_embeddings
        if readout == "sentence+prefixes":
            rows = zip(self.sentence_prefix_start, self.sentence_prefix_count)
            means = np.stack([self.prefix_embeddings[start : start + count].mean(0) for start, count in rows])
            return np.concatenate([self.sentence_embeddings, means], axis=1).astype(np.float32)
        if readout == TOKEN_READOUT:
            raise ValueError("the 'tokens' readout needs the encoder: use readout_features(cache, 'tokens', encoder)")
        raise ValueError(f"unknown sentence readout {readout!r}; valid: {', '.join(SENTENCE_READOUTS)}")

    @property
    def max_tokens(self) -> int:
        """Word pieces of the longest sentence (the most next-token targets one instruction has)."""
        return int(self.sentence_prefix_count.max())

    @property
    def vocab_size(self) -> int:
        """V: number of distinct next tokens (receiver output size)."""
        return len(self.token_vocab)

    def subset(self, is_train: bool | None = None, rows: np.ndarray | None = None) -> EmbeddingCache:
        """The cache restricted to some sentences (train or test ones, or explicit rows), re-indexed from 0.

        ``token_vocab`` and the compact ids are kept, so a receiver trained on one subset fits another.

        Args:
            is_train: keep the training (True) or test (False) sentences.
            rows: explicit sentence rows to keep, in order (instead of ``is_train``).
        """
        if (is_train is None) == (rows is None):
            raise ValueError("give exactly one of is_train and rows")
        rows = np.flatnonzero(self.is_train == is_train) if rows is None else np.asarray(rows, np.int64)
        prefix_rows = np.concatenate(
            [
                np.arange(self.sentence_prefix_start[r], self.sentence_prefix_start[r] + self.sentence_prefix_count[r])
                for r in rows
            ]
            or [np.zeros(0, np.int64)]
        ).astype(np.int64)
        counts = self.sentence_prefix_count[rows]
        goal_sentences, goal_counts = goal_lookup(self.goal_ids[rows], self.num_goals)
        return dataclasses.replace(
            self,
            sentences=tuple(self.sentences[r] for r in rows),
            goal_ids=self.goal_ids[rows],
            is_train=self.is_train[rows],
            sentence_embeddings=self.sentence_embeddings[rows],
            token_ids=self.token_ids[rows],
            token_lengths=self.token_lengths[rows],
            prefix_embeddings=self.prefix_embeddings[prefix_rows],
            prefix_sentence=np.repeat(np.arange(len(rows), dtype=np.int32), counts),
            prefix_next_token=self.prefix_next_token[prefix_rows],
            prefix_next_token_compact=self.prefix_next_token_compact[prefix_rows],
            sentence_prefix_start=(np.cumsum(counts) - counts).astype(np.int32),
            sentence_prefix_count=counts,
            goal_sentences=goal_sentences,
            goal_sentence_counts=goal_counts,
        )


def sentence_features(
    encoder: BertEncoder,
    sentences: Sequence[str],
    readout: str = "sentence",
    batch_size: int = 256,
    progress: bool = False,
    description: str = "sentence features",
) -> np.ndarray:
    """(S, F) features of any sentences, computed as ``EmbeddingCache.sentence_features(readout)`` computes them for
    the cached ones (the pooled embedding; with ``"sentence+prefixes"`` also the mean of the prefix embeddings), or
    with ``"tokens"`` (S, TOKEN_SLOTS, D) per-token states (``TOKEN_READOUT``) rounded to float16 precision.

    Raises:
        ValueError: an unknown readout, a sentence without tokens (empty or only characters the encoder drops), or
            one longer than the encoder's positions (``max_word_pieces``).
    """
    if readout not in TRANSLATOR_READOUTS:
        raise ValueError(f"unknown sentence readout {readout!r}; valid: {', '.join(TRANSLATOR_READOUTS)}")
    pieces = encoder.tokenize(list(sentences))
    for sentence, tokens in zip(sentences, pieces, strict=True):
        if not tokens:
            raise ValueError(f"sentence {sentence!r} has no words the encoder {encoder.name} can read")
        if len(tokens) > max_word_pieces(encoder):
            raise ValueError(
                f"a sentence of {len(tokens)} word pieces is longer than the {max_word_pieces(encoder)} the encoder "
                f"{encoder.name} reads: split it into shorter sentences"
            )
    full = [encoder.with_specials(tokens) for tokens in pieces]
    if readout == TOKEN_READOUT:  # float16 values, as the cache stores them: fresh and cached features agree
        width = max([TOKEN_SLOTS, *(len(tokens) for tokens in full)])
        states = encoder.token_states(full, width, batch_size=batch_size, progress=progress)
        return states.astype(np.float16).astype(np.float32)
    if readout == "sentence":
        return encoder.embed_sequences(full, batch_size=batch_size, progress=progress, description=description)
    distinct: dict[tuple[int, ...], int] = {}  # sentences sharing a beginning share its prefixes: embed each once
    prefix_rows = [
        [distinct.setdefault(tuple(tokens[:i]), len(distinct)) for i in range(len(tokens))] for tokens in pieces
    ]
    sequences = full + [encoder.with_specials(list(prefix)) for prefix in distinct]
    embeddings = encoder.embed_sequences(sequences, batch_size=batch_size, progress=progress, description=description)
    prefixes = embeddings[len(full) :]
    means = np.stack([prefixes[rows].mean(0) for rows in prefix_rows])
    return np.concatenate([embeddings[: len(full)], means], axis=1).astype(np.float32)


def max_word_pieces(encoder: BertEncoder) -> int:
    """The longest sentence ``encoder`` reads, in word pieces: its positions less [CLS] and [SEP]."""
    return encoder.config.max_position_embeddings - 2


def stack_features(rows: Sequence[np.ndarray]) -> np.ndarray:
    """Stacks per-sentence features; token-state rows (T, D) of different widths are zero-padded to the widest, which
    the attention pooling reads as padding (sentence rows (F,) stack as they are)."""
    width = max(row.shape[0] for row in rows) if rows and rows[0].ndim == 2 else None
    if width is None:
        return np.stack(rows)
    return np.stack([np.pad(row, ((0, width - row.shape[0]), (0, 0))) for row in rows])


def features_with_cache(
    sentences: Sequence[str],
    cache_sentences: Sequence[str],
    cached: np.ndarray,
    compute: Callable[[list[str]], np.ndarray],
) -> np.ndarray:
    """Each sentence's features: its row of ``cached`` (the features of ``cache_sentences``, exactly what a run's stages
    read) when it is one of them, else ``compute``'s (called once, on the distinct others); ``stack_features``-ed."""
    rows = {sentence: row for row, sentence in enumerate(cache_sentences)}
    fresh = [sentence for sentence in dict.fromkeys(sentences) if sentence not in rows]
    computed = compute(fresh) if fresh else None
    at = {sentence: index for index, sentence in enumerate(fresh)}
    return stack_features([cached[rows[s]] if s in rows else computed[at[s]] for s in sentences])


def cached_sentence_features(
    encoder: BertEncoder,
    sentences: Sequence[str],
    readout: str = "sentence",
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
    description: str = "paraphrase features",
) -> np.ndarray:
    """``sentence_features`` stored once per (encoder, readout, sentences) in the language cache folder (for sentence
    sets outside an env's instruction file, such as a translator's paraphrases, and for the token readout); written
    atomically (token states as float16, returned as float32)."""
    payload = json.dumps([CACHE_FORMAT, encoder.cache_key, readout, list(sentences)])
    key = hashlib.sha256(payload.encode()).hexdigest()
    directory = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = directory / f"features-{re.sub(r'[^A-Za-z0-9_.-]+', '_', encoder.name)}-{key[:24]}.npy"
    if path.is_file():
        try:
            features = np.load(path, allow_pickle=False)
            if features.shape[0] == len(sentences):
                return features.astype(np.float32)
        except (OSError, ValueError, EOFError):
            pass
    features = sentence_features(encoder, sentences, readout, progress=progress, description=description)
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=directory, prefix=f".{path.name}.", suffix=".tmp", delete=False) as handle:
        np.save(handle, features.astype(np.float16) if readout == TOKEN_READOUT else features)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(handle.name, path)
    return features


def readout_features(
    cache: EmbeddingCache, readout: str, encoder: BertEncoder | None = None, progress: bool = False
) -> np.ndarray:
    """What ``readout`` gives of every cached sentence: ``cache.sentence_features(readout)``, or for the token readout
    the encoder's per-token states (computed once per machine, then read from the language cache folder)."""
    if readout != TOKEN_READOUT:
        return cache.sentence_features(readout)
    if encoder is None:
        raise ValueError("the 'tokens' readout needs the encoder")
    if encoder.weights_sha256 != cache.weights_sha256:
        raise ValueError(f"encoder {encoder.name} is not the one the cache was built with ({cache.encoder_name})")
    return cached_sentence_features(encoder, cache.sentences, readout, progress=progress, description="token states")


def default_cache_dir() -> Path:
    """``$TALAR_JAX_CACHE`` if set, else ``~/.cache/talar-jax/language``."""
    return Path(os.environ.get(CACHE_ENV_VAR) or Path.home() / ".cache" / "talar-jax" / "language")


def cache_path(env: str, encoder: BertEncoder, sentences: tuple[str, ...], goal_ids: np.ndarray, cache_dir=None):
    """``(path, key)`` of the cache file of these sentences under this encoder."""
    payload = json.dumps([CACHE_FORMAT, encoder.cache_key, list(sentences), goal_ids.tolist()])
    key = hashlib.sha256(payload.encode()).hexdigest()
    safe_name = re.sub(r"[^A-Za-z0-9_.-]+", "_", encoder.name)
    directory = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return directory / f"{env}-{safe_name}-{key[:24]}.npz", key


def _compute(env: str, encoder: BertEncoder, instructions, key: str, progress: bool, batch_size: int):
    """Runs the encoder over all sentences and their distinct prefixes."""
    pieces = encoder.tokenize(instructions.sentences)
    for sentence, tokens in zip(instructions.sentences, pieces, strict=True):
        if not tokens:
            raise ValueError(f"sentence {sentence!r} has no tokens under encoder {encoder.name}")
    unique_prefixes: dict[tuple[int, ...], int] = {}
    prefix_unique_row, prefix_sentence, prefix_next = [], [], []
    for row, tokens in enumerate(pieces):
        for i, token in enumerate(tokens):
            prefix_unique_row.append(unique_prefixes.setdefault(tuple(tokens[:i]), len(unique_prefixes)))
            prefix_sentence.append(row)
            prefix_next.append(token)
    full = [encoder.with_specials(tokens) for tokens in pieces]
    sequences = full + [encoder.with_specials(prefix) for prefix in unique_prefixes]
    embeddings = encoder.embed_sequences(
        sequences, batch_size=batch_size, progress=progress, description=f"{env} embeddings ({encoder.name})"
    )
    counts = np.array([len(tokens) for tokens in pieces], np.int32)
    token_ids, _ = encoder.pad(full)
    prefix_next = np.array(prefix_next, np.int32)
    token_vocab = np.unique(prefix_next).astype(np.int32)
    return EmbeddingCache(
        env=env,
        encoder_name=encoder.name,
        weights_sha256=encoder.weights_sha256,
        key=key,
        embedding_dim=encoder.embedding_dim,
        num_goals=instructions.num_goals,
        sentences=instructions.sentences,
        goal_ids=instructions.goal_ids,
        is_train=instructions.is_train,
        sentence_embeddings=embeddings[: len(full)],
        token_ids=token_ids,
        token_lengths=counts + 2,
        prefix_embeddings=embeddings[len(full) :][np.array(prefix_unique_row, np.int64)],
        prefix_sentence=np.array(prefix_sentence, np.int32),
        prefix_next_token=prefix_next,
        prefix_next_token_compact=np.searchsorted(token_vocab, prefix_next).astype(np.int32),
        token_vocab=token_vocab,
        sentence_prefix_start=(np.cumsum(counts) - counts).astype(np.int32),
        sentence_prefix_count=counts,
        goal_sentences=instructions.goal_sentences,
        goal_sentence_counts=instructions.goal_sentence_counts,
    )


def _save(cache: EmbeddingCache, path: Path) -> None:
    """Writes atomically: a temporary file in the same folder, fsync, then ``os.replace``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "format": CACHE_FORMAT,
        "env": cache.env,
        "encoder_name": cache.encoder_name,
        "weights_sha256": cache.weights_sha256,
        "key": cache.key,
        "embedding_dim": cache.embedding_dim,
        "num_goals": cache.num_goals,
    }
    arrays = {name: getattr(cache, name) for name in _ARRAY_FIELDS}
    # many sentences share prefixes (CLEVR: 18.6k prefixes, 4.6k distinct): store each distinct embedding once
    arrays["prefix_distinct_embeddings"], arrays["prefix_distinct_index"] = np.unique(
        cache.prefix_embeddings, axis=0, return_inverse=True
    )
    with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp", delete=False) as handle:
        temporary = Path(handle.name)
        try:
            np.savez(handle, meta=np.array(json.dumps(meta)), sentences=np.array(cache.sentences), **arrays)
            handle.flush()
            os.fsync(handle.fileno())
        except BaseException:
            handle.close()
            temporary.unlink(missing_ok=True)
            raise
    os.replace(temporary, path)


def _load(path: Path, key: str) -> EmbeddingCache | None:
    """The cache stored at ``path`` if it is complete and has ``key``, else None (with a warning if unreadable)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as stored:
            meta = json.loads(str(stored["meta"]))
            arrays = {name: stored[name] for name in _ARRAY_FIELDS}
            arrays["prefix_embeddings"] = stored["prefix_distinct_embeddings"][stored["prefix_distinct_index"]]
            sentences = tuple(str(s) for s in stored["sentences"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as error:
        warnings.warn(f"ignoring unreadable language cache {path} ({error}); rebuilding", stacklevel=3)
        return None
    if meta.get("format") != CACHE_FORMAT or meta.get("key") != key:
        return None
    if arrays["prefix_embeddings"].shape != (len(arrays["prefix_sentence"]), meta["embedding_dim"]):
        warnings.warn(f"ignoring inconsistent language cache {path}; rebuilding", stacklevel=3)
        return None
    goal_sentences, goal_counts = goal_lookup(arrays["goal_ids"], meta["num_goals"])
    return EmbeddingCache(
        env=meta["env"],
        encoder_name=meta["encoder_name"],
        weights_sha256=meta["weights_sha256"],
        key=key,
        embedding_dim=meta["embedding_dim"],
        num_goals=meta["num_goals"],
        sentences=sentences,
        goal_sentences=goal_sentences,
        goal_sentence_counts=goal_counts,
        **arrays,
    )


def build_cache(
    env: str,
    encoder: str | os.PathLike | BertEncoder | None = None,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = True,
    *,
    instructions_file: str | os.PathLike | None = None,
    batch_size: int = 256,
) -> EmbeddingCache:
    """The embedding cache of all sentences of ``env`` (train then test), built once and reused afterwards.

    Args:
        env: "clevr" or "kitchen" (or a registered variant).
        encoder: None for the default all-MiniLM-L6-v2, a BERT folder path, or a loaded ``BertEncoder``.
        cache_dir: folder of the cache files (default ``$TALAR_JAX_CACHE`` or ``~/.cache/talar-jax/language``).
        progress: show a tqdm bar while building.
        instructions_file: instruction JSON other than the package data (see ``load_instructions``).
        batch_size: sequences per jitted encoder call.

    Returns:
        The ``EmbeddingCache``.
    """
    env = canonical_env(env)
    instructions = load_instructions(env, "all", instructions_file=instructions_file)
    encoder = load_encoder(encoder)
    path, key = cache_path(env, encoder, instructions.sentences, instructions.goal_ids, cache_dir)
    cache = _load(path, key)
    if cache is None:
        cache = _compute(env, encoder, instructions, key, progress, batch_size)
        _save(cache, path)
    return cache
