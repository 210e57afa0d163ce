"""Polarity: does a sentence ask for a task, ask not to do it, or ask for its opposite?

Sentence-similarity encoders place "turn off the light" next to "turn on the light", so nothing that compares a
sentence with positive instructions can tell them apart. ``PolarityClassifier`` reads the encoder's state of every
word piece instead (the token readout, as TALAR's translator does) and is fitted on the project's polarity sets
(``talar_jax.language.polarity``): the attention learns which pieces carry the polarity in context, so that "don't
forget to open it" stays positive while "don't open it" does not. A fourth class, ``unknown``, is a sentence that
names something the env does not have ("open the hinged cabinet", "push the orange ball ..."), learnt from the
project's positive sentences with a word naming their goal's objects swapped for a word the env never uses. A few
heads are kept (``PolarityModel``); their mean probabilities are what an agent reads. The model can fine-tune the
encoder's top layers with the heads (``PolarityConfig.tuned_layers``); the shipped one does not, since that read the
held-out half worse. Arrays in, arrays out: the agent loader reads the shipped parameters.
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
from tqdm.auto import tqdm

from talar_jax.language.bert import BertConfig, EncoderTop, top_and_head, with_pretrained_top
from talar_jax.language.cache import TOKEN_READOUT, TOKEN_SLOTS, max_word_pieces, sentence_features
from talar_jax.language.encoder import BertEncoder
from talar_jax.language.polarity import CLASSES

POSITIVE, NEGATED, OPPOSITE, UNKNOWN = range(len(CLASSES))


@dataclasses.dataclass(frozen=True)
class PolarityConfig:
    """How the classifier is built and fitted.

    The head's settings (wider layer, more steps, word-piece dropout, the positive weight of 2) were compared on the
    held-out half, so that half is not untouched for them. Fine-tuning the encoder's top layer was compared on the
    development split of the train half instead (``polarity_set(env, development=True)``, by
    ``python -m experiments.polarity --development``), where per env (kitchen / CLEVR) the share acted on was:
    frozen encoder: positive 92.2 / 94.6 %, negated 1.1 / 0.6 %, opposite 0.0 / 0.0 %; top layer fine-tuned at
    5e-5: positive 93.4 / 96.0 %, negated 2.0 / 1.9 %, opposite 0.1 / 0.5 %; the same with positive weight 3:
    positive 93.2 / 95.7 %, negated 1.9 / 1.4 %, opposite 0.1 / 0.6 %. By the rule chosen beforehand (the most
    positives acted on with at most 5 % of negations and opposites acted on) the fine-tuned top won; fitted on the
    whole train half and read once on the held-out half it acted on positive 91.4 / 100.0 %, negated 8.7 / 10.9 %,
    opposite 0.5 / 6.4 %, worse than the frozen encoder's 93.1 / 99.9 %, 7.9 / 7.0 %, 0.7 / 0.0 %. The development
    split holds out train frames and phrases, which resemble the ones trained on more than the held-out half's do;
    a top layer that moves learns the train half's wording. So ``tuned_layers`` is 0 for the shipped classifier."""

    hidden: int = 128
    """Width of the per-token layer."""
    heads: int = 4
    """Attention-pooling heads."""
    dropout: float = 0.3
    """Dropout on the token states while fitting."""
    token_dropout: float = 0.25
    """Share of word pieces dropped whole while fitting, so that no single piece decides the label: the encoder
    carries a negation into the states of the words around it, and a frame never read still shows there."""
    steps: int = 2000
    """Adam steps per ensemble member. 600 before the ``unknown`` class; with it, on the development split (kitchen /
    CLEVR, share acted on) 600 steps left negations at 4.7 / 2.6 % and positives at 91.4 / 92.9 %, 1200 steps 1.9 /
    1.5 % and 93.4 / 95.2 %, 2000 steps 1.4 / 0.8 % and 93.7 / 95.6 %, unknown sentences 2.2 / 0.3 % (three classes
    at 600 steps: 1.1 / 0.6 % and 92.2 / 94.6 %; at 1200: 0.4 / 0.5 % and 93.4 / 95.4 %)."""
    batch_size: int = 128
    learning_rate: float = 1e-3
    weight_decay: float = 1e-2
    positive_weight: float = 2.0
    """The positive label's weight in the loss relative to the balanced class weights: above 1 the classifier needs
    more evidence before it refuses, which keeps plain instructions it never read acted on."""
    members: int = 5
    """Heads, each with its own initialisation and dropout, over the one (fine-tuned) top."""
    tuned_layers: int = 0
    """The encoder's top layers fine-tuned with the heads (0: the heads read the frozen last layer's states)."""
    top_learning_rate: float = 5e-5
    """Adam's step size for the fine-tuned layers, well below the heads' so that they stay near the encoder's."""
    act_threshold: float = 0.5
    """An agent acts on a sentence only when the ensemble's probability of ``positive`` (with ``unknown``'s below
    ``unknown_threshold``) reaches this (``judged_classes``)."""
    unknown_threshold: float = 0.9
    """An agent refuses a sentence as naming something it does not know only when the probability of ``unknown``
    reaches this. Refused at 0.5, kitchen development phrasings with a word the swaps taught to be strange ("open
    microwave pls", "Set the kettle on the hob.") lost 3 of 90 sentences; a weaker refusal keeps them."""
    classes: int = len(CLASSES)
    """How many of ``CLASSES`` the classifier tells apart: 3 for one fitted before the ``unknown`` class, 4 since."""


