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

from talar_jax.conditioning import Conditioner, InstructionSampler, gather_table_codes, split_instruction_ids
from talar_jax.language.bert import BertModel, mean_pool
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

    The aligned layer (N_pn + N_a MLPs) costs several times the policy per input row, so with ``aligned`` rows are
    gathered from an encoding of the instruction table: every instruction once per rollout or evaluation
    (``freeze``), the training split's distinct instructions once per loss minibatch (``apply_batch`` on unfrozen
    parameters, the same gradient as per row; other instructions read zeros there, as the loss sees training
    instructions only). The plain layer, one matmul, stays per row, which keeps recorded BERT-binary /
    -continuous runs reproducible bit for bit.
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
        if self.encodes_table:
            self.loss_rows = jnp.asarray(split_instruction_ids(goal_sentences_by_split, "train"), jnp.int32)

    def init(self, rng: jax.Array) -> Any:
        return self.layer.init(rng, self.features[:1])

    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        return self.sampler.sample(rng, goal, split)

    @property
    def encodes_table(self) -> bool:
        """Whether rows are gathered from the whole instruction table's encoding (the aligned layer)."""
        return isinstance(self.layer, AlignedEncodingLayer)

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        if self.encodes_table and "codes" in params:
            return self.apply_batch(params, jnp.asarray(instruction)[None])[0]
        out = self.layer.apply(params, self.features[jnp.maximum(instruction, 0)], None)
        return jnp.where(instruction >= 0, out, 0.0)

    def encode(self, params: Any, rows: jax.Array) -> jax.Array:
        """(R, size) codes of the instructions ``rows``."""
        return self.layer.apply(params, self.features[rows], None)

    def freeze(self, params: Any) -> Any:
        if not self.encodes_table:
            return params
        return {"codes": jax.lax.stop_gradient(self.encode(params, jnp.arange(len(self.features))))}

    def apply_batch(self, params: Any, instructions: jax.Array) -> jax.Array:
        if not self.encodes_table:
            return super().apply_batch(params, instructions)
        return gather_table_codes(params, instructions, self.encode, self.loss_rows, len(self.features))


class FinetunedBertConditioner(Conditioner):
    """Appendix E.5's fine-tuned BERT-binary / -continuous: the encoding layer of ``EncodingLayerConditioner`` on the
    pooled sentence embedding of a BERT whose weights the policy's loss trains too (from the pre-trained ones).

    The language model runs inside the training loop here only: the loss (``apply_batch``) encodes every training
    instruction in one batched forward pass per minibatch (a minibatch's rows then gather from it), and a rollout or
    evaluation encodes every instruction once (``freeze``) rather than once per env step. With
    ``first_layer > 0`` only the top encoder layers train: the hidden state below them is computed once from the
    pre-trained weights and kept as a constant (cheaper; the paper trains all of BERT, ``first_layer = 0``).

    Args:
        bert_config: the encoder's ``BertConfig``.
        pretrained: the encoder's ``{"params": ...}`` (``BertEncoder.params``).
        input_ids, attention_mask: (N, T) word pieces with [CLS]/[SEP] of every instruction (cache rows), padded.
        goal_sentences_by_split: as ``InstructionTableConditioner``.
        size, binary: as ``EncodingLayerConditioner``.
        first_layer: index of the lowest trained encoder layer (0: the embeddings and every layer).
        loss_rows: the instruction ids the loss sees (the training split's): the rows ``apply_batch`` encodes.
    """

    def __init__(
        self,
        bert_config: Any,
        pretrained: Mapping,
        input_ids: Any,
        attention_mask: Any,
        goal_sentences_by_split: Mapping,
        size: int,
        binary: bool,
        first_layer: int,
        loss_rows: Any,
    ):
        layers = bert_config.num_hidden_layers
        if not 0 <= first_layer < layers:
            raise ValueError(f"first trained BERT layer must lie in 0..{layers - 1}, got {first_layer}")
        self.mask = jnp.asarray(attention_mask, jnp.int32)
        self.model = BertModel(bert_config, layers=(first_layer, layers))
        params = pretrained["params"]
        if first_layer == 0:
            self.inputs = jnp.asarray(input_ids, jnp.int32)
            self.pretrained = params
        else:  # the frozen lower layers run once, here
            below = BertModel(bert_config, layers=(0, first_layer))
            self.inputs = jax.jit(below.apply)(pretrained, jnp.asarray(input_ids, jnp.int32), self.mask)
            self.pretrained = {f"layer_{i}": params[f"layer_{i}"] for i in range(first_layer, layers)}
        self.layer = NLEncodingLayer(size, binary)
        self.size = size
        self.hidden_size = bert_config.hidden_size
        self.loss_rows = jnp.asarray(np.unique(np.asarray(loss_rows)), jnp.int32)
        self.sampler = InstructionSampler(goal_sentences_by_split, num_instructions=len(self.mask))

    @classmethod
    def from_cache(
        cls,
        encoder: Any,
        cache: Any,
        goal_sentences_by_split: Mapping,
        size: int,
        binary: bool,
        first_layer: int,
        loss_rows: Any,
    ) -> FinetunedBertConditioner:
        """The conditioner over every sentence of a language cache (its word pieces; padding masked), starting from
        ``encoder``'s weights (a ``load_encoder`` result: ``config`` and ``params``)."""
        mask = (np.arange(cache.token_ids.shape[1])[None, :] < cache.token_lengths[:, None]).astype(np.int32)
        return cls(
            encoder.config,
            encoder.params,
            cache.token_ids,
            mask,
            goal_sentences_by_split,
            size,
            binary,
            first_layer,
            loss_rows,
        )

    def init(self, rng: jax.Array) -> Any:
        layer = self.layer.init(rng, jnp.zeros((1, self.hidden_size), jnp.float32))
        return {"bert": self.pretrained, "layer": layer}

    def encode(self, params: Any, rows: jax.Array) -> jax.Array:
        """(R, size) codes of the instructions ``rows`` under ``params`` (one BERT pass over them)."""
        mask = self.mask[rows]
        hidden = self.model.apply({"params": params["bert"]}, self.inputs[rows], mask)
        return self.layer.apply(params["layer"], mean_pool(hidden, mask), None)

    def freeze(self, params: Any) -> Any:
        return {"codes": jax.lax.stop_gradient(self.encode(params, jnp.arange(len(self.mask))))}

    def sample(self, rng: jax.Array, goal: jax.Array, split: str) -> jax.Array:
        return self.sampler.sample(rng, goal, split)

    def apply(self, params: Any, instruction: jax.Array) -> jax.Array:
        return self.apply_batch(params, jnp.asarray(instruction)[None])[0]

    def apply_batch(self, params: Any, instructions: jax.Array) -> jax.Array:
        return gather_table_codes(params, instructions, self.encode, self.loss_rows, len(self.mask))


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
        cond = conditioner.apply_batch(params["conditioner"], instructions[rows])
        dist = networks.policy.apply(params["policy"], network_inputs(params, states[rows], cond))
        return -networks.distribution.log_prob(dist, actions[rows]).mean()

    def init_params(rng):
        rng_policy, rng_conditioner = jax.random.split(rng)
        params = {"policy": networks.init(rng_policy)["policy"], "conditioner": conditioner.init(rng_conditioner)}
        if normalize_observations:
            params[OBS_NORMALIZER] = update_observation_stats(init_observation_stats(env.observation_size), states)
        return params

    return AdamFit(init_params, loss_fn, learning_rate, steps)
