"""Numeric tests of GAE, the clipped PPO loss, reward normalisation, distributions and conditioners."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs.base import ActionSpec
from talar_jax.conditioning import GoalOneHotConditioner, InstructionTableConditioner
from talar_jax.losses import compute_gae, compute_ppo_loss, init_return_normalizer, normalize_rollout_rewards
from talar_jax.networks import Categorical, ClippedGaussian, make_distribution


def _gae(rewards, values, bootstrap, terminations, truncations, gamma=0.5, lam=0.5):
    arrays = [jnp.asarray(x, jnp.float32) for x in (rewards, values, bootstrap, terminations, truncations)]
    return [np.asarray(x) for x in compute_gae(*arrays, gamma, lam)]


def test_gae_hand_worked():
    # gamma = lambda = 0.5, so gamma * lambda = 0.25; next values = [1.0, 2.0, bootstrap 1.0].
    rewards, values, bootstrap = [1.0, 0.0, 2.0], [0.5, 1.0, 2.0], 1.0
    # No episode end: deltas = [1 + .5*1 - .5, 0 + .5*2 - 1, 2 + .5*1 - 2] = [1, 0, 0.5]
    # adv2 = 0.5; adv1 = 0 + .25*.5 = 0.125; adv0 = 1 + .25*.125 = 1.03125
    adv, ret = _gae(rewards, values, bootstrap, [0, 0, 0], [0, 0, 0])
    np.testing.assert_allclose(adv, [1.03125, 0.125, 0.5], rtol=1e-6)
    np.testing.assert_allclose(ret, [1.53125, 1.125, 2.5], rtol=1e-6)
    # Termination at t=1: delta1 = 0 + 0 - 1 = -1 and the recursion stops: adv1 = -1; adv0 = 1 + .25*(-1) = 0.75
    adv, _ = _gae(rewards, values, bootstrap, [0, 1, 0], [0, 0, 0])
    np.testing.assert_allclose(adv, [0.75, -1.0, 0.5], rtol=1e-6)
    # Truncation at t=1: that step carries no signal (adv1 = 0, target = its value 1.0); adv0 = 1 + .25*0 = 1.0
    adv, ret = _gae(rewards, values, bootstrap, [0, 0, 0], [0, 1, 0])
    np.testing.assert_allclose(adv, [1.0, 0.0, 0.5], rtol=1e-6)
    np.testing.assert_allclose(ret[1], 1.0)


def _gae_reference(rewards, values, bootstrap, terminations, truncations, gamma, lam):
    """Plain-Python loop over time and envs."""
    steps, envs = len(rewards), len(rewards[0])
    advantages = [[0.0] * envs for _ in range(steps)]
    for env in range(envs):
        running = 0.0
        for t in reversed(range(steps)):
            next_value = values[t + 1][env] if t + 1 < steps else bootstrap[env]
            if truncations[t][env]:
                running = 0.0
            else:
                not_terminal = 1.0 - terminations[t][env]
                delta = rewards[t][env] + gamma * not_terminal * next_value - values[t][env]
                running = delta + gamma * lam * not_terminal * running
            advantages[t][env] = running
    return np.array(advantages)


def test_gae_matches_python_loop():
    rng = np.random.default_rng(0)
    steps, envs = 9, 4
    rewards, values, bootstrap = rng.normal(size=(steps, envs)), rng.normal(size=(steps, envs)), rng.normal(size=envs)
    ends = rng.random((steps, envs)) < 0.25
    terminations = (ends & (rng.random((steps, envs)) < 0.5)).astype(float)
    truncations = (ends & (terminations < 0.5)).astype(float)
    expected = _gae_reference(rewards, values, bootstrap, terminations, truncations, 0.97, 0.9)
    adv, ret = _gae(rewards, values, bootstrap, terminations, truncations, 0.97, 0.9)
    np.testing.assert_allclose(adv, expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ret, expected + values, rtol=1e-5, atol=1e-5)


def test_ppo_loss_hand_worked():
    # ratios [1.5, 0.5], advantages [1, -1], clip 0.2:
    # surrogate = [min(1.5, 1.2), min(-0.5, -0.8)] = [1.2, -0.8] -> policy loss -mean = -0.2
    # value loss = mean([(1-0)^2, (1-1)^2]) = 0.5; entropy mean 1.5
    # loss = -0.2 + 0.5 * 0.5 - 0.1 * 1.5 = -0.1; both ratios outside [0.8, 1.2] -> clip fraction 1
    # approx kl = mean(r - 1 - log r) = ((0.5 - log 1.5) + (-0.5 - log 0.5)) / 2 = 0.1438410
    loss, metrics = compute_ppo_loss(
        log_prob=jnp.log(jnp.array([1.5, 0.5])),
        old_log_prob=jnp.zeros(2),
        advantages=jnp.array([1.0, -1.0]),
        values=jnp.array([0.0, 1.0]),
        returns=jnp.array([1.0, 1.0]),
        entropy=jnp.array([1.0, 2.0]),
        clip_eps=0.2,
        vf_coef=0.5,
        ent_coef=0.1,
        normalize_advantages=False,
    )
    np.testing.assert_allclose(loss, -0.1, atol=1e-6)
    np.testing.assert_allclose(metrics["losses/policy"], -0.2, atol=1e-6)
    np.testing.assert_allclose(metrics["losses/value"], 0.5, atol=1e-6)
    np.testing.assert_allclose(metrics["losses/clip_fraction"], 1.0)
    np.testing.assert_allclose(metrics["losses/approx_kl"], 0.1438410, atol=1e-6)


def test_ppo_loss_matches_python_loop():
    rng = np.random.default_rng(1)
    n = 16
    log_prob, old, adv = rng.normal(scale=0.3, size=n), rng.normal(scale=0.3, size=n), rng.normal(size=n)
    values, returns, entropy = rng.normal(size=n), rng.normal(size=n), rng.random(n)
    mean = sum(adv) / n
    std = math.sqrt(sum((a - mean) ** 2 for a in adv) / n)
    surrogate = 0.0
    for i in range(n):
        a = (adv[i] - mean) / (std + 1e-8)
        r = math.exp(log_prob[i] - old[i])
        surrogate += min(r * a, min(max(r, 0.9), 1.1) * a) / n
    value_loss = sum((returns[i] - values[i]) ** 2 for i in range(n)) / n
    expected = -surrogate + 0.7 * value_loss - 0.01 * sum(entropy) / n
    args = [jnp.asarray(x, jnp.float32) for x in (log_prob, old, adv, values, returns, entropy)]
    loss, _ = compute_ppo_loss(*args, clip_eps=0.1, vf_coef=0.7, ent_coef=0.01)
    np.testing.assert_allclose(loss, expected, rtol=1e-5)


def test_reward_normalization_matches_sb3_style_reference():
    rng = np.random.default_rng(2)
    steps, envs, gamma = 12, 3, 0.9
    rewards = rng.normal(loc=3.0, scale=2.0, size=(steps, envs))
    dones = (rng.random((steps, envs)) < 0.2).astype(float)
    # Reference: SB3 VecNormalize reward path with RunningMeanStd(epsilon=1e-4), in float64 numpy.
    returns, mean, var, count = np.zeros(envs), 0.0, 1.0, 1e-4
    expected = []
    for t in range(steps):
        returns = returns * gamma + rewards[t]
        batch_mean, batch_var, batch_count = returns.mean(), returns.var(), envs
        delta, total = batch_mean - mean, count + batch_count
        mean, var = (
            mean + delta * batch_count / total,
            (var * count + batch_var * batch_count + delta**2 * count * batch_count / total) / total,
        )
        count = total
        expected.append(np.clip(rewards[t] / np.sqrt(var + 1e-8), -10, 10))
        returns[dones[t] > 0] = 0.0
    state, normalized = normalize_rollout_rewards(
        init_return_normalizer(envs), jnp.asarray(rewards, jnp.float32), jnp.asarray(dones, jnp.float32), gamma
    )
    np.testing.assert_allclose(normalized, np.array(expected), rtol=1e-4)
    np.testing.assert_allclose(state.var, var, rtol=1e-4)
    np.testing.assert_allclose(state.returns, returns, rtol=1e-4, atol=1e-5)


def test_distributions():
    assert isinstance(make_distribution(ActionSpec("discrete", 40)), Categorical)
    assert isinstance(make_distribution(ActionSpec("continuous", 9)), ClippedGaussian)
    with pytest.raises(ValueError, match="discrete, continuous"):
        make_distribution(ActionSpec("hybrid", 3))  # type: ignore[arg-type]
    categorical = Categorical(3)
    logits = jnp.log(jnp.array([0.2, 0.3, 0.5]))
    np.testing.assert_allclose(categorical.log_prob(logits, jnp.int32(2)), math.log(0.5), rtol=1e-6)
    np.testing.assert_allclose(categorical.entropy(logits), -sum(p * math.log(p) for p in (0.2, 0.3, 0.5)), rtol=1e-6)
    # Standard normal in 1-D at x = 1: log N = -1/2 - log(2 pi)/2 = -1.4189385; entropy = (1 + log 2 pi)/2.
    gaussian = ClippedGaussian(1, -1.0, 1.0)
    params = (jnp.zeros(1), jnp.zeros(1))
    np.testing.assert_allclose(gaussian.log_prob(params, jnp.ones(1)), -1.4189385, rtol=1e-6)
    np.testing.assert_allclose(gaussian.entropy(params), 1.4189385, rtol=1e-6)
    samples = gaussian.sample(jax.random.PRNGKey(0), (jnp.full((4000, 1), 0.3), jnp.full((4000, 1), math.log(0.5))))
    assert abs(float(samples.mean()) - 0.3) < 0.03 and abs(float(samples.std()) - 0.5) < 0.03
    draws = categorical.sample(jax.random.PRNGKey(1), jnp.broadcast_to(logits, (4000, 3)))
    np.testing.assert_allclose(np.bincount(np.asarray(draws), minlength=3) / 4000, [0.2, 0.3, 0.5], atol=0.03)


def test_conditioners():
    one_hot = GoalOneHotConditioner(5)
    assert int(one_hot.sample(jax.random.PRNGKey(0), jnp.int32(3), "test")) == 3
    np.testing.assert_array_equal(one_hot.apply({}, jnp.int32(3)), np.eye(5)[3])
    with pytest.raises(ValueError, match="valid splits: train, test"):
        one_hot.sample(jax.random.PRNGKey(0), jnp.int32(3), "val")
    # 3 goals; goal 0 -> instructions {0, 1}, goal 1 -> {2}, goal 2 -> none (train); test: goal 2 -> {3}
    table = np.arange(8, dtype=np.float32).reshape(4, 2)
    lookups = {"train": ([[0, 1], [2, -1], [-1, -1]], [2, 1, 0]), "test": ([[1], [2], [3]], [1, 1, 1])}
    conditioner = InstructionTableConditioner(table, lookups)
    sample = jax.jit(jax.vmap(conditioner.sample, in_axes=(0, None, None)), static_argnums=2)
    keys = jax.random.split(jax.random.PRNGKey(0), 200)
    assert set(np.asarray(sample(keys, 0, "train")).tolist()) == {0, 1}
    assert set(np.asarray(sample(keys, 1, "train")).tolist()) == {2}
    assert set(np.asarray(sample(keys, 2, "train")).tolist()) == {-1}
    assert set(np.asarray(sample(keys, 2, "test")).tolist()) == {3}
    np.testing.assert_array_equal(conditioner.apply({}, jnp.int32(2)), [4.0, 5.0])
    np.testing.assert_array_equal(conditioner.apply({}, jnp.int32(-1)), [0.0, 0.0])
    trainable = InstructionTableConditioner(table, lookups, trainable=True)
    params = trainable.init(jax.random.PRNGKey(0))
    np.testing.assert_array_equal(trainable.apply({"table": params["table"] * 2}, jnp.int32(1)), [4.0, 6.0])
    with pytest.raises(ValueError, match="must lie in"):
        InstructionTableConditioner(table, {"train": ([[0, 7]], [2])})
