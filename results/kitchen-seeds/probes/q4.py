"""Microwave episodes of a finished kitchen run's seeds: fingertip-handle distance, door angle, posture, std."""
import os, sys
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")
import numpy as np, jax, mujoco
from talar_jax.agent import load
from envs.kitchen import tasks

run = sys.argv[1]; seeds = [int(s) for s in sys.argv[2].split(',')]; E = int(sys.argv[3]) if len(sys.argv) > 3 else 12
for S in seeds:
    agent = load(run, seed=S, physics="c")
    env = agent.env; m = env.mj_model; d = mujoco.MjData(m)
    rows = np.flatnonzero((agent.cache.goal_ids == 0) & agent.cache.is_train)
    sentences = [agent.cache.sentences[i] for i in rows[:: max(1, len(rows) // 4)][:4]]
    log_std = np.asarray(agent._policy_params['policy']['params']['log_std'])
    door_adr = m.joint('microwave').qposadr[0]
    for det in (False, True):
        fh_min, fh_end, door_min, succ, qd_end, lens = [], [], [], [], [], []
        fh_curve = np.zeros(281)
        for e in range(E):
            ep = agent.rollout(sentences[e % len(sentences)], jax.random.PRNGKey(100 + e), goal=0, deterministic=det)
            L = ep.length
            fh = []
            for t in range(L + 1):
                d.qpos[:] = ep.qpos[t]; mujoco.mj_kinematics(m, d)
                f = (d.geom('left_finger').xpos + d.geom('right_finger').xpos) / 2
                fh.append(np.linalg.norm(f - d.geom('micro_handle').xpos))
            fh = np.array(fh)
            fh_curve += np.concatenate([fh, np.full(281 - len(fh), fh[-1])])
            fh_min.append(fh.min()); fh_end.append(fh[-1]); door_min.append(ep.qpos[:L + 1, door_adr].min())
            qd_end.append(np.linalg.norm(ep.observations[L - 1, :9] - tasks.SCRIPTED_POSTURE[0])); succ.append(ep.success); lens.append(L)
        fh_curve /= E
        print(f"seed {S} {'mode' if det else 'sample'}: action std {np.exp(log_std).round(2).tolist()} (mean {np.exp(log_std).mean():.3f}); "
              f"success {np.mean(succ):.2f}; length {np.mean(lens):.0f}; fingertips-handle min {np.mean(fh_min):.3f} m, end {np.mean(fh_end):.3f} m; "
              f"curve t=0,25,50,100,200,280: {[round(float(fh_curve[t]),3) for t in (0,25,50,100,200,280)]}; "
              f"door min angle {np.mean(door_min):+.3f} rad; |q_end - scripted q*| {np.mean(qd_end):.2f}", flush=True)