class PolarityClassifier(nn.Module):
    """(B, T, D) token states, zero after a sentence's last piece -> (B, classes) logits over ``CLASSES``."""

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
        return nn.Dense(self.config.classes)(jnp.concatenate([pooled, strongest], axis=-1))


class PolarityModel(nn.Module):
    """The classifier an agent reads: ``config.members`` heads (``PolarityClassifier``) over one set of token states,
    (B, T, D) -> (members, B, classes) logits. With ``config.tuned_layers`` > 0 the states are the ones entering the
    encoder's top layers (``polarity_states``), which an ``EncoderTop`` fine-tuned with the heads turns into the
    states the heads read: frozen sentence-similarity states place "turn off X" next to "turn on X", and a top layer
    that moves can re-read "off", "close" or "don't" in context. The heads share the top (one fine-tuned layer is
    most of the parameters) and differ in their initialisation and dropout."""

    config: PolarityConfig
    encoder: BertConfig | None = None

    @nn.compact
    def __call__(self, states: jax.Array, train: bool = False) -> jax.Array:
        mask = jnp.any(states != 0, axis=-1)
        if self.config.tuned_layers:
            first = self.encoder.num_hidden_layers - self.config.tuned_layers
            states = EncoderTop(self.encoder, first, name="top")(states, mask.astype(jnp.int32)) * mask[..., None]
        heads = [PolarityClassifier(self.config, name=f"head_{m}") for m in range(self.config.members)]
        return jnp.stack([head(states, train) for head in heads])


def polarity_states(
    encoder: BertEncoder, sentences: Sequence[str], config: PolarityConfig, progress: bool = False
) -> np.ndarray:
    """(N, T, D) what ``PolarityModel`` reads of each sentence: the encoder's last-layer token states
    (``TOKEN_READOUT``) for ``tuned_layers == 0``, else the states entering its top ``tuned_layers`` layers; rounded
    to float16 precision, as the language cache stores them, so that fresh and cached states agree."""
    if not config.tuned_layers:
        return sentence_features(encoder, list(sentences), TOKEN_READOUT, progress=progress)
    pieces = encoder.tokenize(list(sentences))
    for sentence, tokens in zip(sentences, pieces, strict=True):
        if not tokens:
            raise ValueError(f"sentence {sentence!r} has no words the encoder {encoder.name} can read")
        if len(tokens) > max_word_pieces(encoder):
            raise ValueError(f"a sentence of {len(tokens)} word pieces is longer than the encoder {encoder.name} reads")
    full = [encoder.with_specials(tokens) for tokens in pieces]
    width = max([TOKEN_SLOTS, *(len(tokens) for tokens in full)])
    first = encoder.config.num_hidden_layers - config.tuned_layers
    states = encoder.token_states(full, width, progress=progress, below_layer=first)
    return states.astype(np.float16).astype(np.float32)


