"""Two physics engines behind one functional API: pure-JAX MJX and MuJoCo's C engine via a callback.

An env's ``physics`` is one of ``PHYSICS_NAMES`` (``envs.make(name, physics="c")``); ``env.physics`` is the ``Physics``
object of that name. ("Backend" is left to JAX, whose ``jax.default_backend()`` names the device kind.)

Both engines step the *same* compiled ``mujoco.MjModel`` and exchange the same small, engine-independent
``PhysicsState`` pytree, so task logic (rewards, observations, resets) is shared JAX code and only the
physics step differs:

* ``MjxPhysics``: ``mujoco.mjx`` with ``impl="jax"``. Pure JAX, so it runs on CPU/GPU/TPU, is jit-, vmap- and
  grad-able. On a CPU it needs ``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false``, which building it sets while JAX
  has not started yet and otherwise warns about (``envs.runtime``).
* ``CPhysics``: MuJoCo's C engine, reached through ``jax.pure_callback`` with a batched host function that
  runs ``mujoco.rollout`` (multi-threaded). The env stays jit- and vmap-able (vmap turns into one batched
  host call), but not differentiable. On a CPU this is the fast physics.
"""

from __future__ import annotations

import abc
import contextlib
import io
import os
import threading
import warnings

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import rollout as mj_rollout

from envs.runtime import prepare_mjx

# mujoco.mjx prints "Failed to import warp / mujoco_warp" when the optional Warp backend is absent; only its
# pure-JAX implementation is used here, so that notice is noise for every user.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx

PHYSICS_NAMES: tuple[str, ...] = ("mjx", "c")
"""The values of ``physics`` (``envs.make``, ``Env(config, physics)``) and the ``name`` of each ``Physics`` class."""


@struct.dataclass
class PhysicsState:
    """The part of the MuJoCo state that persists between env steps (identical for both physics).

    Everything else in ``mjData`` (kinematics, contacts, constraint forces) is recomputed from these
    fields at the next physics step, so nothing is lost by not carrying it.
    """

    qpos: jax.Array  # (nq,)
    qvel: jax.Array  # (nv,)
    time: jax.Array  # ()


class Physics(abc.ABC):
    """Steps a fixed ``mujoco.MjModel`` for ``nsubsteps`` substeps holding a constant control."""

    name: str

    def __init__(self, mj_model: mujoco.MjModel):
        self.mj_model = mj_model

    def init(self, qpos: jax.Array, qvel: jax.Array | None = None) -> PhysicsState:
        """Returns a physics state at ``qpos`` (and ``qvel``, zero by default), time 0."""
        qpos = jnp.asarray(qpos, jnp.float32)
        if qpos.shape[-1] != self.mj_model.nq:
            raise ValueError(f"qpos has {qpos.shape[-1]} entries, the model has nq={self.mj_model.nq}")
        if qvel is None:
            qvel = jnp.zeros(qpos.shape[:-1] + (self.mj_model.nv,), jnp.float32)
        qvel = jnp.asarray(qvel, jnp.float32)
        return PhysicsState(qpos=qpos, qvel=qvel, time=jnp.zeros(qpos.shape[:-1], jnp.float32))

    @abc.abstractmethod
    def step(self, state: PhysicsState, ctrl: jax.Array, nsubsteps: int) -> PhysicsState:
        """Advances ``nsubsteps`` physics steps with ``ctrl`` (nu,) held constant (zero-order hold)."""


