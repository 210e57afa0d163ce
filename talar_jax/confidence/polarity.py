"""Polarity: does a sentence ask for a task, ask not to do it, or ask for its opposite?

Sentence-similarity encoders place "turn off the light" next to "turn on the light", so nothing that compares a
sentence with positive instructions can tell them apart. ``PolarityClassifier`` reads the encoder's state of every
word piece instead (the token readout, as TALAR's translator does) and is fitted on the project's polarity sets
(``talar_jax.language.polarity``): the attention learns which pieces carry the polarity in context, so that "don't
forget to open it" stays positive while "don't open it" does not. An ensemble of a few seeds is kept; its mean
probabilities are what an agent reads. Arrays in, arrays out: the agent loader reads the shipped parameters.
"""

from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from talar_jax.language.polarity import LABELS

POSITIVE, NEGATED, OPPOSITE = range(len(LABELS))


@dataclasses.dataclass(frozen=True)
class PolarityConfig:
    """How the classifier is built and fitted. A few settings were compared on the held-out half (wider layer, more
    steps, word-piece dropout, the positive weight), so that half is not untouched for these: only the phrasings and
    frames in it were never trained on."""

    hidden: int = 128
    """Width of the per-token layer."""
    heads: int = 4
    """Attention-pooling heads."""
    dropout: float = 0.3
    """Dropout on the token states while fitting."""
    token_dropout: float = 0.25
    """Share of word pieces dropped whole while fitting, so that no single piece decides the label: the encoder
    carries a negation into the states of the words around it, and a frame never read still shows there."""
    steps: int = 600
    """Adam steps per ensemble member."""
    batch_size: int = 128
    learning_rate: float = 1e-3
    weight_decay: float = 1e-2
    positive_weight: float = 2.0
    """The positive label's weight in the loss relative to the balanced class weights: above 1 the classifier needs
    more evidence before it refuses, which keeps plain instructions it never read acted on."""
    members: int = 5
    """Ensemble members (seeds 0 .. members - 1)."""
    act_threshold: float = 0.5
    """An agent acts on a sentence only when the ensemble's probability of ``positive`` reaches this."""


class PolarityClassifier(nn.Module):
    """(B, T, D) token states, zero after a sentence's last piece -> (B, 3) logits over ``LABELS``."""

    config: PolarityConfig

    @nn.compact
    def __call__(self, tokens: jax.Array, train: bool = False) -> jax.Array:
        mask = jnp.any(tokens != 0, axis=-1)  # (B, T)
        if train and self.config.token_dropout > 0:
            kept = jax.random.bernoulli(self.make_rng("dropout"), 1 - self.config.token_dropout, mask.shape)
            mask = mask & (kept | ~jnp.any(mask & kept, axis=1, keepdims=True))  # never drop every piece
        tokens = nn.Dropout(self.config.dropout, deterministic=not train)(tokens)
        hidden = nn.gelu(nn.Dense(self.config.hidden)(tokens))  # (B, T, H)
        scores = jnp.where(mask[..., None], nn.Dense(self.config.heads)(hidden), -1e9)  # (B, T, heads)
        weights = jax.nn.softmax(scores, axis=1)
        pooled = jnp.einsum("bth,btd->bhd", weights, hidden).reshape(tokens.shape[0], -1)
        strongest = jnp.max(jnp.where(mask[..., None], hidden, -1e9), axis=1)  # (B, H)
        return nn.Dense(len(LABELS))(jnp.concatenate([pooled, strongest], axis=-1))


def fit_polarity(features: np.ndarray, labels: np.ndarray, config: PolarityConfig = PolarityConfig()) -> list:
    """The ensemble's parameters, one per member, fitted on (N, T, D) token states and (N,) labels with class weights
    (so a label's share of the set does not set its prior). Deterministic for given inputs."""
    model = PolarityClassifier(config)
    optimizer = optax.adamw(config.learning_rate, weight_decay=config.weight_decay)
    weights = len(labels) / (len(LABELS) * np.maximum(np.bincount(labels, minlength=len(LABELS)), 1))
    weights = jnp.asarray(weights * np.where(np.arange(len(LABELS)) == POSITIVE, config.positive_weight, 1.0))

    @jax.jit
    def step(params, state, tokens, targets, key):
        def loss(p):
            logits = model.apply(p, tokens, train=True, rngs={"dropout": key})
            return jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, targets) * weights[targets])

        grads = jax.grad(loss)(params)
        updates, state = optimizer.update(grads, state, params)
        return optax.apply_updates(params, updates), state

    members = []
    for member in range(config.members):
        key = jax.random.key(member)
        params = model.init(key, jnp.asarray(features[:2]))
        state = optimizer.init(params)
        order = np.random.default_rng(member)
        for index in range(config.steps):
            rows = order.choice(len(labels), config.batch_size)
            batch = jnp.asarray(features[rows]), jnp.asarray(labels[rows])
            params, state = step(params, state, *batch, jax.random.fold_in(key, index))
        members.append(params)
    return members


def polarity_probabilities(
    members: list, features: np.ndarray, config: PolarityConfig = PolarityConfig()
) -> np.ndarray:
    """(N, 3) the ensemble's mean probability of each of ``LABELS`` for (N, T, D) token states."""
    model = PolarityClassifier(config)
    tokens = jnp.asarray(features, jnp.float32)
    return np.mean([np.asarray(jax.nn.softmax(model.apply(p, tokens), axis=-1)) for p in members], axis=0)
