"""FrankaKitchen env in TALAR's protocol (one sub-task per episode, or all six at once) on MJX or MuJoCo C."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from envs.base import ActionSpec, Env, EnvConfig, State, check_choice
from envs.kitchen import tasks

INTEGRATORS: tuple[str, ...] = ("euler", "implicitfast")
ALL_TASKS_REWARDS: tuple[str, ...] = ("new", "count")
START_STATES: tuple[str, ...] = ("reset", "others_done", "after_subtask")
START_ARMS: tuple[str, ...] = ("scripted", "ended", "either")
ENDED_POSTURES_FILE = Path(__file__).resolve().parent / "ended_postures.npz"
"""Arm postures in which a trained policy ended each sub-task in chains (``postures``: (sub-tasks, K, 9)), written by
``python -m experiments.ended_postures``; read by ``start_arm='ended'`` or ``'either'``."""
STILLNESS_TESTS: tuple[str, ...] = ("observed", "true")

# Clip bounds of the servo targets (the original robot config's ``pos_bound``; note joint 6's [0, 3.8]).
POS_LOW = np.array([-2.9, -1.8, -2.9, -3.1, -2.9, 0.0, -2.9, 0.0, 0.0], np.float32)
POS_HIGH = np.array([2.9, 1.8, 2.9, 0.0, 2.9, 3.8, 2.9, 0.04, 0.04], np.float32)
ACTION_SCALE = 2.0  # action in [-1, 1] -> joint velocity in [-2, 2] rad/s (m/s for the fingers)

# Simulated joints -> their index in the 30-D observation. Indicator dofs (burners 10/12/14/16, lamp 18) are
# derived from the knob / switch angles through the original couplings.
_OBS_INDEX_OF_JOINT = {
    **{f"panda0_joint{i + 1}": i for i in range(7)},
    "panda0_finger_joint1": 7,
    "panda0_finger_joint2": 8,
    "knob_Joint_1": 9,
    "knob_Joint_2": 11,
    "knob_Joint_3": 13,
    "knob_Joint_4": 15,
    "light_switch": 17,
    "slide_cabinet": 19,
    "microwave": 22,
    "kettle": 23,  # free joint: 7 entries
    "left_hinge_cabinet": 20,
    "right_hinge_cabinet": 21,
}
_BURNER_OF_KNOB = {9: 10, 11: 12, 13: 14, 15: 16}
ARM_COLLISION_PAIRS: tuple[tuple[str, str], ...] = tuple(
    (link, furniture)
    for link in ("panda0_link5", "panda0_link6", "panda0_link7", "hand")
    for furniture in ("range_hood", "stove_block", "slide_cabinet_body", "hinge_cabinet_body")
)
"""Contact pairs added by ``arm_collisions``: arm capsules x kitchen boxes. The microwave's single box reaches 3 cm in
front of its door handle (the original has six), so it would block the hand at the handle and is left out."""
KNOB_PER_BURNER = 174.0  # knob angle = 174 x burner slide, burner range [-0.009, 0]
SWITCH_PER_LAMP = 14.0  # switch angle = 14 x lamp slide, lamp range [-0.05, 0]


@dataclasses.dataclass(frozen=True)
class KitchenConfig(EnvConfig):
    """FrankaKitchen options (defaults: TALAR's protocol with the lean MJX physics settings)."""

    episode_length: int = 280
    """Steps per episode (TALAR, D4RL): 280 x 0.08 s."""
    noise_ratio: float = 0.1
    """Uniform observation noise ratio (D4RL / TALAR 0.1; 0 disables noise)."""
    timestep: float = 0.01
    """Physics timestep in seconds (original: 0.002)."""
    substeps: int = 8
    """Physics steps per env step (original: 40); timestep x substeps is the control period."""
    integrator: str = "implicitfast"
    """Integrator: 'implicitfast' (lean) or 'euler' (original)."""
    solver_iterations: int = 5
    """Newton solver iterations (original: 100)."""
    ls_iterations: int = 8
    """Solver line-search iterations (original: 50)."""
    all_tasks: bool = False
    """False: one sub-task per episode (``kitchen``). True: all six at once (``kitchen-all``)."""
    posture_targets: str = "talar"
    """Target robot postures of the single-task reward's posture term: 'talar' (TALAR's hard-coded postures, the
    original reward), 'scripted' (the scripted controller's posture at success, with the hand at the object) or
    'grasp' (as 'scripted', with the microwave's target grasping the closed door's handle, not past it).
    Measured (results/recipe-measurements/kitchen-diagnosis): with 'talar', parking the arm at the top-burner target
    never touches the knob and is worth about as much as succeeding; goal-conditioned PPO, 573k steps, 3 seeds: top
    burner 0 -> 72 %, light switch 34 -> 100 %, bottom burner 38 -> 82 % with 'scripted'. The microwave's 'scripted'
    target leaves the fingertips 0.28 m from the closed door's handle; 'grasp' with ``stillness='true'`` opened it on
    8 of 8 probe seeds against 3 of 8 (results/kitchen-seeds/). TALAR's experiment commands use 'grasp'."""
    stillness: str = "observed"
    """What the posture term's stillness test reads: 'observed' (the change of the noisy observed distance, TALAR's
    reward) or 'true' (the change of the noise-free distance). The door's observation noise (+-0.01 rad, ten times
    the test's threshold) switches the term off on about 90 % of the microwave's steps under 'observed'; with
    'true' it applies whenever the object did not move (results/kitchen-seeds/)."""
    all_tasks_reward: str = "new"
    """``kitchen-all``'s reward: 'new' (the sub-tasks completed for the first time at this step, each pays once, as
    D4RL / Gymnasium-Robotics) or 'count' (the number of sub-tasks whose test passes at this step: the paper's
    hierarchical-RL reward, Appendix D.1.3)."""
    arm_collisions: bool = False
    """Let the forearm, the wrist links and the hand collide with the range hood, the stove block and both wall
    cabinets (``ARM_COLLISION_PAIRS``; 16 primitive pairs). Off by default, as in the model TALAR's results
    were made with, where only the fingers, the hand and the kettle touch the objects they move; the cost is in
    ``benchmarks/results/kitchen_model_cost.json``."""
    hinge_cabinet_task: bool = False
    """Add D4RL's 'hinge cabinet' (open the right door to 1.45 rad) as a seventh sub-task, goal id 6: sampled at reset
    in ``kitchen``, required in ``kitchen-all``. TALAR's six stay the default (its instructions name six)."""
    start: str = "reset"
    """Where an episode starts: 'reset' (the fixed initial state: TALAR's protocol) or 'others_done' (the same, with
    each sub-task other than the episode's goal already done with probability ``start_done_probability``: its object
    at its goal values, as earlier sub-tasks of a chain leave the kitchen). The goal is drawn as under 'reset'."""
    start_done_probability: float = 0.5
    """With ``start='others_done'`` or ``'after_subtask'``: the probability that each other sub-task starts done."""
    start_arm_noise: float = 0.1
    """With ``start='after_subtask'``: each arm joint's uniform offset (rad) around the posture it starts in.
    'after_subtask' is 'others_done' with the arm where a chain leaves it: at the scripted controller's posture at
    success of one of the done sub-tasks (drawn uniformly; the reset posture when none is done), offset by this.
    Under 'others_done' the arm always starts at the reset posture, which a chain's second clause never sees."""
    start_arm: str = "scripted"
    """With ``start='after_subtask'``: which posture a done sub-task leaves the arm in. 'scripted': the scripted
    controller's at success, one point per sub-task. 'ended': one drawn from the postures in which a trained policy
    ended that sub-task in chains (``ENDED_POSTURES_FILE``): a 7-DoF arm reaches a handle in many ways, and a policy's
    own endings lie up to 1.4 rad per joint from the scripted one. 'either': each start one of the two, evenly.
    Sub-tasks the file lacks (the hinge cabinet) keep the scripted posture."""


@struct.dataclass
class KitchenTask:
    """Per-episode task data and the control law's memory."""

    goal: jax.Array  # () int32 sub-task id (index in tasks.ALL_TASK_NAMES); -1 in kitchen-all
    completed: jax.Array  # (num_goals,) float32, sub-tasks completed so far this episode
    distance: jax.Array  # (num_goals,) float32, each sub-task's distance to its goal at the last observation
    robot_qpos_obs: jax.Array  # (9,) float32, last noisy robot joint observation (q_obs_prev of the control law)
    noise_rng: jax.Array  # (2,) uint32 raw PRNG key for the observation noise


def _raw_key(rng: jax.Array) -> jax.Array:
    return jax.random.key_data(rng) if jnp.issubdtype(rng.dtype, jax.dtypes.prng_key) else rng


class KitchenEnv(Env):
    """9-DoF Franka Panda in a kitchen with six sub-tasks (TALAR, Appendix D.1.1).

    | action index | meaning (each in [-1, 1], scaled x2 to a joint velocity) |
    |---|---|
    | 0-6 | arm joints 1-7 |
    | 7, 8 | fingers (left, right) |

    The servo target is ``clip(q_obs_prev + 2 a dt, pos_bound)`` with ``q_obs_prev`` the last *noisy* robot
    observation, held for ``substeps`` physics steps (dt = timestep x substeps = 0.08 s).

    | observation index | meaning |
    |---|---|
    | 0-8 | robot joint positions (kitchen convention for joints 6, 7) |
    | 9-16 | (knob, burner indicator) pairs 1-4; indicators = knob / 174 |
    | 17, 18 | light switch angle, lamp = switch / 14 |
    | 19 | slide cabinet |
    | 20, 21 | hinge cabinet doors (left, right) |
    | 22 | microwave door |
    | 23-29 | kettle position (x, y, z) and quaternion (w, x, y, z) |

    ``kitchen``: one sub-task per episode (uniform goal id), TALAR's ``prev_curr`` reward with the posture term
    (its target postures chosen by ``posture_targets``), terminates on success. ``kitchen-all``: all six; reward =
    number of sub-tasks newly completed at this step (each pays once; ``all_tasks_reward='count'``: the number
    complete at this step), terminates when all six are complete;
    ``metrics["success"]`` = all six complete. ``hinge_cabinet_task=True`` makes the hinge cabinet a seventh.
    ``goal_observation=True`` appends a one-hot of the sub-task (``kitchen``; ``kitchen-all`` has no goal part).
    """

    config_class = KitchenConfig
    xml_path = Path(__file__).parent / "xmls" / "kitchen.xml"
    render_camera = {"lookat": (-0.4, 0.45, 1.95), "distance": 2.3, "azimuth": 112.0, "elevation": -28.0}

    def check_config(self, config: KitchenConfig) -> None:
        check_choice("integrator", config.integrator, INTEGRATORS)
        check_choice("posture_targets", config.posture_targets, tasks.POSTURE_TARGETS)
        check_choice("stillness", config.stillness, STILLNESS_TESTS)
        check_choice("all_tasks_reward", config.all_tasks_reward, ALL_TASKS_REWARDS)
        check_choice("start", config.start, START_STATES)
        check_choice("start_arm", config.start_arm, START_ARMS)
        if not 0.0 <= config.start_done_probability <= 1.0:
            raise ValueError(f"start_done_probability must lie in [0, 1], got {config.start_done_probability}")
        if config.start_arm_noise < 0:
            raise ValueError(f"start_arm_noise must be >= 0, got {config.start_arm_noise}")
        if config.timestep <= 0 or config.substeps < 1 or config.noise_ratio < 0:
            raise ValueError("timestep must be > 0, substeps >= 1 and noise_ratio >= 0")

    def __init__(self, config: KitchenConfig | None = None, physics: str | None = None):
        super().__init__(config, physics)
        m = self.mj_model
        qpos_index, obs_index = [], []
        for name, obs_at in _OBS_INDEX_OF_JOINT.items():
            joint = m.joint(name)
            width = 7 if joint.type[0] == mujoco.mjtJoint.mjJNT_FREE else 1
            qpos_index += list(range(int(joint.qposadr[0]), int(joint.qposadr[0]) + width))
            obs_index += list(range(obs_at, obs_at + width))
        if sorted(qpos_index) != list(range(m.nq)):
            raise RuntimeError("kitchen.xml joints do not match the observation map")
        self._qpos_index = np.array(qpos_index)
        self._obs_index = np.array(obs_index)
        self._knob_obs = np.array(list(_BURNER_OF_KNOB))
        self._burner_obs = np.array(list(_BURNER_OF_KNOB.values()))
        self._init_qpos = np.zeros(m.nq, np.float32)
        self._init_qpos[self._qpos_index] = tasks.INIT_OBS[self._obs_index]
        self._control_dt = float(self.config.timestep * self.config.substeps)
        self._num_tasks = len(tasks.ALL_TASK_NAMES) if self.config.hinge_cabinet_task else tasks.NUM_TASKS
        self._posture_targets = tasks.posture_targets(self.config.posture_targets, self._num_tasks)
        self._ended_postures = self._read_ended_postures()

    def load_model(self) -> mujoco.MjModel:
        if self.config.arm_collisions:
            spec = mujoco.MjSpec.from_file(str(self.xml_path))
            for geom1, geom2 in ARM_COLLISION_PAIRS:
                spec.add_pair(geomname1=geom1, geomname2=geom2)
            model = spec.compile()
        else:
            model = super().load_model()
        model.opt.timestep = self.config.timestep
        integrators = {
            "euler": mujoco.mjtIntegrator.mjINT_EULER,
            "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
        }
        model.opt.integrator = integrators[self.config.integrator]
        model.opt.iterations = self.config.solver_iterations
        model.opt.ls_iterations = self.config.ls_iterations
        return model

    # --- sizes ----------------------------------------------------------------------------------
    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec("continuous", tasks.NUM_ROBOT_JOINTS, -1.0, 1.0)

    @property
    def num_goals(self) -> int:
        """6 (TALAR's sub-tasks), or 7 with ``hinge_cabinet_task``."""
        return self._num_tasks

    @property
    def task_names(self) -> tuple[str, ...]:
        """Sub-task name per goal id."""
        return tasks.ALL_TASK_NAMES[: self._num_tasks]

    @property
    def goal_names(self) -> tuple[str, ...]:
        """The sub-task names (``task_names``): TALAR's six, and ``'hinge cabinet'`` with ``hinge_cabinet_task``."""
        return self.task_names

    @property
    def state_observation_size(self) -> int:
        return tasks.OBSERVATION_SIZE

    @property
    def agent_observation_size(self) -> int:
        return tasks.NUM_ROBOT_JOINTS  # entries 0-8: the arm's and the fingers' joints

    @property
    def goal_feature_size(self) -> int:
        """A one-hot of the sub-task; none in ``kitchen-all``."""
        return 0 if self.config.all_tasks else self._num_tasks

    def goal_features(self, task: KitchenTask) -> jax.Array:
        if self.config.all_tasks:
            return jnp.zeros((0,), jnp.float32)
        return jax.nn.one_hot(task.goal, self._num_tasks)

    @property
    def init_qpos(self) -> np.ndarray:
        """(nq,) reset joint positions of the simulated model."""
        return self._init_qpos.copy()

    @property
    def observation_map(self) -> tuple[np.ndarray, np.ndarray]:
        """(qpos indices, observation indices): ``obs[obs_indices] = qpos[qpos_indices]`` for simulated joints."""
        return self._qpos_index.copy(), self._obs_index.copy()

    # --- observation ----------------------------------------------------------------------------
    def clean_observation(self, qpos: jax.Array) -> jax.Array:
        """The noise-free 30-D observation of a (nq,) qpos (indicators derived from the knobs and the switch)."""
        obs = jnp.asarray(tasks.INIT_OBS).at[self._obs_index].set(qpos[self._qpos_index])
        burners = jnp.clip(obs[self._knob_obs] / KNOB_PER_BURNER, -0.009, 0.0)
        obs = obs.at[self._burner_obs].set(burners)
        return obs.at[18].set(jnp.clip(obs[17] / SWITCH_PER_LAMP, -0.05, 0.0))

    def _observe(self, qpos: jax.Array, rng: jax.Array) -> jax.Array:
        noise = jax.random.uniform(rng, (tasks.OBSERVATION_SIZE,), minval=-1.0, maxval=1.0)
        return self.clean_observation(qpos) + self.config.noise_ratio * tasks.NOISE_AMPLITUDE * noise

    # --- functional API -------------------------------------------------------------------------
    def reset(self, rng: jax.Array, goal: jax.Array | int | str | None = None) -> State:
        """The fixed initial state and a sub-task: uniform over the unsatisfied ones, or ``goal`` (an id or a
        sub-task name; see ``Env.reset``) when given. ``kitchen-all`` pursues every sub-task and ignores ``goal``
        once checked."""
        goal = self.goal_id(goal)
        out_of_range = self.goal_out_of_range(goal)
        rng_goal, rng_obs, noise_rng = jax.random.split(_raw_key(rng), 3)
        data = self.physics.init(self._init_qpos)
        obs = self._observe(data.qpos, rng_obs)
        distance = tasks.task_distances(obs, self._num_tasks)
        if self.config.all_tasks:
            goal = jnp.int32(-1)
        elif goal is None:
            goal = tasks.sample_goal(rng_goal, distance)
        else:
            goal = jnp.asarray(goal, jnp.int32)
        if self.config.start != "reset":
            # keys of their own, derived, so that the 'reset' start draws exactly what it always drew
            done = self.others_done(jax.random.fold_in(rng_goal, 1), goal)
            qpos = self.qpos_with_done(done)
            if self.config.start == "after_subtask":
                qpos = self.arm_after(jax.random.fold_in(rng_goal, 2), done, qpos)
            data = self.physics.init(qpos)
            obs = self._observe(data.qpos, rng_obs)
            distance = tasks.task_distances(obs, self._num_tasks)
        task = KitchenTask(
            goal=goal,
            completed=jnp.zeros(self._num_tasks, jnp.float32),
            distance=distance,
            robot_qpos_obs=obs[: tasks.NUM_ROBOT_JOINTS],
            noise_rng=_raw_key(noise_rng),
        )
        zero = jnp.zeros((), jnp.float32)
        metrics = {"success": zero, "distance": self._goal_distance(task, distance), "num_completed": zero}
        state = State(
            data=data, obs=self.observe_goal(obs, task), reward=zero, done=zero, metrics=metrics, info={}, task=task
        )
        return self.flag_out_of_range(state, out_of_range)

    def step(self, state: State, action: jax.Array) -> State:
        action = self.check_action(action)
        task: KitchenTask = state.task
        ctrl = jnp.clip(task.robot_qpos_obs + ACTION_SCALE * action * self._control_dt, POS_LOW, POS_HIGH)
        data = self.physics.step(state.data, ctrl, self.config.substeps)
        noise_rng, rng_obs = jax.random.split(task.noise_rng)
        obs = self._observe(data.qpos, rng_obs)
        distance = tasks.task_distances(obs, self._num_tasks)
        if self.config.all_tasks:
            completed, reward = tasks.all_tasks_update(task.completed, distance)
            if self.config.all_tasks_reward == "count":
                reward = jnp.sum(distance < tasks.BONUS_THRESH).astype(jnp.float32)
            success = jnp.all(completed > 0.5).astype(jnp.float32)
        else:
            terms = tasks.single_task_reward(
                task.distance[task.goal],
                distance[task.goal],
                obs[: tasks.NUM_ROBOT_JOINTS],
                task.goal,
                self._posture_targets,
                self._true_progress(state.data.qpos, data.qpos, task.goal),
            )
            reward = sum(terms.values())
            success = terms["success"]
            completed = task.completed.at[task.goal].max(success)
        new_task = task.replace(
            completed=completed,
            distance=distance,
            robot_qpos_obs=obs[: tasks.NUM_ROBOT_JOINTS],
            noise_rng=noise_rng,
        )
        metrics = {
            "success": success,
            "distance": self._goal_distance(new_task, distance),
            "num_completed": jnp.sum(completed),
        }
        return state.replace(
            data=data,
            obs=self.observe_goal(obs, new_task),
            reward=jnp.asarray(reward, jnp.float32),
            done=success,
            metrics=metrics,
            task=new_task,
        )

    def others_done(self, rng: jax.Array, goal: jax.Array) -> jax.Array:
        """(num_goals,) bool: the sub-tasks other than ``goal`` that start done (``start='others_done'``), each with
        probability ``start_done_probability`` (``goal`` -1, ``kitchen-all``: any sub-task)."""
        others = jnp.arange(self._num_tasks) != goal
        return jax.random.bernoulli(rng, self.config.start_done_probability, (self._num_tasks,)) & others

    def qpos_with_done(self, done: jax.Array) -> jax.Array:
        """(nq,) the reset joint positions with the objects of the ``done`` sub-tasks at their goal values."""
        mask = jnp.asarray(tasks.TASK_MASK[: self._num_tasks])
        at_goal = (done.astype(jnp.float32) @ mask) > 0.5  # (30,) observation entries of the done sub-tasks
        goal_obs = jnp.asarray(tasks.TASK_GOAL[: self._num_tasks]).sum(0)  # the sub-tasks' entries do not overlap
        obs = jnp.where(at_goal, goal_obs, jnp.asarray(tasks.INIT_OBS))
        return jnp.asarray(self._init_qpos).at[self._qpos_index].set(obs[self._obs_index])

    def _read_ended_postures(self) -> np.ndarray | None:
        """(num_goals, K, 9) the recorded endings ``arm_after`` draws from (``ENDED_POSTURES_FILE``), the scripted
        posture standing in for the sub-tasks the file lacks; None under ``start_arm='scripted'``, which reads none."""
        if self.config.start_arm == "scripted":
            return None
        if not ENDED_POSTURES_FILE.is_file():
            raise FileNotFoundError(f"start_arm={self.config.start_arm!r} reads {ENDED_POSTURES_FILE}: missing")
        with np.load(ENDED_POSTURES_FILE) as recorded:
            ended = np.asarray(recorded["postures"], np.float32)[: self._num_tasks]
        scripted = tasks.posture_targets("scripted", self._num_tasks)[len(ended) :, None]
        return np.concatenate([ended, np.repeat(scripted, ended.shape[1], axis=1)])

    def arm_after(self, rng: jax.Array, done: jax.Array, qpos: jax.Array) -> jax.Array:
        """``qpos`` with the arm at a posture in which one of the ``done`` sub-tasks (uniformly) leaves it, kept when
        none is done, each arm joint offset uniformly by up to ``start_arm_noise`` (``start='after_subtask'``). The
        posture is the scripted controller's at success or a recorded ending, as ``start_arm`` says. The fingers keep
        the posture's opening: an offset there would open or shut the hand for no reason."""
        rng_task, rng_noise = jax.random.split(rng)
        last = jax.random.categorical(rng_task, jnp.where(done, 0.0, -jnp.inf))
        posture = jnp.asarray(tasks.posture_targets("scripted", self._num_tasks))[last]
        if self.config.start_arm != "scripted":
            # keys of their own, so that 'scripted' draws exactly what it always drew
            rng_pick, rng_which = jax.random.split(jax.random.fold_in(rng, 3))
            endings = jnp.asarray(self._ended_postures)[last]  # (K, 9)
            ended = endings[jax.random.randint(rng_pick, (), 0, endings.shape[0])]
            use_ended = jnp.bool_(True) if self.config.start_arm == "ended" else jax.random.bernoulli(rng_which)
            posture = jnp.where(use_ended, ended, posture)
        arm = jnp.where(jnp.any(done), posture, qpos[: tasks.NUM_ROBOT_JOINTS])
        noise = self.config.start_arm_noise * jax.random.uniform(rng_noise, (7,), minval=-1.0, maxval=1.0)
        arm = jnp.clip(arm.at[:7].add(noise), POS_LOW, POS_HIGH)
        return qpos.at[: tasks.NUM_ROBOT_JOINTS].set(arm)

    def retarget(self, state: State, goal: jax.Array | int | str) -> State:
        """``state`` pursuing sub-task ``goal`` from now on (see ``Env.retarget``): the goal id and the goal part of
        the observation change; the physics, the last noisy observation, each sub-task's distance and the sub-tasks
        completed so far are kept, so the next step's reward measures progress on the new goal from where it stands.
        From a reset state it gives what ``reset`` with that goal gives. ``kitchen-all`` has no goal to change."""
        if self.config.all_tasks:
            raise NotImplementedError("kitchen-all pursues every sub-task at once: it has no goal to retarget")
        goal = self.goal_id(goal)
        if goal is None:
            raise ValueError("retarget needs a goal (an id or a sub-task name)")
        out_of_range = self.goal_out_of_range(goal)
        task = state.task.replace(goal=jnp.asarray(goal, jnp.int32))
        zero = jnp.zeros((), jnp.float32)
        metrics = {
            "success": zero,
            "distance": self._goal_distance(task, task.distance),
            "num_completed": jnp.sum(task.completed),
        }
        obs = self.observe_goal(state.obs[: tasks.OBSERVATION_SIZE], task)
        retargeted = state.replace(obs=obs, reward=zero, done=zero, metrics=metrics, task=task)
        return self.flag_out_of_range(retargeted, out_of_range)

    def _true_progress(self, qpos_before: jax.Array, qpos_after: jax.Array, goal: jax.Array) -> jax.Array | None:
        """The goal's noise-free progress over a step when ``stillness='true'``, else None (the observed one)."""
        if self.config.stillness == "observed":
            return None
        before = tasks.task_distances(self.clean_observation(qpos_before), self._num_tasks)[goal]
        return before - tasks.task_distances(self.clean_observation(qpos_after), self._num_tasks)[goal]

    def _goal_distance(self, task: KitchenTask, distance: jax.Array) -> jax.Array:
        """The goal's distance (kitchen) or the summed distance of the sub-tasks not yet completed (kitchen-all)."""
        if self.config.all_tasks:
            return jnp.sum(jnp.where(task.completed > 0.5, 0.0, distance))
        return distance[task.goal]
