"""TALAR's task language: the TL generator g(s, s'), the referential-game receiver and the translator.

Paper section 4.2 and Table 2. The task language L_T of a state pair is the concatenation
``(pred_1, ..., pred_Npn, arg_1, ..., arg_Na)``: ``N_pn`` predicate values in {0, 1} followed by ``N_a``
one-hot arguments of ``arg_size`` entries, so ``|L_T| = N_pn + N_a * arg_size`` (4 + 2 * 5 = 14 by default).
Discreteness comes from straight-through Gumbel-softmax, so the generator is trained end to end by the
receiver's next-token loss (Eq. 2); the translator is trained by Eq. 3 to reproduce the frozen generator's
TL from a sentence embedding.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax


@dataclasses.dataclass(frozen=True)
class TaskLanguageSpec:
    """Shape of the task language."""

    num_predicates: int = 4
    """N_pn: number of predicate networks (each outputs one Boolean)."""
    num_arguments: int = 2
    """N_a: number of argument networks (each outputs a one-hot)."""
    arg_size: int = 5
    """Size of each argument network's one-hot output."""

    def __post_init__(self):
        for name in ("num_predicates", "num_arguments"):
            if getattr(self, name) < 0:
                raise ValueError(f"TaskLanguageSpec.{name} must be >= 0, got {getattr(self, name)}")
        if self.arg_size < 1 or self.size < 1:
            raise ValueError(f"TaskLanguageSpec needs arg_size >= 1 and at least one predicate or argument: {self}")

    @property
    def size(self) -> int:
        """|L_T|."""
        return self.num_predicates + self.num_arguments * self.arg_size


def gumbel_softmax(logits: jax.Array, rng: jax.Array | None, temperature: float = 1.0) -> jax.Array:
    """Straight-through Gumbel-softmax: a hard one-hot forward, the soft sample's gradient backward.

    With ``rng=None`` no noise is added (the deterministic argmax, used for targets and evaluation).

    Args:
        logits: (..., k).
        rng: PRNG key or None.
        temperature: softmax temperature of the relaxed sample.

    Returns:
        (..., k) one-hot in value, differentiable through the relaxed sample.
    """
    if rng is not None:
        logits = logits + jax.random.gumbel(rng, logits.shape, logits.dtype)
    soft = jax.nn.softmax(logits / temperature, axis=-1)
    hard = jax.nn.one_hot(jnp.argmax(soft, axis=-1), logits.shape[-1], dtype=soft.dtype)
    return hard + (soft - jax.lax.stop_gradient(soft))  # exactly one-hot forward


class ReluMLP(nn.Module):
    """Dense layers with an activation between them (none after the last)."""

    layer_sizes: Sequence[int]

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, size in enumerate(self.layer_sizes):
            x = nn.Dense(size, name=f"dense_{i}")(x)
            if i < len(self.layer_sizes) - 1:
                x = nn.relu(x)
        return x


class TaskLanguageGenerator(nn.Module):
    """g(s, s') -> L_T: N_a argument networks then N_pn predicate networks (Fig. 2b)."""

    spec: TaskLanguageSpec = TaskLanguageSpec()
    hidden_sizes: Sequence[int] = (128, 128)
    temperature: float = 1.0

    def discrete(self) -> bool:
        """True: straight-through one-hot outputs (L_T); False: their softmax probabilities (see the Aligned
        baselines' ``AlignedEncodingLayer``)."""
        return True

    @nn.compact
    def __call__(
        self, state: jax.Array, next_state: jax.Array | None = None, rng: jax.Array | None = None
    ) -> jax.Array:
        """Args: state, next_state (..., obs) (None: the networks read ``state`` alone); rng: Gumbel noise key, None
        for the deterministic TL.

        Returns: L_T (..., spec.size) with values in {0, 1}.
        """
        pair = state if next_state is None else jnp.concatenate([state, next_state], axis=-1)
        spec = self.spec
        keys = (
            list(jax.random.split(rng, spec.num_arguments + spec.num_predicates))
            if rng is not None
            else [None] * (spec.num_arguments + spec.num_predicates)
        )

        def squash(logits, key):
            if self.discrete():
                return gumbel_softmax(logits, key, self.temperature)
            return jax.nn.softmax(logits / self.temperature, axis=-1)

        arguments = [
            squash(ReluMLP((*self.hidden_sizes, spec.arg_size), name=f"argument_net_{i}")(pair), keys[i])
            for i in range(spec.num_arguments)
        ]
        predicate_input = jnp.concatenate([pair, *arguments], axis=-1)
        predicates = [
            squash(
                ReluMLP((*self.hidden_sizes, 2), name=f"predicate_net_{j}")(predicate_input),
                keys[spec.num_arguments + j],
            )[..., 1:]
            for j in range(spec.num_predicates)
        ]
        return jnp.concatenate([*predicates, *arguments], axis=-1)


