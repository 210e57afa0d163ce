"""Brax's own PPO trainer runs on the CLEVR env unchanged (through ``envs.wrap_for_brax_training``): the training
function of examples/brax_ppo_clevr.py, at a tiny size."""

import importlib
from pathlib import Path

import jax
import numpy as np

import envs

EXAMPLES = Path(__file__).parent.parent / "examples"


def test_brax_ppo_trains_a_few_iterations_on_clevr(monkeypatch):
    # The example runs as a script, with examples/ on sys.path (its provenance import needs that).
    monkeypatch.syspath_prepend(str(EXAMPLES))
    example = importlib.import_module("brax_ppo_clevr")
    # MuJoCo C physics keeps the compile small; brax sees 40 float scores per action and the env takes the argmax.
    env = envs.make("clevr", physics="c", goal_observation=True)
    progress = []
    make_policy, params = example.train(
        env,
        2 * 8 * 10 * 4,  # two training iterations (batch 8 x unroll 10 x 4 minibatches each)
        0,
        lambda step, metrics: progress.append((step, metrics)),
        num_envs=8,
        hidden=(32,),
        num_minibatches=4,
        num_updates_per_batch=1,
        num_evals=2,
    )
    assert params is not None and len(jax.tree.leaves(params)) > 0
    assert all(np.isfinite(np.asarray(leaf)).all() for leaf in jax.tree.leaves(params))
    assert progress and progress[-1][0] > 0
    metrics = progress[-1][1]
    for key in ("eval/episode_reward", "eval/episode_success"):
        assert key in metrics and np.isfinite(metrics[key]), key
    action = make_policy(params, deterministic=True)(env.reset(jax.random.key(0)).obs, jax.random.key(1))[0]
    assert action.shape == (env.action_size,)
