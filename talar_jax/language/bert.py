"""BERT encoder in flax.linen, matching transformers' ``BertModel`` (last hidden state), and its weight converter."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

_ACTIVATIONS = {
    "gelu": lambda x: jax.nn.gelu(x, approximate=False),  # erf GELU (BERT, MiniLM)
    "gelu_new": lambda x: jax.nn.gelu(x, approximate=True),
    "gelu_pytorch_tanh": lambda x: jax.nn.gelu(x, approximate=True),
    "relu": jax.nn.relu,
}


@dataclasses.dataclass(frozen=True)
class BertConfig:
    """The fields of a Hugging Face BERT ``config.json`` the encoder uses."""

    vocab_size: int
    hidden_size: int
    num_hidden_layers: int
    num_attention_heads: int
    intermediate_size: int
    max_position_embeddings: int = 512
    type_vocab_size: int = 2
    hidden_act: str = "gelu"
    layer_norm_eps: float = 1e-12
    pad_token_id: int = 0

    @classmethod
    def from_dict(cls, config: Mapping) -> BertConfig:
        """Reads a parsed ``config.json``; raises ValueError when it does not describe a BERT encoder."""
        model_type = config.get("model_type")
        if model_type != "bert":
            raise ValueError(f"config.json has model_type {model_type!r}, expected 'bert'")
        if config.get("position_embedding_type", "absolute") != "absolute":
            raise ValueError(f"position_embedding_type {config['position_embedding_type']!r} is not supported")
        required = ("vocab_size", "hidden_size", "num_hidden_layers", "num_attention_heads", "intermediate_size")
        missing = [name for name in required if name not in config]
        if missing:
            raise ValueError(f"config.json lacks {missing}")
        fields = {f.name for f in dataclasses.fields(cls)}
        values = {name: config[name] for name in fields if config.get(name) is not None}
        result = cls(**values)
        if result.hidden_act not in _ACTIVATIONS:
            raise ValueError(f"hidden_act {result.hidden_act!r} is not supported; valid: {sorted(_ACTIVATIONS)}")
        if result.hidden_size % result.num_attention_heads:
            raise ValueError("hidden_size must be a multiple of num_attention_heads")
        return result


class BertEmbeddings(nn.Module):
    """Word + position + token-type embeddings, then LayerNorm."""

    config: BertConfig

    @nn.compact
    def __call__(self, input_ids: jax.Array, token_type_ids: jax.Array) -> jax.Array:
        """(B, T) int ids -> (B, T, H)."""
        config = self.config
        positions = jnp.arange(input_ids.shape[-1])
        words = nn.Embed(config.vocab_size, config.hidden_size, name="word_embeddings")(input_ids)
        position = nn.Embed(config.max_position_embeddings, config.hidden_size, name="position_embeddings")(positions)
        token_type = nn.Embed(config.type_vocab_size, config.hidden_size, name="token_type_embeddings")(token_type_ids)
        return nn.LayerNorm(epsilon=config.layer_norm_eps, name="LayerNorm")(words + position + token_type)


class BertSelfAttention(nn.Module):
    """Multi-head scaled dot-product self-attention with a key padding mask."""

    config: BertConfig

    @nn.compact
    def __call__(self, hidden: jax.Array, attention_bias: jax.Array) -> jax.Array:
        """(B, T, H) hidden and (B, 1, 1, T) additive bias -> (B, T, H) context."""
        config = self.config
        heads, head_dim = config.num_attention_heads, config.hidden_size // config.num_attention_heads

        def split_heads(x: jax.Array) -> jax.Array:  # (B, T, H) -> (B, heads, T, head_dim)
            return x.reshape(*x.shape[:2], heads, head_dim).transpose(0, 2, 1, 3)

        query = split_heads(nn.Dense(config.hidden_size, name="query")(hidden))
        key = split_heads(nn.Dense(config.hidden_size, name="key")(hidden))
        value = split_heads(nn.Dense(config.hidden_size, name="value")(hidden))
        scores = jnp.einsum("bhqd,bhkd->bhqk", query, key) / math.sqrt(head_dim) + attention_bias
        context = jnp.einsum("bhqk,bhkd->bhqd", jax.nn.softmax(scores, axis=-1), value)
        return context.transpose(0, 2, 1, 3).reshape(hidden.shape)


class BertAttention(nn.Module):
    """Self-attention, output projection, residual and LayerNorm."""

    config: BertConfig

    @nn.compact
    def __call__(self, hidden: jax.Array, attention_bias: jax.Array) -> jax.Array:
        context = BertSelfAttention(self.config, name="self")(hidden, attention_bias)
        output = nn.Dense(self.config.hidden_size, name="output_dense")(context)
        return nn.LayerNorm(epsilon=self.config.layer_norm_eps, name="output_LayerNorm")(output + hidden)


class BertLayer(nn.Module):
    """One transformer encoder layer: attention, then the feed-forward block with residual and LayerNorm."""

    config: BertConfig

    @nn.compact
    def __call__(self, hidden: jax.Array, attention_bias: jax.Array) -> jax.Array:
        config = self.config
        attended = BertAttention(config, name="attention")(hidden, attention_bias)
        intermediate = _ACTIVATIONS[config.hidden_act](
            nn.Dense(config.intermediate_size, name="intermediate")(attended)
        )
        output = nn.Dense(config.hidden_size, name="output_dense")(intermediate)
        return nn.LayerNorm(epsilon=config.layer_norm_eps, name="output_LayerNorm")(output + attended)


class BertModel(nn.Module):
    """BERT encoder stack; returns the last hidden state (no pooler).

    ``layers = (first, stop)`` runs encoder layers ``first .. stop - 1`` only: with ``first > 0`` the input is the
    hidden state before layer ``first`` (the embeddings are skipped) and the output the one after layer
    ``stop - 1``. Parameter names are the whole model's, so such a slice's parameters are a subset of its tree
    (how the fine-tuned BERT baselines train only the top layers).
    """

    config: BertConfig
    layers: tuple[int, int] | None = None

    @nn.compact
    def __call__(self, input_ids: jax.Array, attention_mask: jax.Array, token_type_ids: jax.Array | None = None):
        """Encodes padded token ids.

        Args:
            input_ids: (B, T) int32 token ids, or (B, T, H) hidden states when ``layers`` starts after layer 0.
            attention_mask: (B, T) 1 for real tokens, 0 for padding.
            token_type_ids: (B, T) segment ids; zeros when None.

        Returns:
            (B, T, H) float32 last hidden state (rows at padded positions are meaningless).
        """
        first, stop = self.layers or (0, self.config.num_hidden_layers)
        if not 0 <= first <= stop <= self.config.num_hidden_layers:
            raise ValueError(f"layers {self.layers} must satisfy 0 <= first <= stop <= {self.config.num_hidden_layers}")
        if first == 0:
            if token_type_ids is None:
                token_type_ids = jnp.zeros_like(input_ids)
            hidden = BertEmbeddings(self.config, name="embeddings")(input_ids, token_type_ids)
        else:
            hidden = input_ids
        # additive key mask, as transformers: 0 for tokens, dtype minimum for padding
        attention_bias = jnp.where(attention_mask[:, None, None, :] > 0, 0.0, jnp.finfo(hidden.dtype).min)
        for index in range(first, stop):
            hidden = BertLayer(self.config, name=f"layer_{index}")(hidden, attention_bias)
        return hidden


class EncoderTop(nn.Module):
    """An encoder's layers ``first`` and above as a block a small model trains: (B, T, H) states entering layer
    ``first`` (``BertEncoder.token_states(..., below_layer=first)``) and a (B, T) mask -> (B, T, H) last hidden state.

    Frozen sentence-similarity states carry what a sentence is about, not always how it is built (a negation, where a
    clause begins); letting the top layers move while a head is fitted lets them re-read the sentence for that head.
    Start from the encoder's own weights (``with_pretrained_top``), so that the head begins from what it knows."""

    config: BertConfig
    first: int

    @nn.compact
    def __call__(self, states: jax.Array, mask: jax.Array) -> jax.Array:
        return BertModel(self.config, layers=(self.first, self.config.num_hidden_layers), name="bert")(states, mask)


