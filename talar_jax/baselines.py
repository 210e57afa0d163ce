"""The paper's outside-in baselines (section 5.1, Appendix E.7): instruction encodings fed to the same PPO.

* One-hot: a unique one-hot per instruction over train and test instructions together (``one_hot_table``).
* BERT-binary / BERT-continuous: a dense layer on the frozen sentence embedding, made binary with a
  straight-through Bernoulli (reparameterisation) trick or left continuous, trained jointly with the policy by RL
  (``NLEncodingLayer``); the "pre-trained" variants first fit policy and layer by behaviour cloning.
* Aligned BERT-binary / -continuous (Appendix E.3): the same, with the TL generator's architecture as the encoding
  layer (``AlignedEncodingLayer``: N_a argument networks, then N_pn predicate networks reading the arguments).
* GLA: a latent-action auto-encoder of state pairs (``LatentActionAutoencoder``); instructions are then
  translated into its binary latent code (``make_train_gla``).
* Handcrafted: the translator trained to a one-hot of the goal instead of the generator's TL (``goal_one_hot``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from talar_jax.conditioning import Conditioner, InstructionSampler
from talar_jax.networks import (
    OBS_NORMALIZER,
    init_observation_stats,
    make_ppo_networks,
    network_inputs,
    update_observation_stats,
)
from talar_jax.optim import AdamFit
from talar_jax.task_language import ReluMLP, TaskLanguageGenerator, TaskLanguageSpec


def one_hot_table(num_instructions: int) -> np.ndarray:
    """(S, S) identity: instruction i is encoded as e_i (One-hot baseline)."""
    return np.eye(num_instructions, dtype=np.float32)


def goal_one_hot(goal_ids: np.ndarray, num_goals: int) -> np.ndarray:
    """(N, num_goals) one-hot of each tuple's goal: the Handcrafted baseline's translation target."""
    return np.eye(num_goals, dtype=np.float32)[np.asarray(goal_ids)]


def straight_through_bernoulli(logits: jax.Array, rng: jax.Array | None) -> jax.Array:
    """Binary sample with the gradient of its probability (sigmoid); ``rng=None`` thresholds at 0.5."""
    probs = jax.nn.sigmoid(logits)
    if rng is None:
        hard = (probs > 0.5).astype(probs.dtype)
    else:
        hard = (jax.random.uniform(rng, probs.shape) < probs).astype(probs.dtype)
    return hard + (probs - jax.lax.stop_gradient(probs))


class NLEncodingLayer(nn.Module):
    """Dense layer on a frozen sentence embedding: binary (straight-through) or continuous (tanh) code."""

    size: int
    binary: bool

    @nn.compact
    def __call__(self, sentence_embedding: jax.Array, rng: jax.Array | None = None) -> jax.Array:
        logits = nn.Dense(self.size)(sentence_embedding)
        return straight_through_bernoulli(logits, rng) if self.binary else jnp.tanh(logits)


class AlignedEncodingLayer(TaskLanguageGenerator):
    """Appendix E.3's "Aligned" encoding: the TL generator's networks on the sentence embedding instead of a state
    pair (call it with the embedding alone), trained by RL with the policy. Binary: straight-through one-hot
    arguments and 0/1 predicates, as the generator's; continuous: their softmax probabilities."""

    binary: bool = True

    def discrete(self) -> bool:
        return self.binary


class LatentActionAutoencoder(nn.Module):
    """GLA: encode (s, s') into a binary latent action z, decode s' from (s, z) (Table 2 sizes)."""

    latent_size: int
    observation_size: int
    encoder_hidden: Sequence[int] = (128, 128, 64)
    decoder_hidden: Sequence[int] = (64, 128, 128)

    def setup(self):
        self.encoder = ReluMLP((*self.encoder_hidden, self.latent_size))
        self.decoder = ReluMLP((*self.decoder_hidden, self.observation_size))

    def encode(self, state: jax.Array, next_state: jax.Array, rng: jax.Array | None = None) -> jax.Array:
        """(..., obs) x 2 -> (..., latent_size) binary latent action."""
        return straight_through_bernoulli(self.encoder(jnp.concatenate([state, next_state], -1)), rng)

    def decode(self, state: jax.Array, latent: jax.Array) -> jax.Array:
        """Predicts s' (..., obs) from s and the latent action."""
        return self.decoder(jnp.concatenate([state, latent], -1))

    def __call__(self, state, next_state, rng=None):
        latent = self.encode(state, next_state, rng)
        return self.decode(state, latent), latent


def make_train_gla(latent_size: int, observation_size: int, steps: int, batch_size: int, learning_rate: float):
    """The auto-encoder as an ``AdamFit``: ``fit(rng, states, final_states) -> (params, losses)`` (MSE of s_T)."""
    model = LatentActionAutoencoder(latent_size, observation_size)

    def init_params(rng, states, final_states):
        return model.init(rng, states[:1], final_states[:1])

    def loss_fn(params, rng_step, states, final_states):
        rng_rows, rng_noise = jax.random.split(rng_step)
        rows = jax.random.randint(rng_rows, (batch_size,), 0, states.shape[0])
        prediction, _ = model.apply(params, states[rows], final_states[rows], rng_noise)
        return jnp.mean((prediction - final_states[rows]) ** 2)

    return AdamFit(init_params, loss_fn, learning_rate, steps)


