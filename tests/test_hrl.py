"""Hierarchical RL (paper section 5.3): the factorised TL action distribution, the high-level step's holding of
the frozen low-level policy, and the ``experiments.hrl`` command end to end on a quick run."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from envs.base import ActionSpec, State
from experiments import hrl
from talar_jax.hrl import HighLevelEnv, talar_action_spec, task_language_code
from talar_jax.networks import FactorisedCategorical, make_distribution
from talar_jax.task_language import TaskLanguageSpec


def test_factorised_distribution_matches_per_head_reference():
    spec = TaskLanguageSpec(num_predicates=3, num_arguments=2, arg_size=4)
    action_spec = talar_action_spec(spec)
    assert action_spec.sizes == (2, 2, 2, 4, 4) and action_spec.size == 14
    distribution = make_distribution(action_spec)
    assert isinstance(distribution, FactorisedCategorical)
    logits = jax.random.normal(jax.random.key(0), (7, 14))
    action = distribution.sample(jax.random.key(1), logits)
    assert action.shape == (7, 5) and action.dtype == jnp.int32
    assert np.all(np.asarray(action) < np.array(action_spec.sizes))
    # per-head reference with plain numpy softmaxes
    bounds = np.cumsum((0, *action_spec.sizes))
    log_prob, entropy = np.zeros(7), np.zeros(7)
    for head in range(5):
        head_logits = np.asarray(logits[:, bounds[head] : bounds[head + 1]], np.float64)
        p = np.exp(head_logits - head_logits.max(1, keepdims=True))
        p /= p.sum(1, keepdims=True)
        log_prob += np.log(p[np.arange(7), np.asarray(action[:, head])])
        entropy -= (p * np.log(p)).sum(1)
    np.testing.assert_allclose(distribution.log_prob(logits, action), log_prob, rtol=1e-5)
    np.testing.assert_allclose(distribution.entropy(logits), entropy, rtol=1e-5)
    np.testing.assert_array_equal(distribution.mode(logits)[:, 4], np.argmax(logits[:, 10:14], 1))
    # the code the IFP reads: predicate bits, then argument one-hots
    code = task_language_code(spec, jnp.array([1, 0, 1, 3, 0]))
    np.testing.assert_array_equal(code, [1, 0, 1, 0, 0, 0, 1, 1, 0, 0, 0])


@struct.dataclass
class _Counter:
    count: jax.Array


class CountingEnv:
    """Low-level stand-in: reward = the code's first entry + the step index; ends after ``limit`` steps."""

    observation_size, limit = 1, 25

    def reset(self, rng):
        zero = jnp.zeros((), jnp.float32)
        return State(data=_Counter(zero), obs=zero[None], reward=zero, done=zero, metrics={"success": zero})

    def step(self, state, action):
        count = state.data.count + 1.0
        done = (count >= self.limit).astype(jnp.float32)
        return state.replace(data=_Counter(count), obs=count[None], reward=action + count, done=done)


def test_high_level_step_holds_the_low_level_policy_and_sums_its_rewards():
    calls = []

    def low_policy(obs, code, rng):
        calls.append(1)  # traced once per scan body
        return code[0]

    env = HighLevelEnv(CountingEnv(), low_policy, ActionSpec("discrete", 3), lambda a: jnp.array([a], jnp.float32))
    step = jax.jit(env.step)
    state = step(env.reset(jax.random.key(0)), jnp.int32(2))
    assert float(state.data.data.count) == 10 and float(state.metrics["low_steps"]) == 10
    assert float(state.reward) == sum(2 + k for k in range(1, 11))  # ten low-level rewards summed
    state = step(state, jnp.int32(0))
    assert float(state.reward) == sum(range(11, 21)) and float(state.done) == 0
    state = step(state, jnp.int32(1))  # the low level ends after 25 steps: 5 more, then frozen
    assert float(state.data.data.count) == 25 and float(state.metrics["low_steps"]) == 5 and float(state.done) == 1
    assert float(state.reward) == sum(1 + k for k in range(21, 26))
    assert len(calls) == 1


@pytest.mark.parametrize(
    ("env_name", "methods"),
    [
        ("clevr", ["talar", "hal"]),
        pytest.param("clevr", ["flat"], marks=pytest.mark.slow),
        pytest.param("kitchen", ["talar"], marks=pytest.mark.slow),
    ],
)
def test_hrl_command_quick_end_to_end(env_name, methods, request, tmp_path, capsys):
    # the low level: the quick TALAR runs the experiment tests share. The default suite covers the two high-level
    # action spaces; the flat baseline and the kitchen (the wiring is shared) run with --all, as each adds a minute.
    run_dir = request.getfixturevalue(f"{env_name}_run")[0]
    args = ["--env", env_name, "--quick", "--seeds", "2", "--out", str(tmp_path / "hrl"), "--run-dir", str(run_dir)]
    args += ["--methods", *methods, "--episode-length", "2", "--env-steps", "5120", "--no-progress"]
    summary = hrl.run_command(args)
    assert set(summary["methods"]) == set(methods) and summary["hold"] == 10
    for method in methods:
        returns = np.asarray(summary["methods"][method]["returns_per_seed"])
        assert returns.shape[0] == 2 and np.isfinite(returns).all() and (returns >= 0).all()
        assert summary["methods"][method]["env_steps"][-1] >= 5120
    saved = json.loads((tmp_path / "hrl" / "summary.json").read_text())
    assert saved["low_level_env_steps_per_seed"] == 5120
    assert (tmp_path / "hrl" / "hrl.png").stat().st_size > 0
    assert "area under the curve" in (tmp_path / "hrl" / "results.md").read_text()
    capsys.readouterr()
    assert hrl.main(["--env", "nope"]) == 2
    assert "error: unknown env" in capsys.readouterr().err