class Receiver(nn.Module):
    """f(T_i | L_T, b(T_1..T_{i-1})): logits over the task vocabulary (the referential game's listener)."""

    vocab_size: int
    hidden_sizes: Sequence[int] = (256,)

    @nn.compact
    def __call__(self, task_language: jax.Array, prefix_embedding: jax.Array) -> jax.Array:
        """Args: task_language (..., |L_T|); prefix_embedding (..., D). Returns logits (..., vocab_size)."""
        return ReluMLP((*self.hidden_sizes, self.vocab_size))(jnp.concatenate([task_language, prefix_embedding], -1))


def receiver_logits_per_prefix(
    receiver_params: dict, task_language: jax.Array, prefix_table: jax.Array, prefix_index: jax.Array
) -> jax.Array:
    """``Receiver.apply(params, TL broadcast over tokens, prefix_table[prefix_index])``, computed cheaper.

    The receiver's first layer is ``W [L_T; b] = W_L L_T + W_b b``: its prefix half is computed once per row of
    ``prefix_table`` and gathered, its task-language half once per tuple and broadcast over the tuple's tokens.
    Reads the parameter layout ``Receiver`` creates (a test checks the two agree).

    Args:
        receiver_params: ``Receiver`` parameters.
        task_language: (B, |L_T|) one message per tuple.
        prefix_table: (Q, D) prefix embeddings.
        prefix_index: (B, T) row of ``prefix_table`` of each of a tuple's T prefixes.

    Returns:
        (B, T, vocab_size) logits.
    """
    first = receiver_params["params"]["ReluMLP_0"]["dense_0"]
    prefix_part = prefix_table @ first["kernel"][task_language.shape[-1] :]
    return _receiver_with_prefix_part(receiver_params, task_language, prefix_part[prefix_index])


def receiver_logits_per_token(receiver_params: dict, task_language: jax.Array, prefixes: jax.Array) -> jax.Array:
    """``Receiver.apply(params, TL broadcast over tokens, prefixes)`` with the first layer split as in
    ``receiver_logits_per_prefix``, for prefixes already gathered: (B, T, D) -> (B, T, vocab_size) logits. Cheaper
    than the broadcast when there are more distinct prefixes than rows: the task-language half runs once per tuple,
    and its gradient skips the prefix inputs (data)."""
    first = receiver_params["params"]["ReluMLP_0"]["dense_0"]
    prefix_part = prefixes @ first["kernel"][task_language.shape[-1] :]
    return _receiver_with_prefix_part(receiver_params, task_language, prefix_part)


def _receiver_with_prefix_part(receiver_params: dict, task_language: jax.Array, prefix_part: jax.Array) -> jax.Array:
    """The receiver's logits from its first layer's prefix half, (B, T, hidden), already computed."""
    layers = receiver_params["params"]["ReluMLP_0"]
    first = layers["dense_0"]
    message_part = task_language @ first["kernel"][: task_language.shape[-1]] + first["bias"]
    x = message_part[:, None, :] + prefix_part
    for i in range(1, len(layers)):
        x = nn.relu(x) @ layers[f"dense_{i}"]["kernel"] + layers[f"dense_{i}"]["bias"]
    return x


@jax.custom_vjp
def attention_pool(tokens: jax.Array, kernel: jax.Array, bias: jax.Array) -> jax.Array:
    """Attention pooling of token states: a linear score per token and head, softmax over the real tokens (rows not
    all zero), the weighted sum of the states.

    Args: tokens (..., T, D); kernel (D, H), bias (H,) of the scores.
    Returns: (..., H, D) one pooled state per head.

    The gradient is written out (``_attention_pool_backward``) so that every product runs in a layout XLA's CPU
    matmuls handle well: with autodiff's own layouts, the four products of this 4-head pooling took 43 % of a CLEVR
    translator step for 6 % of its FLOPs (an output dimension of 4, or a batch of thousands of 4 x T products).
    """
    return _attention_pool_forward(tokens, kernel, bias)[0]


def _attention_pool_forward(tokens, kernel, bias):
    real = jnp.any(tokens != 0, axis=-1, keepdims=True)  # (..., T, 1): a token, not padding
    scores = jnp.where(real, tokens @ kernel + bias, -1e9)
    weights = jax.nn.softmax(scores, axis=-2)  # (..., T, H)
    # the barriers keep XLA from folding the transposes back into the products (see attention_pool)
    heads_first = jax.lax.optimization_barrier(jnp.swapaxes(weights, -1, -2))  # (..., H, T)
    pooled = jnp.einsum("...ht,...td->...hd", heads_first, tokens)
    return pooled, (tokens, kernel, weights)


def _attention_pool_backward(residuals, pooled_grad):
    tokens, kernel, weights = residuals
    weights_grad = jnp.einsum("...hd,...td->...th", pooled_grad, tokens)
    # softmax's backward over tokens; a padding slot has weight exactly 0, so its score gets no gradient, as the
    # -1e9 of the forward pass (a constant) would give it
    scores_grad = weights * (weights_grad - jnp.sum(weights * weights_grad, axis=-2, keepdims=True))
    flat_scores_grad = scores_grad.reshape(-1, scores_grad.shape[-1])
    kernel_grad_t = jnp.einsum("nh,nd->hd", flat_scores_grad, tokens.reshape(-1, tokens.shape[-1]))
    kernel_grad = jax.lax.optimization_barrier(kernel_grad_t).T
    tokens_grad = jnp.einsum("...th,...hd->...td", weights, pooled_grad) + scores_grad @ kernel.T
    return tokens_grad, kernel_grad, flat_scores_grad.sum(0)