def make_gla_codes(latent_size: int, observation_size: int):
    """Returns ``codes(params, states, final_states) -> (N, latent_size)`` deterministic latent actions."""
    model = LatentActionAutoencoder(latent_size, observation_size)

    def codes(params, states, final_states):
        return model.apply(params, states, final_states, None, method=LatentActionAutoencoder.encode)

    return codes


class EncodingLayerConditioner(Conditioner):
    """BERT-binary / BERT-continuous: a trainable dense layer (``NLEncodingLayer``) on frozen sentence features, or
    with ``aligned`` the TL generator's architecture (``AlignedEncodingLayer``, the paper's "Aligned" baselines).

    Args:
        sentence_features: (num_instructions, D) the features of every instruction (the language cache's
            sentence readout).
        goal_sentences_by_split: as ``InstructionTableConditioner``.
        size: encoding size (|L_T| in the paper's comparison).
        binary: straight-through Bernoulli bits (BERT-binary) or a continuous layer (BERT-continuous).
        aligned: None, or (task-language spec, hidden layers) of an ``AlignedEncodingLayer`` (``size`` must then be
            the spec's).
    """

    def __init__(
        self,
        sentence_features: Any,
        goal_sentences_by_split: Mapping,
        size: int,
        binary: bool,
        aligned: tuple[TaskLanguageSpec, Sequence[int]] | None = None,
    ):
        self.features = jnp.asarray(sentence_features, jnp.float32)
        if aligned is None:
            self.layer = NLEncodingLayer(size, binary)
        else:
            spec, hidden = aligned
            if spec.size != size:
                raise ValueError(f"aligned encoding: size {size} differs from the task-language spec's {spec.size}")
            self.layer = AlignedEncodingLayer(spec, tuple(hidden), binary=binary)
        self.size = size
        self.sampler = InstructionSampler(goal_sentences_by_split, num_instructions=len(self.features))

    def init(self, rng: jax.Array) -> Any:
        return self.layer.init(rng, self.features[:1])

    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        return self.sampler.sample(rng, goal, split)

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        out = self.layer.apply(params, self.features[jnp.maximum(instruction, 0)], None)
        return jnp.where(instruction >= 0, out, 0.0)


def make_behaviour_cloning(
    env: Any,
    conditioner: Conditioner,
    dataset: Any,
    hidden_sizes: Sequence[int],
    batch_size: int,
    learning_rate: float,
    steps: int,
    normalize_observations: bool = False,
) -> AdamFit:
    """``fit(rng) -> ({"policy", "conditioner"}, losses)``: maximise log pi(a_i | s_i, enc(L_N)) on a task dataset.

    The pre-trained BERT-* baselines start PPO from these weights (policy and encoding layer).

    Args:
        env: the env the policy acts in (observation size, action spec).
        conditioner: the instruction encoder trained jointly.
        dataset: a ``TaskDataset`` ((s_i, a_i, instruction id) tuples).
        hidden_sizes: the policy MLP's hidden layers (the IFP's).
        batch_size, learning_rate, steps: Adam settings.
        normalize_observations: standardise states by the dataset's statistics, returned as
            ``params["obs_normalizer"]`` (PPO then goes on updating them), as an IFP that normalises does.
    """
    networks = make_ppo_networks(env.observation_size, conditioner.size, env.action_spec, hidden_sizes)
    states = jnp.asarray(dataset.states, jnp.float32)
    actions = jnp.asarray(dataset.actions)
    instructions = jnp.asarray(dataset.instruction_ids, jnp.int32)

    def loss_fn(params, rng_step):
        if OBS_NORMALIZER in params:  # statistics, not parameters: zero gradient, so Adam leaves them
            params = {**params, OBS_NORMALIZER: jax.lax.stop_gradient(params[OBS_NORMALIZER])}
        rows = jax.random.randint(rng_step, (batch_size,), 0, states.shape[0])
        cond = jax.vmap(conditioner.apply, in_axes=(None, 0))(params["conditioner"], instructions[rows])
        dist = networks.policy.apply(params["policy"], network_inputs(params, states[rows], cond))
        return -networks.distribution.log_prob(dist, actions[rows]).mean()

    def init_params(rng):
        rng_policy, rng_conditioner = jax.random.split(rng)
        params = {"policy": networks.init(rng_policy)["policy"], "conditioner": conditioner.init(rng_conditioner)}
        if normalize_observations:
            params[OBS_NORMALIZER] = update_observation_stats(init_observation_stats(env.observation_size), states)
        return params

    return AdamFit(init_params, loss_fn, learning_rate, steps)
