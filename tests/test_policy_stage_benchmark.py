"""The speed benchmarks' arithmetic: the learner's FLOP count, the pipeline's full-budget estimate, and where the
pipeline benchmark times the bare physics."""

import dataclasses
from unittest import mock

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


def test_pipeline_estimate_adds_the_curves_evaluations_and_the_final_one():
    from benchmarks.pipeline import _ifp_full_budget

    ppo = PPOConfig(num_envs=4, rollout_length=8, minibatch_size=8, updates_per_chunk=1, total_env_steps=320)
    ppo = dataclasses.replace(ppo, eval_every_chunks=4, eval_episodes=10, final_eval_episodes=40)  # 10 chunks
    rows = [{"train/sps": 100.0}, {"train/sps": 64.0}, {"train/sps": 64.0, "eval/seconds": 8.0}]
    estimate = _ifp_full_budget(rows, ppo, seeds=2)
    # training: 320 steps x 2 seeds at 64 steps/s; 3 evaluations (chunks 4, 8, 10): two curve ones at 8 x 10 / 40
    assert estimate["ifp_evaluations_full"] == 3
    assert estimate["ifp_eval_full_s_estimate"] == 2 * 2.0 + 8.0
    assert estimate["ifp_full_s_estimate"] == 10.0 + 12.0


def test_pipeline_times_physics_windows_between_the_stages_and_restores_them():
    import experiments.methods.talar as talar_method
    import experiments.methods.translation as translation
    import experiments.pipeline as pipeline
    from benchmarks.pipeline import WINDOWS, physics_between_stages

    class FakeClock:
        def __init__(self):
            self.asked = []

        def time(self, seconds):
            self.asked.append(seconds)
            return 100, 2.0

    calls = []
    real = (talar_method.run_stage, translation.run_stage, pipeline.stage_ifp)
    clock = FakeClock()
    with (
        mock.patch.object(talar_method, "run_stage", lambda run_dir, name, *a, **k: calls.append(name)),
        mock.patch.object(translation, "run_stage", lambda run_dir, name, *a, **k: calls.append(name)),
        mock.patch.object(pipeline, "stage_ifp", lambda config, setup, env: calls.append("ifp")),
    ):
        inner = (talar_method.run_stage, translation.run_stage, pipeline.stage_ifp)
        with physics_between_stages(clock, 7.5) as windows:
            talar_method.run_stage("out", "talar/task_language", "key", None)
            translation.run_stage("out", "talar/translator", "key", None)
            pipeline.stage_ifp(None, None, None)
        assert (talar_method.run_stage, translation.run_stage, pipeline.stage_ifp) == inner
    assert (talar_method.run_stage, translation.run_stage, pipeline.stage_ifp) == real
    assert calls == ["talar/task_language", "talar/translator", "ifp"]
    assert tuple(w["before"] for w in windows) == WINDOWS
    assert clock.asked == [7.5] * 4 and all(w["sps"] == 50.0 for w in windows)