attention_pool.defvjp(_attention_pool_forward, _attention_pool_backward)


class AttentionPooling(nn.Module):
    """``attention_pool`` with its scores' parameters, laid out as ``nn.Dense``'s (``kernel`` (D, H), ``bias`` (H,),
    the same initialisers)."""

    heads: int

    @nn.compact
    def __call__(self, tokens: jax.Array) -> jax.Array:
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (tokens.shape[-1], self.heads))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.heads,))
        return attention_pool(tokens, kernel, bias)


class Translator(nn.Module):
    """p_phi: sentence embedding -> logits of L_T (predicate logits, then argument logits); Fig. 2c.

    With ``reads_tokens`` the input is the encoder's state of each word piece, (..., T, D), zero after the last one
    (``TOKEN_READOUT``): ``attention_heads`` attention poolings (a linear score per token, softmax over the
    sentence's tokens, the weighted sum of the states) replace the mean pooling before the same MLP, so the translator
    can learn which words name the goal wherever they stand in the sentence. Padding never changes the output.
    """

    spec: TaskLanguageSpec = TaskLanguageSpec()
    hidden_sizes: Sequence[int] = (256, 256, 256, 256)
    reads_tokens: bool = False
    attention_heads: int = 4

    @nn.compact
    def __call__(self, sentence_embedding: jax.Array) -> jax.Array:
        """Args: sentence_embedding (..., D), or (..., T, D) token states with ``reads_tokens``.
        Returns logits (..., spec.size) (see ``translator_loss``)."""
        x = sentence_embedding
        if self.reads_tokens:
            # named as the nn.Dense that held the scores' parameters before, so trained translators still load
            pooled = AttentionPooling(self.attention_heads, name="Dense_0")(x)
            x = pooled.reshape(*pooled.shape[:-2], self.attention_heads * x.shape[-1])
        return ReluMLP((*self.hidden_sizes, self.spec.size))(x)


def split_task_language(spec: TaskLanguageSpec, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Splits (..., |L_T|) into predicates (..., N_pn) and arguments (..., N_a, arg_size)."""
    predicates = x[..., : spec.num_predicates]
    arguments = x[..., spec.num_predicates :].reshape(*x.shape[:-1], spec.num_arguments, spec.arg_size)
    return predicates, arguments


def decode_translation(spec: TaskLanguageSpec, logits: jax.Array) -> jax.Array:
    """Translator logits -> hard task language (predicate = logit > 0, argument = one-hot of the argmax)."""
    predicate_logits, argument_logits = split_task_language(spec, logits)
    predicates = (predicate_logits > 0).astype(jnp.float32)
    arguments = jax.nn.one_hot(jnp.argmax(argument_logits, -1), spec.arg_size, dtype=jnp.float32)
    return jnp.concatenate([predicates, arguments.reshape(*arguments.shape[:-2], -1)], axis=-1)


def referential_game_loss(
    receiver_logits: jax.Array, next_tokens: jax.Array, mask: jax.Array | None = None
) -> jax.Array:
    """Eq. 2: mean negative log-likelihood of the next token.

    Args:
        receiver_logits: (B, V) logits over the task vocabulary, or (B, T, V): T candidate tokens per tuple.
        next_tokens: (B,) or (B, T) int indices into that vocabulary.
        mask: (B, T) bool, which of a tuple's T tokens are real; the NLL is averaged over them (T_i uniform over
            the instruction's tokens), then over tuples. None: a plain mean.
    """
    nll = optax.softmax_cross_entropy_with_integer_labels(receiver_logits, next_tokens)
    if mask is None:
        return nll.mean()
    return ((nll * mask).sum(-1) / mask.sum(-1)).mean()


def translator_nll(spec: TaskLanguageSpec, logits: jax.Array, target: jax.Array) -> jax.Array:
    """Eq. 3 per row: -log p_phi(L_T | b(L_N)), with independent Bernoulli predicates and categorical arguments.

    Args:
        spec: task-language shape.
        logits: (B, |L_T|) translator outputs.
        target: (B, |L_T|) the generator's hard task language, or a mean of such (the NLL is linear in the target,
            so a row with the mean target of k tuples carries the mean of their k losses).

    Returns:
        (B,) the summed per-component negative log-likelihoods of each row.
    """
    predicate_logits, argument_logits = split_task_language(spec, logits)
    predicate_target, argument_target = split_task_language(spec, target)
    predicate_nll = optax.sigmoid_binary_cross_entropy(predicate_logits, predicate_target).sum(-1)
    argument_nll = optax.softmax_cross_entropy(argument_logits, argument_target).sum(-1)
    return predicate_nll + argument_nll


def translator_loss(spec: TaskLanguageSpec, logits: jax.Array, target: jax.Array) -> jax.Array:
    """Eq. 3: the mean over the batch of ``translator_nll``."""
    return translator_nll(spec, logits, target).mean()
