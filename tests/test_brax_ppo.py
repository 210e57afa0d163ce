"""Brax's own PPO trainer runs on the CLEVR env unchanged (through ``envs.wrap_for_brax_training``)."""

import functools

import jax
import numpy as np
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import train as ppo

import envs


def test_brax_ppo_trains_a_few_iterations_on_clevr():
    # MuJoCo C physics keeps the compile small; brax sees 40 float scores per action and the env takes the argmax.
    env = envs.make("clevr", physics="c")
    progress = []
    network_factory = functools.partial(
        ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(32,), value_hidden_layer_sizes=(32,)
    )
    make_policy, params, metrics = ppo.train(
        environment=env,
        num_timesteps=2 * 8 * 10 * 4,  # two training iterations
        episode_length=env.episode_length,
        wrap_env_fn=envs.wrap_for_brax_training,
        num_envs=8,
        batch_size=8,
        num_minibatches=4,
        unroll_length=10,
        num_updates_per_batch=1,
        num_evals=2,
        num_eval_envs=8,
        network_factory=network_factory,
        progress_fn=lambda step, metrics: progress.append((step, metrics)),
        seed=0,
    )
    assert params is not None and len(jax.tree.leaves(params)) > 0
    assert all(np.isfinite(np.asarray(leaf)).all() for leaf in jax.tree.leaves(params))
    assert progress and progress[-1][0] > 0
    for key in ("eval/episode_reward", "eval/episode_success"):
        assert key in metrics and np.isfinite(metrics[key]), key
    action = make_policy(params, deterministic=True)(env.reset(jax.random.key(0)).obs, jax.random.key(1))[0]
    assert action.shape == (env.action_size,)
