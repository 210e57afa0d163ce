"""PPO numerics as pure module-level functions: GAE, the clipped loss and SB3-style reward normalisation."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from talar_jax.types import ReturnNormalizerState


def compute_gae(
    rewards: jax.Array,
    values: jax.Array,
    bootstrap_value: jax.Array,
    terminations: jax.Array,
    truncations: jax.Array,
    gamma: float,
    gae_lambda: float,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation over a time-major rollout of auto-resetting envs.

    ``values[t + 1]`` (or ``bootstrap_value`` after the last step) is the value of the state after step t,
    unless an episode ended at t: after a termination the next value is 0; after a truncation the true
    next state was replaced by a fresh episode, so (as Brax) the truncated step gets advantage 0 and
    target = its own value (it carries no learning signal), and the recursion is cut there.

    Args:
        rewards: (T, ...) rewards.
        values: (T, ...) value estimates of the states the actions were taken in.
        bootstrap_value: (...) value of the state after the last step.
        terminations: (T, ...) 1.0 where the episode terminated at step t.
        truncations: (T, ...) 1.0 where the episode hit its time limit at step t (and did not terminate).
        gamma: discount.
        gae_lambda: GAE lambda.

    Returns:
        (advantages, returns), each (T, ...); returns = advantages + values (the value targets).
    """
    next_values = jnp.concatenate([values[1:], bootstrap_value[None]], axis=0)
    keep = 1.0 - truncations
    deltas = (rewards + gamma * (1.0 - terminations) * next_values - values) * keep
    continues = gamma * gae_lambda * (1.0 - terminations) * keep

    def backward(advantage_next: jax.Array, step: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        delta, cont = step
        advantage = delta + cont * advantage_next
        return advantage, advantage

    _, advantages = jax.lax.scan(backward, jnp.zeros_like(bootstrap_value), (deltas, continues), reverse=True)
    return advantages, advantages + values


def compute_ppo_loss(
    log_prob: jax.Array,
    old_log_prob: jax.Array,
    advantages: jax.Array,
    values: jax.Array,
    returns: jax.Array,
    entropy: jax.Array,
    clip_eps: float,
    vf_coef: float,
    ent_coef: float,
    normalize_advantages: bool = True,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """SB3's PPO loss on one minibatch: clipped surrogate + vf_coef * MSE(value) - ent_coef * entropy.

    Args:
        log_prob: (B,) log-probabilities of the taken actions under the current policy.
        old_log_prob: (B,) their log-probabilities under the acting policy.
        advantages: (B,) GAE advantages (normalised here to mean 0, std 1 when ``normalize_advantages``).
        values: (B,) current value predictions.
        returns: (B,) value targets.
        entropy: (B,) entropy of the current policy.
        clip_eps: ratio clip range.
        vf_coef: value loss weight.
        ent_coef: entropy bonus weight.
        normalize_advantages: normalise advantages per minibatch (SB3 default).

    Returns:
        (loss, metrics) with metrics ``losses/{policy, value, entropy, approx_kl, clip_fraction}``.
    """
    if normalize_advantages:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    log_ratio = log_prob - old_log_prob
    ratio = jnp.exp(log_ratio)
    surrogate = jnp.minimum(ratio * advantages, jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * advantages)
    policy_loss = -jnp.mean(surrogate)
    value_loss = jnp.mean((returns - values) ** 2)
    entropy_mean = jnp.mean(entropy)
    loss = policy_loss + vf_coef * value_loss - ent_coef * entropy_mean
    metrics = {
        "losses/policy": policy_loss,
        "losses/value": value_loss,
        "losses/entropy": entropy_mean,
        "losses/approx_kl": jnp.mean((ratio - 1.0) - log_ratio),
        "losses/clip_fraction": jnp.mean((jnp.abs(ratio - 1.0) > clip_eps).astype(jnp.float32)),
    }
    return loss, metrics


def init_return_normalizer(num_envs: int) -> ReturnNormalizerState:
    """Fresh statistics: mean 0, variance 1, count 1e-4 (SB3 ``RunningMeanStd``)."""
    return ReturnNormalizerState(
        returns=jnp.zeros((num_envs,), jnp.float32),
        mean=jnp.zeros((), jnp.float32),
        var=jnp.ones((), jnp.float32),
        count=jnp.full((), 1e-4, jnp.float32),
    )


def normalize_reward_step(
    state: ReturnNormalizerState, rewards: jax.Array, dones: jax.Array, gamma: float, clip: float = 10.0
) -> tuple[ReturnNormalizerState, jax.Array]:
    """One vectorised env step of SB3 ``VecNormalize`` (reward part only).

    returns <- gamma * returns + rewards; update the running variance with the batch of returns;
    reward / sqrt(var + 1e-8) clipped to [-clip, clip]; returns <- 0 where an episode ended.

    Args:
        state: statistics before the step.
        rewards: (num_envs,) raw rewards.
        dones: (num_envs,) 1.0 where an episode ended (terminated or truncated) at this step.
        gamma: discount of the tracked return.
        clip: clip of the normalised reward.

    Returns:
        (state', normalised rewards (num_envs,)).
    """
    returns = state.returns * gamma + rewards
    batch_mean, batch_var, batch_count = jnp.mean(returns), jnp.var(returns), returns.shape[0]
    delta = batch_mean - state.mean
    total = state.count + batch_count
    mean = state.mean + delta * batch_count / total
    m2 = state.var * state.count + batch_var * batch_count + delta**2 * state.count * batch_count / total
    var = m2 / total
    normalized = jnp.clip(rewards / jnp.sqrt(var + 1e-8), -clip, clip)
    new_state = ReturnNormalizerState(returns=returns * (1.0 - dones), mean=mean, var=var, count=total)
    return new_state, normalized


def normalize_rollout_rewards(
    state: ReturnNormalizerState, rewards: jax.Array, dones: jax.Array, gamma: float, clip: float = 10.0
) -> tuple[ReturnNormalizerState, jax.Array]:
    """``normalize_reward_step`` over a (T, num_envs) rollout, in time order (same result as step by step)."""

    def step(carry: ReturnNormalizerState, inputs: tuple[jax.Array, jax.Array]):
        return normalize_reward_step(carry, inputs[0], inputs[1], gamma, clip)

    return jax.lax.scan(step, state, (rewards, dones))
