"""Policy/value MLPs on [observation, conditioning vector] and the action distributions (chosen by action spec)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

from envs.base import ActionSpec

_LOG_2PI = math.log(2.0 * math.pi)


class MLP(nn.Module):
    """Dense layers with ``activation`` between them (not after the last), orthogonal initialisation.

    Attributes:
        layer_sizes: output width of every layer, the last one included.
        activation: hidden activation.
        hidden_scale: orthogonal gain of the hidden layers (sqrt(2), as SB3).
        final_scale: orthogonal gain of the last layer (0.01 for policy logits/means, 1 for values).
    """

    layer_sizes: Sequence[int]
    activation: Callable[[jax.Array], jax.Array] = nn.tanh
    hidden_scale: float = math.sqrt(2.0)
    final_scale: float = 1.0

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for index, size in enumerate(self.layer_sizes):
            last = index == len(self.layer_sizes) - 1
            scale = self.final_scale if last else self.hidden_scale
            x = nn.Dense(size, kernel_init=nn.initializers.orthogonal(scale), bias_init=nn.initializers.zeros)(x)
            if not last:
                x = self.activation(x)
        return x


class PolicyNetwork(nn.Module):
    """Maps [obs, cond] to distribution parameters: logits (A,) or (mean (A,), log_std (A,)).

    The Gaussian's log standard deviation is a state-independent parameter initialised at 0 (SB3).
    """

    hidden_sizes: Sequence[int]
    action_size: int
    continuous: bool

    @nn.compact
    def __call__(self, x: jax.Array) -> Any:
        out = MLP((*self.hidden_sizes, self.action_size), final_scale=0.01)(x)
        if not self.continuous:
            return out
        log_std = self.param("log_std", nn.initializers.zeros, (self.action_size,))
        return out, jnp.broadcast_to(log_std, out.shape)


class ValueNetwork(nn.Module):
    """Maps [obs, cond] to a scalar value."""

    hidden_sizes: Sequence[int]

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        return MLP((*self.hidden_sizes, 1), final_scale=1.0)(x)[..., 0]


@dataclasses.dataclass(frozen=True)
class Categorical:
    """Categorical over ``size`` actions, parameterised by logits (..., size); actions are int32 (...)."""

    size: int

    def sample(self, rng: jax.Array, logits: jax.Array) -> jax.Array:
        return jax.random.categorical(rng, logits).astype(jnp.int32)

    def mode(self, logits: jax.Array) -> jax.Array:
        return jnp.argmax(logits, axis=-1).astype(jnp.int32)

    def log_prob(self, logits: jax.Array, action: jax.Array) -> jax.Array:
        log_probs = jax.nn.log_softmax(logits)
        return jnp.take_along_axis(log_probs, action[..., None].astype(jnp.int32), axis=-1)[..., 0]

    def entropy(self, logits: jax.Array) -> jax.Array:
        log_probs = jax.nn.log_softmax(logits)
        return -jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1)


@dataclasses.dataclass(frozen=True)
class ClippedGaussian:
    """Diagonal Gaussian over (..., size) whose samples the env clips to its bounds (SB3's default for Box actions).

    Log-probabilities and entropy are those of the unclipped Gaussian; actions are stored unclipped.
    Parameters are ``(mean, log_std)``, each (..., size).
    """

    size: int
    low: float
    high: float

    def sample(self, rng: jax.Array, dist_params: tuple[jax.Array, jax.Array]) -> jax.Array:
        mean, log_std = dist_params
        return mean + jnp.exp(log_std) * jax.random.normal(rng, mean.shape)

    def mode(self, dist_params: tuple[jax.Array, jax.Array]) -> jax.Array:
        return dist_params[0]

    def log_prob(self, dist_params: tuple[jax.Array, jax.Array], action: jax.Array) -> jax.Array:
        mean, log_std = dist_params
        z = (action - mean) * jnp.exp(-log_std)
        return jnp.sum(-0.5 * z * z - log_std - 0.5 * _LOG_2PI, axis=-1)

    def entropy(self, dist_params: tuple[jax.Array, jax.Array]) -> jax.Array:
        return jnp.sum(dist_params[1] + 0.5 * (1.0 + _LOG_2PI), axis=-1)


@dataclasses.dataclass(frozen=True)
class FactorisedCategorical:
    """Independent categoricals, one per head (head i over ``sizes[i]`` values), from logits (..., sum(sizes)).

    Actions are int32 (..., num_heads); the log-probability and the entropy are the sums over heads. A task-language
    code is such an action: N_pn two-way predicate heads and N_a argument heads of ``arg_size``.
    """

    sizes: tuple[int, ...]

    def _split(self, logits: jax.Array) -> list[jax.Array]:
        bounds = list(itertools.accumulate(self.sizes))[:-1]
        return jnp.split(logits, bounds, axis=-1)

    def sample(self, rng: jax.Array, logits: jax.Array) -> jax.Array:
        keys = jax.random.split(rng, len(self.sizes))
        heads = [jax.random.categorical(key, head) for key, head in zip(keys, self._split(logits), strict=True)]
        return jnp.stack(heads, axis=-1).astype(jnp.int32)

    def mode(self, logits: jax.Array) -> jax.Array:
        return jnp.stack([jnp.argmax(head, axis=-1) for head in self._split(logits)], axis=-1).astype(jnp.int32)

    def log_prob(self, logits: jax.Array, action: jax.Array) -> jax.Array:
        heads = self._split(logits)
        return sum(Categorical(h.shape[-1]).log_prob(h, action[..., i]) for i, h in enumerate(heads))

    def entropy(self, logits: jax.Array) -> jax.Array:
        return sum(Categorical(head.shape[-1]).entropy(head) for head in self._split(logits))


Distribution = Categorical | ClippedGaussian | FactorisedCategorical


def make_distribution(action_spec: ActionSpec) -> Distribution:
    """The action distribution for an env's action spec (the only place that looks at ``action_spec.kind``)."""
    if action_spec.kind == "discrete":
        return Categorical(action_spec.size)
    if action_spec.kind == "continuous":
        return ClippedGaussian(action_spec.size, action_spec.low, action_spec.high)
    if action_spec.kind == "multi_discrete":
        return FactorisedCategorical(tuple(action_spec.sizes))
    raise ValueError(f"unknown action kind {action_spec.kind!r}; valid kinds: discrete, continuous, multi_discrete")


OBS_NORMALIZER = "obs_normalizer"
"""Key of the observation statistics in PPO parameters (present only when observations are normalised)."""


def init_observation_stats(size: int) -> dict[str, jax.Array]:
    """Fresh running statistics of observations: mean 0, variance 1, count 1e-4 (SB3 ``RunningMeanStd``)."""
    return {
        "mean": jnp.zeros((size,), jnp.float32),
        "var": jnp.ones((size,), jnp.float32),
        "count": jnp.full((), 1e-4, jnp.float32),
    }


def update_observation_stats(stats: dict[str, jax.Array], obs: jax.Array) -> dict[str, jax.Array]:
    """Merges a batch of observations (..., size) into running statistics (parallel mean/variance update)."""
    obs = obs.reshape((-1, stats["mean"].shape[0]))
    batch_mean, batch_var, batch_count = jnp.mean(obs, axis=0), jnp.var(obs, axis=0), obs.shape[0]
    delta = batch_mean - stats["mean"]
    total = stats["count"] + batch_count
    m2 = stats["var"] * stats["count"] + batch_var * batch_count + delta**2 * stats["count"] * batch_count / total
    return {"mean": stats["mean"] + delta * batch_count / total, "var": m2 / total, "count": total}


def normalize_observation(stats: dict[str, jax.Array], obs: jax.Array, clip: float = 10.0) -> jax.Array:
    """(obs - mean) / sqrt(var + 1e-8) clipped to [-clip, clip] (SB3 ``VecNormalize`` defaults)."""
    return jnp.clip((obs - stats["mean"]) / jnp.sqrt(stats["var"] + 1e-8), -clip, clip)


def network_inputs(params: dict[str, Any], obs: jax.Array, cond: jax.Array) -> jax.Array:
    """[observation, conditioning vector], the observation normalised when ``params`` carry its statistics."""
    if OBS_NORMALIZER in params:
        obs = normalize_observation(params[OBS_NORMALIZER], obs)
    return jnp.concatenate([obs, cond], axis=-1)


class PPONetworks(NamedTuple):
    """The policy and value modules, the action distribution and the input sizes."""

    policy: PolicyNetwork
    value: ValueNetwork
    distribution: Distribution
    observation_size: int
    conditioning_size: int

    def init(self, rng: jax.Array) -> dict[str, Any]:
        """Fresh ``{"policy": ..., "value": ...}`` parameters."""
        rng_policy, rng_value = jax.random.split(rng)
        dummy = jnp.zeros((self.observation_size + self.conditioning_size,), jnp.float32)
        return {"policy": self.policy.init(rng_policy, dummy), "value": self.value.init(rng_value, dummy)}


def make_ppo_networks(
    observation_size: int, conditioning_size: int, action_spec: ActionSpec, hidden_sizes: Sequence[int] = (32, 64, 64)
) -> PPONetworks:
    """Separate policy and value MLPs (tanh) on [obs, cond]; the head follows ``action_spec``."""
    distribution = make_distribution(action_spec)
    return PPONetworks(
        policy=PolicyNetwork(tuple(hidden_sizes), action_spec.size, isinstance(distribution, ClippedGaussian)),
        value=ValueNetwork(tuple(hidden_sizes)),
        distribution=distribution,
        observation_size=observation_size,
        conditioning_size=conditioning_size,
    )


def make_inference_fn(networks: PPONetworks) -> Callable[..., Callable[..., jax.Array]]:
    """Returns ``make_policy(params, deterministic) -> policy(obs, cond, rng) -> action`` (one env; vmap it).

    ``params`` are the ``{"policy": ..., ...}`` parameters of one seed (observation statistics, when present,
    normalise the observation; other keys are ignored).
    """

    def make_policy(params: dict[str, Any], deterministic: bool = False) -> Callable[..., jax.Array]:
        def policy(obs: jax.Array, cond: jax.Array, rng: jax.Array) -> jax.Array:
            dist_params = networks.policy.apply(params["policy"], network_inputs(params, obs, cond))
            if deterministic:
                return networks.distribution.mode(dist_params)
            return networks.distribution.sample(rng, dist_params)

        return policy

    return make_policy