def with_pretrained_top(params: dict, encoder_params: dict, first: int, path: tuple[str, ...]) -> dict:
    """``params`` (a model's, as ``init`` gives them) with the ``EncoderTop`` at ``path`` under "params" set to the
    encoder's own weights of layers ``first`` and above. The other leaves are left as they are."""
    params = jax.tree_util.tree_map(lambda x: x, params)  # a copy whose dicts may be edited
    top = params["params"]
    for name in path:
        top = top[name]
    for name in list(top["bert"]):
        index = int(name.removeprefix("layer_"))
        if index < first:
            raise ValueError(f"{path} holds {name}, below layer {first}")
        top["bert"][name] = jax.tree_util.tree_map(jnp.asarray, encoder_params["params"][name])
    return params


def top_and_head(top: optax.GradientTransformation, head: optax.GradientTransformation) -> optax.GradientTransformation:
    """One optimiser for a model holding an ``EncoderTop`` named "top": ``top`` for its pretrained layers (which should
    move slowly, or they forget what the encoder knew), ``head`` for every other parameter (fresh ones, fast)."""

    def labels(params):
        return {"params": {name: "top" if name == "top" else "head" for name in params["params"]}}

    return optax.multi_transform({"top": top, "head": head}, labels)


def mean_pool(hidden: jax.Array, attention_mask: jax.Array, normalize: bool = True) -> jax.Array:
    """Sentence-transformers pooling: mean over non-pad tokens ([CLS]/[SEP] included), then L2-normalise.

    Args:
        hidden: (B, T, H) last hidden state.
        attention_mask: (B, T) 1 for real tokens.
        normalize: divide by the L2 norm (as all-MiniLM-L6-v2's Normalize module).

    Returns:
        (B, H) pooled vectors.
    """
    mask = attention_mask[..., None].astype(hidden.dtype)
    pooled = jnp.sum(hidden * mask, axis=1) / jnp.maximum(jnp.sum(mask, axis=1), 1e-9)
    if normalize:
        pooled = pooled / jnp.maximum(jnp.linalg.norm(pooled, axis=-1, keepdims=True), 1e-12)
    return pooled