class MjxPhysics(Physics):
    """Pure-JAX physics (``mujoco.mjx``, ``impl='jax'``)."""

    name = "mjx"

    def __init__(self, mj_model: mujoco.MjModel):
        # Before put_model, whose arrays are JAX's first computation in a fresh process: the flag still takes then.
        prepare_mjx()
        super().__init__(mj_model)
        self.mjx_model = mjx.put_model(mj_model, impl="jax")

    def full_data(self, state: PhysicsState, ctrl: jax.Array | None = None) -> mjx.Data:
        """An ``mjx.Data`` holding ``state`` (positions, velocities, control); kinematics not yet computed."""
        data = mjx.make_data(self.mjx_model, impl="jax")
        data = data.replace(qpos=state.qpos, qvel=state.qvel, time=state.time)
        if ctrl is not None:
            data = data.replace(ctrl=ctrl)
        return data

    def forward(self, state: PhysicsState) -> mjx.Data:
        """Runs MuJoCo's forward pass (kinematics, contacts, ...) and returns the full ``mjx.Data``."""
        return mjx.forward(self.mjx_model, self.full_data(state))

    def step(self, state: PhysicsState, ctrl: jax.Array, nsubsteps: int) -> PhysicsState:
        data = self.full_data(state, jnp.asarray(ctrl, jnp.float32))

        def substep(data: mjx.Data, _) -> tuple[mjx.Data, None]:
            return mjx.step(self.mjx_model, data), None

        data, _ = jax.lax.scan(substep, data, None, length=nsubsteps)
        return PhysicsState(qpos=data.qpos, qvel=data.qvel, time=data.time)


