"""Roll out a microwave-only probe run's policies (each seed): where the fingertips go, whether the door moves."""
import dataclasses, json, sys, os
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")
import numpy as np, jax, jax.numpy as jnp, mujoco
from pathlib import Path
from envs.kitchen import tasks
from envs.kitchen.env import KitchenEnv, KitchenConfig
from talar_jax.conditioning import GoalOneHotConditioner
from talar_jax.ppo import PPOConfig, make_train, initial_state, RunFiles
from experiments.recipes import get_recipe

run = Path(sys.argv[1]); E = 16
cfg = PPOConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in json.loads((run / 'config.json').read_text()).items()})
env = KitchenEnv(dataclasses.replace(KitchenConfig(), **get_recipe('kitchen').env_options), 'c')
cond = GoalOneHotConditioner(env.num_goals)
trainer = make_train(cfg, env, cond)
state = initial_state(trainer, cfg)
rf = RunFiles(run, cfg); state, _ = rf.restore(state, {"chunks": 0, "wall_s": 0.0, "target_reached": None}); rf.close()
params = state.params
m = env.mj_model; d = mujoco.MjData(m)

def episodes(p, rng, deterministic):
    policy = trainer.make_policy(p, deterministic)
    def one(key):
        k0, k1 = jax.random.split(key)
        s = env.reset(k0, goal=0)
        def body(s, k):
            a = policy(s.obs[None], jax.nn.one_hot(jnp.array([0]), env.num_goals), k)[0]
            n = env.step(s, a)
            n = jax.tree.map(lambda x, y: jnp.where(s.done > 0.5, y, x), n, s)  # freeze after success
            return n, (s.data.qpos, s.reward, s.done)
        _, out = jax.lax.scan(body, s, jax.random.split(k1, 280))
        return out
    return jax.vmap(one)(jax.random.split(rng, E))

fn = jax.jit(episodes, static_argnums=2)
S = cfg.num_seeds
for s in range(S):
    p = jax.tree.map(lambda x: x[s], params)
    std = float(np.exp(np.asarray(p['policy']['params']['log_std'])).mean())
    for det in (False, True):
        qpos, rew, done = jax.device_get(fn(p, jax.random.PRNGKey(7), det))
        fh = np.zeros(qpos.shape[:2]); qd = np.zeros(qpos.shape[:2])
        door = qpos[..., m.joint('microwave').qposadr[0]]
        for e in range(E):
            for t in range(280):
                d.qpos[:] = qpos[e, t]; mujoco.mj_kinematics(m, d)
                f = (d.geom('left_finger').xpos + d.geom('right_finger').xpos) / 2
                fh[e, t] = np.linalg.norm(f - d.geom('micro_handle').xpos)
                qd[e, t] = np.linalg.norm(qpos[e, t, :9] - tasks.SCRIPTED_POSTURE[0])  # note: sim joint order = obs for arm
        succ = (done.max(1) > 0.5).mean()
        print(f"seed {s} {'mode' if det else 'sample'} std {std:.3f}: success {succ:.2f}, min finger-handle {fh.min(1).mean():.3f} m "
              f"(t=50: {fh[:, 50].mean():.3f}, t=279: {fh[:, -1].mean():.3f}), |q-q*| t=279 {qd[:, -1].mean():.2f}, "
              f"min door angle {door.min(1).mean():+.3f}, return {rew.sum(1).mean():+.2f}")