def _flax_path(name: str) -> tuple[str, ...] | None:
    """Hugging Face BertModel weight name -> flax parameter path, or None for tensors the encoder ignores."""
    parts = name.split(".")
    if parts[0] == "bert":
        parts = parts[1:]
    if parts[0] not in ("embeddings", "encoder") or name.endswith("position_ids"):
        return None  # pooler, MLM / NSP heads, buffers
    leaf = {"gamma": "weight", "beta": "bias"}.get(parts[-1], parts[-1])  # old checkpoints name LayerNorm so
    parts = parts[:-1]
    if parts[0] == "embeddings":
        module = parts[1]
        path = ("embeddings", module)
        if module == "LayerNorm":
            return (*path, "scale" if leaf == "weight" else "bias")
        return (*path, "embedding")
    if len(parts) < 4 or parts[1] != "layer":
        return None
    layer, rest = f"layer_{parts[2]}", parts[3:]
    if rest[:2] == ["attention", "self"]:
        path = (layer, "attention", "self", rest[2])
    elif rest[:2] == ["attention", "output"]:
        path = (layer, "attention", f"output_{rest[2]}")
    elif rest == ["intermediate", "dense"]:
        path = (layer, "intermediate")
    elif rest[0] == "output":
        path = (layer, f"output_{rest[1]}")
    else:
        return None
    if path[-1].endswith("LayerNorm"):
        return (*path, "scale" if leaf == "weight" else "bias")
    return (*path, "kernel" if leaf == "weight" else "bias")


def convert_weights(tensors: Mapping[str, np.ndarray], config: BertConfig) -> dict:
    """Hugging Face BERT tensors (torch layout, optional ``bert.`` prefix) -> flax params of ``BertModel``.

    Dense weights (out, in) become kernels (in, out); LayerNorm weight/bias (or gamma/beta) become scale/bias.

    Args:
        tensors: name -> array, as read from ``model.safetensors``.
        config: the model config.

    Returns:
        ``{"params": ...}`` with exactly the shapes ``BertModel(config).init`` makes.

    Raises:
        ValueError: a tensor is missing or has the wrong shape.
    """
    params: dict = {}
    for name, array in tensors.items():
        path = _flax_path(name)
        if path is None:
            continue
        value = np.asarray(array, np.float32)
        if path[-1] == "kernel":
            value = value.T
        node = params
        for key in path[:-1]:
            node = node.setdefault(key, {})
        node[path[-1]] = value
    dummy = jnp.zeros((1, 2), jnp.int32)
    expected = jax.eval_shape(BertModel(config).init, jax.random.key(0), dummy, dummy)["params"]
    expected_flat = {
        "/".join(k.key for k in path): leaf.shape for path, leaf in jax.tree_util.tree_leaves_with_path(expected)
    }
    got_flat = {"/".join(k.key for k in path): leaf.shape for path, leaf in jax.tree_util.tree_leaves_with_path(params)}
    missing = sorted(set(expected_flat) - set(got_flat))
    if missing:
        raise ValueError(f"BERT weights lack {len(missing)} tensors, e.g. {missing[:3]} (flax names)")
    wrong = [(k, got_flat[k], shape) for k, shape in expected_flat.items() if got_flat[k] != shape]
    if wrong:
        raise ValueError(f"BERT weights have wrong shapes (name, got, expected): {wrong[:3]}")
    extra = sorted(set(got_flat) - set(expected_flat))
    if extra:
        raise ValueError(f"BERT weights have tensors the config does not describe: {extra[:3]}")
    return {"params": params}
