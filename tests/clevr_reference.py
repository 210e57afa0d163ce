"""Host-side (numpy + MuJoCo C) push simulator for both CLEVR models: the original-env reference and calibration."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from envs.clevr import tasks
from envs.clevr.env import ORIGINAL_XML


class PushSimulator:
    """One CLEVR scene in C MuJoCo, stepped like the original env: teleport the pusher, push for ``substeps``.

    Works for the original free-ball model (qpos: 5 x 7 free-joint entries, then pusher x, y) and for the lean
    model (qpos: 5 x (x, y), then pusher x, y). Ball velocities carry over between pushes, as in the original.
    """

    def __init__(
        self, xml_path: Path | str = ORIGINAL_XML, substeps: int | None = None, model: mujoco.MjModel | None = None
    ):
        self.model = model if model is not None else mujoco.MjModel.from_xml_path(str(xml_path))
        self.data = mujoco.MjData(self.model)
        self.free_balls = self.model.nq == 7 * tasks.NUM_BALLS + 2
        self.ball_stride = 7 if self.free_balls else 2
        self.pusher_adr = self.ball_stride * tasks.NUM_BALLS
        # the original simulates 40 x 0.01 s per action; a lean model with a larger timestep keeps 0.4 s
        self.substeps = substeps if substeps is not None else round(0.4 / self.model.opt.timestep)

    def set_balls(self, ball_xy: np.ndarray) -> None:
        """Places the balls at ``ball_xy`` (5, 2) at rest, pusher at the origin."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        for i, (x, y) in enumerate(np.asarray(ball_xy, np.float64).reshape(tasks.NUM_BALLS, 2)):
            at = i * self.ball_stride
            d.qpos[at : at + 2] = x, y
            if self.free_balls:
                d.qpos[at + 2 : at + 7] = -0.195, 1.0, 0.0, 0.0, 0.0
        mujoco.mj_forward(m, d)

    def ball_xy(self) -> np.ndarray:
        """(5, 2) ball centre positions."""
        at = np.arange(tasks.NUM_BALLS) * self.ball_stride
        return np.stack([self.data.qpos[at], self.data.qpos[at + 1]], axis=1).copy()

    def push(self, action: int) -> np.ndarray:
        """Teleports the pusher 0.15 d behind ball ``action // 8`` and pushes with force d; returns ball_xy."""
        m, d = self.model, self.data
        ball, direction = divmod(int(action), tasks.NUM_DIRECTIONS)
        force = tasks.PUSH_DIRECTIONS[direction].astype(np.float64)
        d.qpos[self.pusher_adr : self.pusher_adr + 2] = self.ball_xy()[ball] - tasks.PUSH_OFFSET * force
        d.qvel[-2:] = 0.0
        mujoco.mj_forward(m, d)
        d.ctrl[:] = force
        for _ in range(self.substeps):
            mujoco.mj_step(m, d)
        return self.ball_xy()