class CPhysics(Physics):
    """MuJoCo's C engine through one batched ``jax.pure_callback`` per env step.

    Under ``jax.vmap`` (any nesting) the callback receives the whole batch at once and runs it with
    ``mujoco.rollout`` over ``nthread`` threads. Results do not depend on the batch size or thread count.
    """

    name = "c"

    def __init__(self, mj_model: mujoco.MjModel, nthread: int | None = None):
        super().__init__(mj_model)
        self.nthread = max(1, nthread if nthread is not None else (os.cpu_count() or 1))
        # One MjData cache per physics object, guarded by a lock. Not ``threading.local``: XLA runs callbacks on
        # foreign threads whose Python thread state (and its locals, hence MjData) is torn down after each
        # callback, which segfaulted (seen with the kitchen model).
        self._lock = threading.Lock()
        self._cached_datas: list[mujoco.MjData] = []
        m = mj_model
        full = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self._state_size = mujoco.mj_stateSize(m, full)
        sizes = [
            mujoco.mj_stateSize(m, spec)
            for spec in (mujoco.mjtState.mjSTATE_TIME, mujoco.mjtState.mjSTATE_QPOS, mujoco.mjtState.mjSTATE_QVEL)
        ]
        self._time_at, self._qpos_at, self._qvel_at = np.cumsum([0] + sizes[:-1])
        # The full-physics state of the model's default data: act, mocap and plugin state stay at defaults.
        template = mujoco.MjData(m)
        self._template_state = np.empty(self._state_size)
        mujoco.mj_getState(m, template, self._template_state, full)

    def _datas(self, count: int) -> list[mujoco.MjData]:
        while len(self._cached_datas) < count:
            self._cached_datas.append(mujoco.MjData(self.mj_model))
        return self._cached_datas[:count]

    def host_step(self, qpos: np.ndarray, qvel: np.ndarray, time: np.ndarray, ctrl: np.ndarray, nsubsteps: int):
        """Numpy batched step: arrays with any leading batch shape, returns (qpos, qvel, time) in float32."""
        m = self.mj_model
        batch_shape = qpos.shape[:-1]
        n = int(np.prod(batch_shape, dtype=np.int64))
        state0 = np.tile(self._template_state, (n, 1))
        state0[:, self._time_at] = time.reshape(n)
        state0[:, self._qpos_at : self._qpos_at + m.nq] = qpos.reshape(n, m.nq)
        state0[:, self._qvel_at : self._qvel_at + m.nv] = qvel.reshape(n, m.nv)
        control = np.broadcast_to(ctrl.reshape(n, 1, m.nu).astype(np.float64), (n, nsubsteps, m.nu))
        nthread = min(self.nthread, n)
        if n == 1:  # unbatched: a direct mj_step loop, bit-identical to rollout and without its ~70 us set-up
            return self._host_step_single(state0[0], control[0, 0], nsubsteps, batch_shape)
        with self._lock:
            datas = self._datas(nthread)
            states, _ = mj_rollout.rollout(
                [m] * n if nthread > 1 else m,
                datas if nthread > 1 else datas[0],
                state0,
                np.ascontiguousarray(control),
                nstep=nsubsteps,
            )
        last = states[:, -1]
        out_qpos = last[:, self._qpos_at : self._qpos_at + m.nq].reshape(batch_shape + (m.nq,))
        out_qvel = last[:, self._qvel_at : self._qvel_at + m.nv].reshape(batch_shape + (m.nv,))
        out_time = last[:, self._time_at].reshape(batch_shape)
        return out_qpos.astype(np.float32), out_qvel.astype(np.float32), out_time.astype(np.float32)

    def _host_step_single(self, state0: np.ndarray, ctrl: np.ndarray, nsubsteps: int, batch_shape: tuple):
        """One env: set the full state (zero warm start, as rollout does) and call ``mj_step`` ``nsubsteps`` times."""
        m, full = self.mj_model, mujoco.mjtState.mjSTATE_FULLPHYSICS
        with self._lock:
            data = self._datas(1)[0]
            mujoco.mj_setState(m, data, state0, full)
            data.qacc_warmstart[:] = 0.0
            data.ctrl[:] = ctrl
            for _ in range(nsubsteps):
                mujoco.mj_step(m, data)
            qpos, qvel, time = data.qpos.copy(), data.qvel.copy(), data.time
        return (
            qpos.reshape(batch_shape + (m.nq,)).astype(np.float32),
            qvel.reshape(batch_shape + (m.nv,)).astype(np.float32),
            np.full(batch_shape, time, np.float32),
        )

    def step(self, state: PhysicsState, ctrl: jax.Array, nsubsteps: int) -> PhysicsState:
        ctrl = jnp.asarray(ctrl, jnp.float32)
        shapes = (
            jax.ShapeDtypeStruct(state.qpos.shape, jnp.float32),
            jax.ShapeDtypeStruct(state.qvel.shape, jnp.float32),
            jax.ShapeDtypeStruct(state.time.shape, jnp.float32),
        )

        def callback(qpos, qvel, time, ctrl):
            return self.host_step(np.asarray(qpos), np.asarray(qvel), np.asarray(time), np.asarray(ctrl), nsubsteps)

        qpos, qvel, time = jax.pure_callback(
            callback, shapes, state.qpos, state.qvel, state.time, ctrl, vmap_method="broadcast_all"
        )
        return PhysicsState(qpos=qpos, qvel=qvel, time=time)


def make_physics(name: str, mj_model: mujoco.MjModel) -> Physics:
    """Builds the named physics (``"mjx"`` or ``"c"``, see ``PHYSICS_NAMES``) for ``mj_model``."""
    if name == "mjx":
        return MjxPhysics(mj_model)
    if name == "c":
        return CPhysics(mj_model)
    raise ValueError(f"unknown physics {name!r}; choose one of {', '.join(PHYSICS_NAMES)}")


def default_physics() -> str:
    """The faster physics for the current default JAX device: MJX on GPU/TPU, MuJoCo C on CPU. The one rule behind
    every default choice of physics (``envs.make``, the Gymnasium adapters, the experiment commands); asking it
    starts JAX's backends."""
    return "c" if jax.default_backend() == "cpu" else "mjx"


_RENAMED = {"PHYSICS_BACKENDS": "PHYSICS_NAMES", "default_backend": "default_physics"}


def __getattr__(name: str):
    """The names these had before "physics" became the one word for the choice of engine, with a warning."""
    if name in _RENAMED:
        warnings.warn(f"envs.physics.{name} is deprecated; use {_RENAMED[name]}", DeprecationWarning, stacklevel=2)
        return globals()[_RENAMED[name]]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
