"""Goal-given PPO probe on the kitchen (one-hot goal, the IFP's PPO settings): the microwave alone (--goal 0) or all
six sub-tasks (--goal -1), with the reward variants of the README (--mw-target grasp, --still clean).

From the repository root: PYTHONPATH=. python results/kitchen-seeds/probes/mw.py --name base --steps 700000 --seeds 4
[--goal -1] [--mw-target grasp] [--still clean] [--normalize-obs] [--num-envs N] [--rollout L] [--ent C] [--log-std X]
Writes runs/kitchen-seeds/<name>/ (metrics.jsonl, checkpoints).
"""
import argparse, dataclasses, json, os, time
from pathlib import Path
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")
import jax, jax.numpy as jnp, numpy as np
import envs
from envs.kitchen import tasks
from envs.kitchen.env import KitchenEnv, KitchenConfig
from talar_jax.conditioning import GoalOneHotConditioner
from talar_jax.ppo import PPOConfig, run_ppo, make_train
from experiments.recipes import get_recipe

p = argparse.ArgumentParser()
p.add_argument("--name", required=True)
p.add_argument("--goal", type=int, default=0)
p.add_argument("--mw-target", default="success", choices=["success", "grasp"])
p.add_argument("--still", default="noisy", choices=["noisy", "clean"])
p.add_argument("--normalize-obs", action="store_true")
p.add_argument("--num-envs", type=int, default=64)
p.add_argument("--rollout", type=int, default=64)
p.add_argument("--minibatch", type=int, default=128)
p.add_argument("--epochs", type=int, default=10)
p.add_argument("--ent", type=float, default=0.0)
p.add_argument("--log-std", type=float, default=None)
p.add_argument("--seeds", type=int, default=4)
p.add_argument("--seed", type=int, default=0)
p.add_argument("--steps", type=int, default=600_000)
p.add_argument("--updates-per-chunk", type=int, default=10)
p.add_argument("--eval-every", type=int, default=1)
p.add_argument("--eval-episodes", type=int, default=32)
a = p.parse_args()


class FixedGoalKitchen(KitchenEnv):
    """Always the same sub-task; optionally the posture term's stillness test on the noise-free distance."""

    def __init__(self, config, physics, goal, still):
        super().__init__(config, physics)
        self.fixed_goal, self.still = goal, still
        if a.mw_target == "grasp":  # fingers behind the closed door's handle (scripted controller, noise-free, step 100)
            targets = np.array(self._posture_targets)
            targets[0] = GRASP
            self._posture_targets = targets

    def reset(self, rng, goal=None):
        return super().reset(rng, goal=None if self.fixed_goal < 0 else self.fixed_goal)

    def step(self, state, action):
        new = super().step(state, action)
        if self.still == "noisy":
            return new
        g = state.task.goal
        clean_prev = tasks.task_distances(self.clean_observation(state.data.qpos), self.num_goals)[g]
        clean_now = tasks.task_distances(self.clean_observation(new.data.qpos), self.num_goals)[g]
        terms = tasks.single_task_reward(state.task.distance[g], new.task.distance[g], new.obs[:9], g,
                                         self._posture_targets)
        posture_dist = jnp.linalg.norm(new.obs[:9] - jnp.asarray(self._posture_targets)[g])
        still = jnp.abs(clean_prev - clean_now) <= tasks.STILL_THRESH
        posture = jnp.where(still, -tasks.POSTURE_SCALE * posture_dist, 0.0)
        reward = terms["progress"] + terms["success"] + posture
        return new.replace(reward=jnp.asarray(reward, jnp.float32))


GRASP = np.array([-2.1448, -1.4059, 2.85, -0.4638, 0.2893, 0.2808, 2.3598, 0.04, 0.04], np.float32)
recipe = get_recipe("kitchen")
config = dataclasses.replace(KitchenConfig(), **recipe.env_options)
env = FixedGoalKitchen(config, "c", a.goal, a.still)
ppo = dataclasses.replace(
    recipe.ifp, num_seeds=a.seeds, seed=a.seed, total_env_steps=a.steps, num_envs=a.num_envs, rollout_length=a.rollout,
    minibatch_size=a.minibatch, num_epochs=a.epochs, ent_coef=a.ent, normalize_observations=a.normalize_obs,
    eval_every_chunks=a.eval_every, eval_episodes=a.eval_episodes, updates_per_chunk=a.updates_per_chunk,
)
cond = GoalOneHotConditioner(env.num_goals)
initial = None
if a.log_std is not None:
    trainer = make_train(ppo, env, cond)
    keys = jax.random.split(jax.random.PRNGKey(ppo.seed), ppo.num_seeds)
    params = jax.jit(jax.vmap(trainer.init))(keys).params
    pol = jax.tree.map(lambda x: x, params["policy"])
    pol["params"]["log_std"] = jnp.full_like(pol["params"]["log_std"], a.log_std)
    initial = {"policy": pol}
out = Path("runs/kitchen-seeds") / a.name
out.mkdir(parents=True, exist_ok=True)
(out / "args.json").write_text(json.dumps(vars(a)))
t0 = time.time()
res = run_ppo(ppo, env, cond, out, eval_splits=("train",), progress=False, initial_params=initial)
print("done", time.time() - t0, res.final_eval["train"]["success_per_seed"])
