"""CLEVR-Robot env (``clevr``: 80 push goals; ``clevr-arrangement``: Appendix D.1.3) on MJX or MuJoCo C."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
from flax import struct

from envs.base import ActionSpec, Env, EnvConfig, State, check_choice
from envs.clevr import tasks
from envs.physics import PhysicsState

ORIGINAL_XML = Path(__file__).parent / "xmls" / "clevr_original.xml"
"""The original env's free-ball model (google-research/clevr_robot_env), which the lean ``clevr.xml`` is calibrated
against: the reference of the tests and of the original-style benchmark, never stepped by ``ClevrEnv``."""

TASK_KINDS: tuple[str, ...] = ("goal", "arrangement")
ACTION_TYPES: tuple[str, ...] = ("discrete", "collect")
START_STATES: tuple[str, ...] = ("reset", "after_goal")
AFTER_GOAL_DISTANCE = 0.3
"""``start='after_goal'``: the centre distance at which the other goal's source ball is set beside its reference ball
(more than two radii, 0.26, so the balls do not overlap; less than the success distance, 0.39)."""
_PUSHER_QPOS = slice(2 * tasks.NUM_BALLS, 2 * tasks.NUM_BALLS + 2)  # pusher x, y in the lean model's qpos


@dataclasses.dataclass(frozen=True)
class ClevrConfig(EnvConfig):
    """CLEVR-Robot options (defaults: the original env's semantics on the calibrated lean physics)."""

    episode_length: int = 50
    """Steps per episode (TALAR: 50)."""
    task: str = "goal"
    """'goal': one of 80 push goals per episode; 'arrangement': the 6-constraint arrangement task."""
    action_type: str = "discrete"
    """'discrete': 40 pushes (any ball, 8 directions); 'collect': TALAR's data-collection variant, 8 pushes of the
    goal's source ball only (the original collected its task dataset this way; goal task only)."""
    arrangement_reward: str = "distinct"
    """Arrangement task: the reward counts the 6 distinct constraints that hold ('distinct') or the paper's ten as
    listed, coinciding ones counted as often as they are listed ('listed', 0..10)."""
    fail_on_displacement: bool = False
    """Goal task: terminate with -10 when a non-source ball moves > 0.2 from its episode-start position."""
    timestep: float = 0.02
    """Physics timestep in seconds (lean calibration; the original used 0.01)."""
    substeps: int = 20
    """Physics steps per action; timestep x substeps = 0.4 s of pushing, as in the original."""
    solver_iterations: int = 1
    """Newton solver iterations (original: 20; 1 to 20 agree within 1 mm on this model, see xmls/clevr.xml)."""
    ls_iterations: int = 4
    """Solver line-search iterations."""
    start: str = "reset"
    """Goal task: where an episode starts. 'reset' (balls drawn at random: the original's and TALAR's) or 'after_goal'
    (the same draw, then a random goal made to hold, as a chain's earlier goal leaves the balls: its source ball set
    beside its reference ball on the goal's side; goals are tried in random order until that spot is on the table
    and clear of the other balls)."""


@struct.dataclass
class ClevrTask:
    """Per-episode task data (the arrangement task has no goal: goal/source/destination/relation are -1)."""

    goal: jax.Array  # () int32 goal id in [0, 80) (tasks.py), -1 for arrangement
    source: jax.Array  # () int32 colour index of the ball to move
    destination: jax.Array  # () int32 colour index of the reference ball
    relation: jax.Array  # () int32 index into tasks.RELATIONS (0 front, 1 behind, 2 left, 3 right)
    start_xy: jax.Array  # (5, 2) float32 ball centres at the episode start
    distance: jax.Array  # () float32 source-to-target distance after the last step (the dense reward's d_prev)


def _goal_task(goal: jax.Array, ball_xy: jax.Array) -> ClevrTask:
    """The task of pushing for ``goal`` from the balls at ``ball_xy`` (an episode's start, or a new goal's)."""
    return ClevrTask(
        goal=goal,
        source=jnp.asarray(tasks.GOAL_SOURCE)[goal],
        destination=jnp.asarray(tasks.GOAL_DESTINATION)[goal],
        relation=jnp.asarray(tasks.GOAL_RELATION)[goal],
        start_xy=ball_xy,
        distance=tasks.goal_distance(ball_xy, goal),
    )


class ClevrEnv(Env):
    """Five balls on a table and a point pusher (Jiang et al. 2019 CLEVR-Robot; TALAR's goal semantics).

    | action a in [0, 40) | meaning |
    |---|---|
    | a // 8 | ball to push (0 red, 1 blue, 2 green, 3 purple, 4 cyan) |
    | a % 8 | direction: +x, +y, -x, -y, then (+x+y, -x+y, +x-y, -x-y) x 0.8 (force per axis, N) |

    A push teleports the pusher 0.15 d behind the ball (zero pusher velocity) and applies force d for 0.4 s;
    ball velocities carry over between steps. Float score vectors of length 40 are argmax-ed. With
    ``action_type='collect'`` the action is a direction in [0, 8) and the ball is the goal's source.

    | observation index | meaning |
    |---|---|
    | 2i, 2i + 1 | x, y of ball i (metres; front = +y, right = +x) |

    ``goal``: reward 10 (d_prev - d) with d the distance from the source to destination + 0.195 u_relation,
    +100 and termination on success (right sector and centre distance < 0.39); optional -10 displacement
    failure. ``arrangement``: reward = number of the 6 constraints holding (sector test, no distance limit; or of the
    paper's ten as listed with ``arrangement_reward='listed'``); terminates with success when all 6 hold.
    """

    config_class = ClevrConfig
    xml_path = Path(__file__).parent / "xmls" / "clevr.xml"
    # straight above the table: x to the right, y up ("to the left of" reads left, "in front of" reads up)
    render_camera = {"lookat": (0.0, 0.2, -0.3), "distance": 1.75, "azimuth": 90.0, "elevation": -90.0}

    def __init__(self, config: ClevrConfig | None = None, physics: str | None = None):
        super().__init__(config, physics)
        self._arrangement = self.config.task == "arrangement"
        self._collect = self.config.action_type == "collect"

    def check_config(self, config: ClevrConfig) -> None:
        check_choice("task", config.task, TASK_KINDS)
        check_choice("arrangement_reward", config.arrangement_reward, tasks.ARRANGEMENT_REWARDS)
        check_choice("action_type", config.action_type, ACTION_TYPES)
        check_choice("start", config.start, START_STATES)
        if config.action_type == "collect" and config.task != "goal":
            raise ValueError("action_type='collect' pushes the goal's source ball: it needs task='goal'")
        if config.timestep <= 0 or config.substeps < 1 or config.solver_iterations < 1 or config.ls_iterations < 1:
            raise ValueError("timestep must be > 0; substeps, solver_iterations and ls_iterations >= 1")

    def load_model(self) -> mujoco.MjModel:
        model = super().load_model()
        model.opt.timestep = self.config.timestep
        model.opt.iterations = self.config.solver_iterations
        model.opt.ls_iterations = self.config.ls_iterations
        return model

    # --- sizes ----------------------------------------------------------------------------------
    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec("discrete", tasks.NUM_DIRECTIONS if self._collect else tasks.NUM_ACTIONS)

    def push_action(self, state: State, action: jax.Array) -> jax.Array:
        """The 40-way push id of ``action`` in ``state`` (for ``action_type='collect'``: source * 8 + direction).

        Task datasets store this id, so a dataset collected with either action type serves 40-action policies.
        """
        action = self.check_action(action)
        if self._collect:
            return state.task.source * tasks.NUM_DIRECTIONS + action
        return action

    @property
    def num_goals(self) -> int:
        """80 push goals; the arrangement task is a single fixed goal."""
        return 1 if self._arrangement else tasks.NUM_GOALS

    @property
    def goal_names(self) -> tuple[str, ...]:
        """The 80 goals' descriptions (``'red ball in front of the blue ball'``); ``('arrangement',)`` for the
        arrangement task."""
        return ("arrangement",) if self._arrangement else tasks.GOAL_NAMES

    @property
    def state_observation_size(self) -> int:
        return 2 * tasks.NUM_BALLS

    @property
    def goal_feature_size(self) -> int:
        """One-hots of the source ball (5), the reference ball (5) and the relation (4); none for arrangement."""
        return 0 if self._arrangement else 2 * tasks.NUM_BALLS + tasks.NUM_RELATIONS

    def goal_features(self, task: ClevrTask) -> jax.Array:
        if self._arrangement:
            return jnp.zeros((0,), jnp.float32)
        return jnp.concatenate(
            [
                jax.nn.one_hot(task.source, tasks.NUM_BALLS),
                jax.nn.one_hot(task.destination, tasks.NUM_BALLS),
                jax.nn.one_hot(task.relation, tasks.NUM_RELATIONS),
            ]
        )

    # --- functional API -------------------------------------------------------------------------
    def reset(self, rng: jax.Array, goal: jax.Array | int | str | None = None) -> State:
        """A fresh scene and a goal: uniform over the goals not already met, or ``goal`` (an id or a name; see
        ``Env.reset``) when given: the balls are then re-drawn, up to 16 times, until that goal does not already
        hold. The arrangement task has one fixed goal and ignores ``goal`` once checked."""
        goal = self.goal_id(goal)
        out_of_range = self.goal_out_of_range(goal)
        rng_balls, rng_goal = jax.random.split(rng)
        ball_xy = self._draw_balls(rng_balls)
        if goal is not None and not self._arrangement:
            goal = jnp.asarray(goal, jnp.int32)

            def already_met(carry):
                return tasks.goal_success(carry[1], goal) & (carry[2] < 16)

            def redraw(carry):
                key, sub = jax.random.split(carry[0])
                return key, self._draw_balls(sub), carry[2] + 1

            _, ball_xy, _ = jax.lax.while_loop(already_met, redraw, (rng_goal, ball_xy, jnp.int32(0)))
        qpos = jnp.zeros(self.mj_model.nq, jnp.float32).at[: self.state_observation_size].set(ball_xy.reshape(-1))
        data = self.physics.init(qpos)
        if self._arrangement:
            none = jnp.int32(-1)
            task = ClevrTask(none, none, none, none, ball_xy, jnp.float32(0.0))
        else:
            goal = tasks.sample_goal(rng_goal, ball_xy) if goal is None else goal
            task = _goal_task(goal, ball_xy)
        zero = jnp.zeros((), jnp.float32)
        metrics = self._metrics(ball_xy, task, zero, zero)
        obs = self.observe_goal(ball_xy.reshape(-1), task)
        state = State(data=data, obs=obs, reward=zero, done=zero, metrics=metrics, info={}, task=task)
        return self.flag_out_of_range(state, out_of_range)

    def step(self, state: State, action: jax.Array) -> State:
        out_of_range = self.action_out_of_range(action)
        action = self.push_action(state, action)
        ball, direction = action // tasks.NUM_DIRECTIONS, action % tasks.NUM_DIRECTIONS
        force = jnp.asarray(tasks.PUSH_DIRECTIONS)[direction]
        data: PhysicsState = state.data
        ball_xy = data.qpos[: self.state_observation_size].reshape(tasks.NUM_BALLS, 2)
        pusher_xy = ball_xy[ball] - tasks.PUSH_OFFSET * force
        qpos, qvel = data.qpos.at[_PUSHER_QPOS].set(pusher_xy), data.qvel.at[_PUSHER_QPOS].set(0.0)
        teleported = data.replace(qpos=qpos, qvel=qvel)
        data = self.physics.step(teleported, force, self.config.substeps)
        ball_xy = data.qpos[: self.state_observation_size].reshape(tasks.NUM_BALLS, 2)
        task: ClevrTask = state.task
        if self._arrangement:
            satisfied = tasks.arrangement_satisfied(ball_xy)
            success = jnp.all(satisfied)
            failure = jnp.bool_(False)
            if self.config.arrangement_reward == "listed":
                reward = jnp.sum(satisfied[jnp.asarray(tasks.ARRANGEMENT_LISTED)]).astype(jnp.float32)
            else:
                reward = jnp.sum(satisfied).astype(jnp.float32)
        else:
            distance = tasks.goal_distance(ball_xy, task.goal)
            success = tasks.goal_success(ball_xy, task.goal)
            failure = jnp.bool_(False)
            if self.config.fail_on_displacement:
                failure = tasks.displacement_failure(ball_xy, task.start_xy, task.source) & ~success
            reward = tasks.goal_reward(task.distance, distance, success, failure)
            task = task.replace(distance=distance)
        success, failure = success.astype(jnp.float32), failure.astype(jnp.float32)
        metrics = self._metrics(ball_xy, task, success, failure)
        done = jnp.maximum(success, failure)
        obs = self.observe_goal(ball_xy.reshape(-1), task)
        stepped = state.replace(data=data, obs=obs, reward=reward, done=done, metrics=metrics, task=task)
        return self.flag_out_of_range(stepped, out_of_range)

    def _draw_balls(self, rng: jax.Array) -> jax.Array:
        """(5, 2) a scene at reset: ``tasks.sample_ball_positions`` ('reset'), then with 'after_goal' a random goal
        made to hold (``after_goal``), with a key derived from ``rng`` so that the balls are the 'reset' ones first."""
        ball_xy = tasks.sample_ball_positions(rng)
        if self.config.start == "after_goal" and not self._arrangement:
            candidates = jax.random.permutation(jax.random.fold_in(rng, 1), tasks.NUM_GOALS)
            ball_xy = after_goal(ball_xy, candidates)
        return ball_xy

    def retarget(self, state: State, goal: jax.Array | int | str) -> State:
        """``state`` pursuing ``goal`` from now on (see ``Env.retarget``): the goal, its source and reference balls
        and its relation change, and the episode start becomes the balls' current positions (``start_xy``, what
        ``fail_on_displacement`` measures from, and the dense reward's distance), as if a reset had laid the balls
        out as they are now; ball and pusher velocities are kept. The arrangement task has no goal to change."""
        if self._arrangement:
            raise NotImplementedError("the arrangement task has one fixed goal: it has no goal to retarget")
        goal = self.goal_id(goal)
        if goal is None:
            raise ValueError("retarget needs a goal (an id or a goal name)")
        out_of_range = self.goal_out_of_range(goal)
        goal = jnp.asarray(goal, jnp.int32)
        ball_xy = state.data.qpos[: self.state_observation_size].reshape(tasks.NUM_BALLS, 2)
        task = _goal_task(goal, ball_xy)
        zero = jnp.zeros((), jnp.float32)
        metrics = self._metrics(ball_xy, task, zero, zero)
        obs = self.observe_goal(ball_xy.reshape(-1), task)
        retargeted = state.replace(obs=obs, reward=zero, done=zero, metrics=metrics, task=task)
        return self.flag_out_of_range(retargeted, out_of_range)

    def _metrics(self, ball_xy: jax.Array, task: ClevrTask, success: jax.Array, failure: jax.Array) -> dict:
        if self._arrangement:
            num_satisfied = jnp.sum(tasks.arrangement_satisfied(ball_xy)).astype(jnp.float32)
            return {"success": success, "num_satisfied": num_satisfied}
        return {"success": success, "failure": failure, "distance": task.distance}


def after_goal(ball_xy: jax.Array, goals: jax.Array) -> jax.Array:
    """(5, 2) ``ball_xy`` with the first goal of ``goals`` (K,) that fits made to hold: its source ball at
    ``AFTER_GOAL_DISTANCE`` from its reference ball, on the goal's side. A goal fits when that spot lies in the
    reachable region and at least ``tasks.MIN_SEPARATION`` from the other balls; with none fitting, ``ball_xy``."""
    parts = (jnp.asarray(t)[goals] for t in (tasks.GOAL_SOURCE, tasks.GOAL_DESTINATION, tasks.GOAL_RELATION))
    source, destination, relation = parts
    spots = ball_xy[destination] + AFTER_GOAL_DISTANCE * jnp.asarray(tasks.RELATION_VECTORS)[relation]  # (K, 2)
    balls = jnp.arange(tasks.NUM_BALLS)
    others = (balls != source[:, None]) & (balls != destination[:, None])  # (K, 5)
    far = jnp.linalg.norm(ball_xy[None] - spots[:, None], axis=-1) >= tasks.MIN_SEPARATION
    clear = jnp.all(far | ~others, axis=1)
    inside = jnp.all((spots >= tasks.REGION_LOW) & (spots <= tasks.REGION_HIGH), axis=1)
    fits = clear & inside
    first = jnp.argmax(fits)
    return jnp.where(jnp.any(fits), ball_xy.at[source[first]].set(spots[first]), ball_xy)
