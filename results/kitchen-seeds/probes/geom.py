"""Where the hand is at each posture target, relative to the closed microwave's handle."""
import numpy as np, mujoco
import envs
from envs.kitchen import tasks
env = envs.make("kitchen", physics="c", posture_targets="scripted")
m = env.mj_model; d = mujoco.MjData(m)
qi, oi = env.observation_map
def place(q9, door=0.0):
    obs = tasks.INIT_OBS.copy(); obs[:9] = q9; obs[22] = door
    d.qpos[:] = env.init_qpos; d.qpos[qi] = obs[oi]; mujoco.mj_forward(m, d)
    ee = d.site('end_effector').xpos.copy()
    lf = d.geom('left_finger').xpos.copy(); rf = d.geom('right_finger').xpos.copy()
    h = d.geom('micro_handle').xpos.copy()
    return ee, (lf + rf) / 2, h
for name, Q in (("scripted", tasks.SCRIPTED_POSTURE), ("talar", tasks.TARGET_POSTURE)):
    ee, f, h = place(Q[0])
    print(f"{name} microwave q*: end effector {np.round(ee,3)}, fingertips {np.round(f,3)}, closed-door handle {np.round(h,3)}, "
          f"|fingers-handle| {np.linalg.norm(f-h):.3f} m")
ee, f, h = place(tasks.INIT_OBS[:9])
print(f"reset posture: end effector {np.round(ee,3)} fingertips {np.round(f,3)} |fingers-handle| {np.linalg.norm(f-h):.3f}")
# handle position when the door is at the success threshold angle
for ang in (-0.45, -0.3):
    _, _, h2 = place(tasks.SCRIPTED_POSTURE[0], ang)
    print(f"handle at door {ang}: {np.round(h2,3)}; scripted q* fingertips to it {np.linalg.norm(f - h2) if False else np.linalg.norm(place(tasks.SCRIPTED_POSTURE[0], ang)[1]-h2):.3f}")
