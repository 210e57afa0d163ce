"""The policy-stage benchmark's FLOP count of a PPO update's learning (the learner's floor is judged by it)."""

import dataclasses

from benchmarks.policy_stage import learning_flops_per_update
from talar_jax.ppo import PPOConfig
from tests.point_env import PointConfig, PointEnv


def test_learning_flops_count_forward_and_backward_of_both_networks_over_every_epoch():
    env = PointEnv(PointConfig(continuous=True))  # 2-D observation, 4 goals (one-hot), 2-D action
    config = PPOConfig(num_envs=4, rollout_length=8, minibatch_size=8, num_epochs=3, num_seeds=2, hidden_sizes=(5,))
    inputs = env.observation_size + env.num_goals
    per_sample = 2 * (inputs * 5 + 5 * env.action_spec.size) + 2 * (inputs * 5 + 5 * 1)  # policy + value, 2/MAC
    assert learning_flops_per_update(config, env) == 3 * per_sample * 32 * 3 * 2  # x3 fwd+bwd, batch, epochs, seeds
    deeper = dataclasses.replace(config, hidden_sizes=(5, 5))
    assert learning_flops_per_update(deeper, env) > learning_flops_per_update(config, env)