def fit_polarity(
    features: np.ndarray,
    labels: np.ndarray,
    config: PolarityConfig = PolarityConfig(),
    encoder: BertEncoder | None = None,
    progress: bool = False,
) -> dict:
    """The ``PolarityModel``'s parameters fitted on (N, T, D) states (``polarity_states``) and (N,) labels with class
    weights (so a label's share of the set does not set its prior). Over a frozen encoder each head is fitted alone,
    on its own seed and batch order (the most diverse ensemble); with ``tuned_layers`` the heads are fitted together
    with the top, which starts from ``encoder``'s weights and moves at ``top_learning_rate`` (one fine-tuned layer for
    all heads, since it is most of the parameters). Deterministic for given inputs."""
    weights = len(labels) / (config.classes * np.maximum(np.bincount(labels, minlength=config.classes), 1))
    weights = jnp.asarray(weights * np.where(np.arange(config.classes) == POSITIVE, config.positive_weight, 1.0))
    heads = optax.adamw(config.learning_rate, weight_decay=config.weight_decay)
    if not config.tuned_layers:
        single = PolarityClassifier(config)
        fitted = {}
        for member in range(config.members):
            params = single.init(jax.random.key(member), jnp.asarray(features[:2]))
            params = _fit(single, params, heads, features, labels, weights, config, member, progress)
            fitted[f"head_{member}"] = params["params"]
        return {"params": fitted}
    model = PolarityModel(config, encoder.config)
    params = model.init(jax.random.key(0), jnp.asarray(features[:2]))
    params = with_pretrained_top(
        params, encoder.params, encoder.config.num_hidden_layers - config.tuned_layers, ("top",)
    )
    optimizer = top_and_head(optax.adamw(config.top_learning_rate, weight_decay=config.weight_decay), heads)
    width = int(np.any(features != 0, axis=-1).sum(axis=1).max())  # no step reads the zeros after every sentence
    return _fit(model, params, optimizer, features[:, :width], labels, weights, config, 0, progress)


def _fit(model, params, optimizer, features, labels, weights, config: PolarityConfig, seed: int, progress: bool):
    """``params`` after ``config.steps`` steps of ``optimizer`` on batches drawn with ``seed``."""
    state = optimizer.init(params)

    @jax.jit
    def step(params, state, tokens, targets, key):
        def loss(p):
            logits = model.apply(p, tokens, train=True, rngs={"dropout": key})  # ([members,] B, classes)
            every = jnp.broadcast_to(targets, logits.shape[:-1])
            return jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, every) * weights[every])

        grads = jax.grad(loss)(params)
        updates, state = optimizer.update(grads, state, params)
        return optax.apply_updates(params, updates), state

    key, order = jax.random.key(seed), np.random.default_rng(seed)
    for index in tqdm(range(config.steps), desc=f"polarity {seed}", disable=not progress):
        rows = order.choice(len(labels), config.batch_size)
        batch = jnp.asarray(features[rows]), jnp.asarray(labels[rows])
        params, state = step(params, state, *batch, jax.random.fold_in(key, index))
    return params


def polarity_probabilities(
    params: dict, features: np.ndarray, config: PolarityConfig = PolarityConfig(), encoder: BertConfig | None = None
) -> np.ndarray:
    """(N, classes) the heads' mean probability of each of ``CLASSES`` for (N, T, D) states (``polarity_states``);
    ``encoder``: the encoder's config, for a model with ``tuned_layers``."""
    apply = _probabilities(config, encoder)
    params = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), params)
    rows = range(0, len(features), 512)
    out = [np.asarray(apply(params, jnp.asarray(features[i : i + 512], jnp.float32))) for i in rows]
    return np.concatenate(out) if out else np.zeros((0, config.classes), np.float32)


@functools.cache
def _probabilities(config: PolarityConfig, encoder: BertConfig | None):
    """The compiled mean probability of the heads, one per model (an agent judges sentence after sentence)."""
    model = PolarityModel(config, encoder)
    return jax.jit(lambda params, states: jnp.mean(jax.nn.softmax(model.apply(params, states), axis=-1), axis=0))


def judged_classes(probabilities: np.ndarray, config: PolarityConfig) -> np.ndarray:
    """(N,) what an agent makes of each sentence of (N, classes) probabilities: ``POSITIVE`` when it acts;
    ``UNKNOWN`` when the probability of unknown reaches ``config.unknown_threshold``; else, when the probability of
    positive (and of unknown, below its threshold) is under ``config.act_threshold``, the likelier of ``NEGATED``
    and ``OPPOSITE``. With three classes this is acting at a probability of positive of ``act_threshold``."""
    probabilities = np.asarray(probabilities)
    unknown = probabilities[:, UNKNOWN] if probabilities.shape[1] > UNKNOWN else np.zeros(len(probabilities))
    refused = probabilities[:, POSITIVE] + unknown < config.act_threshold
    polarity = np.where(probabilities[:, NEGATED] >= probabilities[:, OPPOSITE], NEGATED, OPPOSITE)
    out = np.where(refused, polarity, POSITIVE)
    return np.where(unknown >= config.unknown_threshold, UNKNOWN, out)


def shipped_params(params: dict) -> dict:
    """The parameters as shipped: the fine-tuned top in float16 (half the bytes of a layer of the encoder, which the
    shipped files carry in git), the heads in float32. ``polarity_probabilities`` reads either."""
    return {
        "params": {
            name: jax.tree_util.tree_map(lambda x: np.asarray(x, np.float16 if name == "top" else np.float32), tree)
            for name, tree in params["params"].items()
        }
    }
