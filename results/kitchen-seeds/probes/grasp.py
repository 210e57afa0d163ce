"""The microwave's grasp posture: the scripted controller's noise-free episode, fingertip-handle distance and the
posture at each step until the door first moves (step 100 = fingers behind the closed door's handle)."""
import numpy as np, jax, jax.numpy as jnp, mujoco
import envs
from envs.kitchen import tasks
from envs.kitchen.scripted import scripted_action
env = envs.make("kitchen", physics="c", posture_targets="scripted", noise_ratio=0.0)
state = env.reset(jax.random.PRNGKey(0), goal=0)
step = jax.jit(env.step); act = jax.jit(scripted_action)
m = env.mj_model; d = mujoco.MjData(m); qi, oi = env.observation_map
def fingers(obs):
    d.qpos[:] = env.init_qpos; d.qpos[qi] = np.asarray(obs)[oi]; mujoco.mj_forward(m, d)
    return (d.geom('left_finger').xpos + d.geom('right_finger').xpos) / 2, d.geom('micro_handle').xpos.copy()
rows = []
for t in range(200):
    obs = np.asarray(state.obs[:30])
    f, h = fingers(obs)
    rows.append((t, obs[22], np.linalg.norm(f - h), obs[:9].copy()))
    state = step(state, act(state.obs, jnp.int32(0), jnp.int32(t)))
    if state.done > 0.5: print('success at', t + 1); break
first = next(r for r in rows if r[1] < -0.01)
print('door first moves at step', first[0], 'finger-handle', round(first[2], 3))
for t in (60, 80, 90, 100, first[0] - 1, first[0]):
    r = rows[t]; print(t, 'door', round(float(r[1]), 3), 'finger-handle', round(float(r[2]), 3), 'q', np.round(r[3], 4).tolist())
