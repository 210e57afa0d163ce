"""Env contract for every registered env (``envs.ALL_ENVS``): shapes, finiteness, no retracing, determinism,
MJX-vs-C agreement, goals (names, eager checks) and clear errors. Sizes are read from each env, so new envs are covered
by registering them. Also: the default physics and the CPU XLA flag that MJX needs, seen from a fresh interpreter."""

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.wrappers import wrap_for_training

NUM_ENVS, NUM_STEPS = 8, 120  # the long random rollout (C backend, time limits and auto-resets included)
AGREE_STEPS, AGREE_ATOL = 4, 5e-3  # MJX (float32) vs MuJoCo C (float64): same reset key and actions, |obs diff| max


def random_actions(spec: envs.ActionSpec, key: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """Uniform random actions of ``spec`` with leading ``shape``."""
    if spec.kind == "discrete":
        return jax.random.randint(key, shape, 0, spec.size)
    return jax.random.uniform(key, shape + (spec.size,), minval=spec.low, maxval=spec.high)


def assert_close(a, b):
    """Equal arrays, floats up to the rounding of a compiled against an eager computation."""
    a, b = np.asarray(a), np.asarray(b)
    if np.issubdtype(a.dtype, np.floating):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
    else:
        np.testing.assert_array_equal(a, b)


class Compiled:
    """An env on both backends and its jitted functions, built once per env name (module scope)."""

    def __init__(self, name: str):
        self.name = name
        self.c_env = envs.make(name, physics="c")
        self.mjx_env = envs.make(name, physics="mjx")
        self.step_traces = 0
        self.reset = jax.jit(self.c_env.reset)

        def counted_step(state, action):
            self.step_traces += 1  # runs only while tracing
            return self.c_env.step(state, action)

        self.step = jax.jit(counted_step)
        self.rollout = jax.jit(self._training_rollout)
        self.c_short = jax.jit(lambda key: self._short_rollout(self.c_env, key))
        self.mjx_short = jax.jit(lambda key: self._short_rollout(self.mjx_env, key))

    def _training_rollout(self, key):
        env = envs.wrap_for_training(self.c_env)
        key_reset, key_actions = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(key_reset, NUM_ENVS))
        actions = random_actions(env.action_spec, key_actions, (NUM_STEPS, NUM_ENVS))

        def body(state, action):
            state = jax.vmap(env.step)(state, action)
            return state, (state.obs, state.reward, state.done, state.info["steps"], state.metrics["success"])

        return jax.lax.scan(body, state, actions)[1]

    def _short_rollout(self, env, key):
        key_reset, key_actions = jax.random.split(key)
        state = env.reset(key_reset)

        def body(state, action):
            state = env.step(state, action)
            return state, state.obs

        return jax.lax.scan(body, state, random_actions(env.action_spec, key_actions, (AGREE_STEPS,)))[1]


@pytest.fixture(scope="module", params=envs.ALL_ENVS)
def compiled(request) -> Compiled:
    return Compiled(request.param)


def test_registry_lists_envs():
    assert "clevr" in envs.ALL_ENVS and "clevr-arrangement" in envs.ALL_ENVS
    assert envs.registered_names() == envs.ALL_ENVS


def test_jitted_reset_and_step_shapes(compiled):
    env = compiled.c_env
    state = compiled.reset(jax.random.key(0))
    assert state.obs.shape == (env.observation_size,)
    assert env.action_size == env.action_spec.size >= 1 and env.num_goals >= 1 and env.episode_length >= 1
    action = random_actions(env.action_spec, jax.random.key(1), ())
    stepped = compiled.step(state, action)
    assert stepped.obs.shape == (env.observation_size,) and stepped.obs.dtype == jnp.float32
    assert stepped.reward.shape == () and stepped.done.shape == ()
    assert "success" in stepped.metrics and set(stepped.metrics) == set(state.metrics)
    assert jax.tree.structure(stepped.task) == jax.tree.structure(state.task) and state.task is not None
    assert not np.array_equal(stepped.obs, state.obs)  # the action did something


def test_no_retracing(compiled):
    env = compiled.c_env
    state = compiled.reset(jax.random.key(2))
    for i in range(3):
        state = compiled.step(state, random_actions(env.action_spec, jax.random.key(10 + i), ()))
    state = compiled.step(compiled.reset(jax.random.key(3)), random_actions(env.action_spec, jax.random.key(4), ()))
    jax.block_until_ready(state)
    assert compiled.step_traces == 1


def test_long_random_rollout_is_finite_and_resets(compiled):
    obs, reward, done, steps, success = compiled.rollout(jax.random.key(5))
    env = compiled.c_env
    assert obs.shape == (NUM_STEPS, NUM_ENVS, env.observation_size)
    assert np.isfinite(obs).all() and np.isfinite(reward).all()
    assert set(np.unique(done)) <= {0.0, 1.0} and set(np.unique(success)) <= {0.0, 1.0}
    assert steps.max() <= env.episode_length
    if env.episode_length < NUM_STEPS:  # time limits end episodes and auto-reset starts new ones
        assert done.sum() >= NUM_ENVS


def test_determinism_for_a_seed(compiled):
    first = compiled.rollout(jax.random.key(6))
    again = compiled.rollout(jax.random.key(6))
    other = compiled.rollout(jax.random.key(7))
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0], other[0])


def test_backends_agree_on_a_short_rollout(compiled):
    c_obs = np.asarray(compiled.c_short(jax.random.key(8)))
    mjx_obs = np.asarray(compiled.mjx_short(jax.random.key(8)))
    assert np.isfinite(mjx_obs).all()
    np.testing.assert_allclose(mjx_obs, c_obs, atol=AGREE_ATOL, rtol=0)


@pytest.mark.parametrize(
    ("name", "option"),
    [
        ("clevr", "task"),
        ("clevr", "arrangement_reward"),
        ("clevr", "action_type"),
        ("kitchen", "integrator"),
        ("kitchen", "posture_targets"),
        ("kitchen", "stillness"),
        ("kitchen", "all_tasks_reward"),
    ],
)
def test_an_unknown_string_option_names_its_valid_values(name, option):
    default = getattr(envs.get_default_config(name), option)
    with pytest.raises(ValueError, match=f"^unknown {option} 'nope'; choose one of .*{default}"):
        envs.make(name, physics="c", **{option: "nope"})


def test_clear_errors(compiled):
    name, env = compiled.name, compiled.c_env
    with pytest.raises(ValueError, match="registered environments: .*clevr"):
        envs.make(name + "-nope")
    with pytest.raises(ValueError, match="valid options: .*episode_length"):
        envs.make(name, not_an_option=1)
    with pytest.raises(TypeError, match="episode_length"):
        envs.make(name, episode_length="long")
    with pytest.raises(ValueError, match="choose one of mjx, c"):
        envs.make(name, physics="gpu")
    state = compiled.reset(jax.random.key(0))
    spec = env.action_spec
    if spec.kind == "discrete":
        with pytest.raises(ValueError, match=f"valid actions are 0..{spec.size - 1}"):
            env.step(state, jnp.int32(spec.size))
        with pytest.raises(ValueError, match="scalar int"):
            env.step(state, jnp.zeros(spec.size + 1))
    else:
        with pytest.raises(ValueError, match=f"shape \\({spec.size},\\)"):
            env.step(state, jnp.zeros(spec.size + 1))


@pytest.mark.parametrize("name", envs.ALL_ENVS)
def test_goal_observation_appends_the_tasks_goal(name):
    plain = envs.make(name, physics="c")
    env = envs.make(name, physics="c", goal_observation=True)
    keys = jax.random.split(jax.random.key(3), 16)
    base, states = jax.jit(jax.vmap(plain.reset))(keys), jax.jit(jax.vmap(env.reset))(keys)
    assert states.obs.shape == (16, env.observation_size)
    assert env.observation_size == plain.observation_size + env.goal_feature_size
    np.testing.assert_array_equal(states.obs[:, : plain.observation_size], base.obs)  # same env part
    goal_part = np.asarray(states.obs[:, plain.observation_size :])
    if name in ("clevr-arrangement", "kitchen-all"):  # a single fixed task: no goal part
        assert goal_part.shape == (16, 0)
    elif name == "clevr":  # one-hots of source, reference ball and relation
        task = states.task
        expected = np.concatenate(
            [np.eye(5)[task.source], np.eye(5)[task.destination], np.eye(4)[task.relation]], axis=1
        )
        np.testing.assert_array_equal(goal_part, expected)
    else:  # kitchen: one-hot of the sub-task
        np.testing.assert_array_equal(goal_part, np.eye(env.num_goals)[np.asarray(states.task.goal)])
    # the goal part stays after a step, and fixed goals show up in it
    action = random_actions(env.action_spec, jax.random.key(4), ())
    state = jax.jit(env.step)(env.reset(jax.random.key(5), goal=None), action)
    assert state.obs.shape == (env.observation_size,)
    np.testing.assert_array_equal(state.obs[plain.observation_size :], env.goal_features(state.task))


def test_kitchen_hinge_cabinet_is_a_seventh_goal():
    env = envs.make("kitchen", physics="c", hinge_cabinet_task=True, goal_observation=True)
    assert env.num_goals == 7 and env.task_names[-1] == "hinge cabinet" and env.observation_size == 37
    goals = np.asarray(jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 700)).task.goal)
    assert np.bincount(goals, minlength=7).min() > 60  # sampled like the other six
    assert envs.make("kitchen-all", physics="c", hinge_cabinet_task=True).reset(
        jax.random.key(0)
    ).task.completed.shape == (7,)


# --- goals: names and eager checks -----------------------------------------------------------------------------------
def test_goal_names_resolve_to_their_ids(compiled):
    env = compiled.c_env
    names = env.goal_names
    assert len(names) == env.num_goals
    for goal_id, name in enumerate(names):
        assert env.goal_id(name) == goal_id == env.goal_id(f"  {name.upper().replace(' ', '_')} ")
        assert env.goal_id(str(goal_id)) == goal_id
    last = env.num_goals - 1
    by_name, by_id = env.reset(jax.random.key(0), goal=names[last]), env.reset(jax.random.key(0), goal=last)
    jax.tree.map(np.testing.assert_array_equal, by_name, by_id)


def test_reset_rejects_an_out_of_range_goal_eagerly(compiled):
    env, n = compiled.c_env, compiled.c_env.num_goals
    for bad in (n, -1, 200, np.int64(n), jnp.int32(n), jnp.array([0, n]), np.array(-1), 1.5, jnp.float32(1), True):
        with pytest.raises(ValueError, match=rf"give an id in 0\.\.{n - 1}") as error:
            env.reset(jax.random.key(0), goal=bad)
        assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match="unknown goal 'no such goal'"):
        env.reset(jax.random.key(0), goal="no such goal")
    assert int(env.reset(jax.random.key(0), goal=jnp.int32(n - 1)).task.goal) in (n - 1, -1)  # -1: a fixed task
    # VmapWrapper checks a batch of goals before tracing it
    with pytest.raises(ValueError, match=rf"goal {n} is out of range"):
        envs.VmapWrapper(env).reset(jax.random.split(jax.random.key(0), 2), np.array([0, n]))


def test_a_traced_goal_out_of_range_gives_a_nan_state(compiled):
    """Inside jit a goal has no value while tracing: an out-of-range one makes the state's obs and reward NaN,
    an in-range one gives the state an eager reset gives (up to the compiler's float rounding)."""
    env, n = compiled.c_env, compiled.c_env.num_goals
    reset = jax.jit(env.reset)
    for bad in (n, -1, 999):
        state = reset(jax.random.key(0), bad)
        assert np.isnan(np.asarray(state.obs)).all() and np.isnan(float(state.reward)), bad
    for good in sorted({0, n // 2, n - 1}):  # the ends and the middle: an eager reset per goal is slow
        state = reset(jax.random.key(0), good)
        assert np.isfinite(np.asarray(state.obs)).all()
        jax.tree.map(assert_close, state, env.reset(jax.random.key(0), good))
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(1), 3), jnp.int32([0, n, 0]))
    assert np.isnan(np.asarray(states.obs)).any(axis=1).tolist() == [False, True, False]


def test_a_traced_discrete_action_out_of_range_gives_a_nan_state(compiled):
    env, spec = compiled.c_env, compiled.c_env.action_spec
    if spec.kind != "discrete":  # continuous actions are clipped to their bounds by definition
        pytest.skip("a continuous env")
    state = compiled.reset(jax.random.key(0))
    for bad in (spec.size, -1):
        stepped = compiled.step(state, jnp.int32(bad))
        assert np.isnan(np.asarray(stepped.obs)).all() and np.isnan(float(stepped.reward)), bad
    for good in (0, spec.size - 1):
        stepped = compiled.step(state, jnp.int32(good))
        assert np.isfinite(np.asarray(stepped.obs)).all()
        jax.tree.map(assert_close, stepped, env.step(state, good))


# --- wrappers are envs ------------------------------------------------------------------------------------------------
def test_a_wrapped_env_is_an_env_and_its_reset_passes_the_goal_on(compiled):
    env = compiled.c_env
    last = env.num_goals - 1
    wrapped = envs.wrap_for_brax_training(env, episode_length=5)  # VmapWrapper(metrics(AutoReset(Episode(env))))
    assert isinstance(wrapped, envs.Env) and wrapped.unwrapped is env
    for member in ("num_goals", "goal_names", "action_spec", "observation_size", "render_camera", "config_class"):
        assert getattr(wrapped, member) == getattr(env, member), member
    assert wrapped.episode_length == 5 and wrapped.goal_id(env.goal_names[last]) == last
    keys = jax.random.split(jax.random.key(0), 2)
    expected = jax.vmap(lambda key: env.reset(jax.random.split(key)[1], last))(keys)
    for goal in (last, env.goal_names[last], np.array([last, last])):
        state = wrapped.reset(keys, goal=goal)
        np.testing.assert_array_equal(state.obs, expected.obs)
        np.testing.assert_array_equal(state.task.goal, expected.task.goal)
    with pytest.raises(ValueError, match="out of range"):
        wrapped.reset(keys, goal=env.num_goals)


def test_the_old_names_still_work_with_a_deprecation_warning():
    env = envs.make("kitchen", physics="c")
    with pytest.warns(DeprecationWarning, match="PHYSICS_NAMES"):
        assert envs.PHYSICS_BACKENDS == envs.PHYSICS_NAMES
    with pytest.warns(DeprecationWarning, match="default_physics"):
        assert envs.default_backend() == envs.default_physics()
    with pytest.warns(DeprecationWarning, match="physics.name"):
        assert env.backend == "c"
    with pytest.warns(DeprecationWarning, match="goal_names"):
        assert envs.goal_names("kitchen") == env.goal_names
    with pytest.warns(DeprecationWarning, match="goal_id"):
        assert envs.resolve_goal("kettle", env.goal_names) == 1 == env.check_goal("kettle")
    with pytest.warns(DeprecationWarning, match="envs.instructions"):
        from envs.registry import instruction_format  # noqa: F401
    from tests.point_env import PointEnv  # an env that names no goals of its own

    with pytest.warns(DeprecationWarning, match="override the goal_names property"):

        class OldStyle(PointEnv):
            @classmethod
            def goal_names_of(cls, config):
                return ("north", "west", "south", "east")

    assert OldStyle().goal_names == ("north", "west", "south", "east") and OldStyle().goal_id("south") == 2


# --- rendering --------------------------------------------------------------------------------------------------------
def test_render_works_off_screen_with_no_mujoco_gl_set():
    """No MUJOCO_GL and no display (a server, a container): the renderer makes its own EGL or OSMesa context."""
    import ctypes.util

    if not (ctypes.util.find_library("EGL") or ctypes.util.find_library("OSMesa")):
        pytest.skip("neither EGL nor OSMesa is installed")
    code = (
        "import json, os, jax, numpy as np, envs\n"
        "env = envs.make('clevr', physics='c')\n"
        "qpos = np.stack([np.asarray(env.reset(jax.random.key(i)).data.qpos) for i in range(2)])\n"
        "frames = env.render(qpos, 64, 48)\n"
        "print(json.dumps({'shapes': [list(f.shape) for f in frames], 'std': float(np.std(frames)),"
        " 'mujoco_gl': os.environ.get('MUJOCO_GL')}))\n"
    )
    environment = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    done = subprocess.run(
        [sys.executable, "-c", code], env=environment, capture_output=True, text=True, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["shapes"] == [[48, 64, 3]] * 2 and out["std"] > 0 and out["mujoco_gl"] is None


# --- default physics and the CPU XLA flag --------------------------------------------------------------------------
def test_make_picks_the_default_physics_and_an_explicit_physics_wins(compiled):
    assert envs.make(compiled.name).physics.name == envs.default_physics()
    if jax.default_backend() == "cpu":
        assert envs.default_physics() == "c"
    assert compiled.mjx_env.physics.name == "mjx" and compiled.c_env.physics.name == "c"


def run_fresh(code: str, xla_flags: str | None = None) -> dict:
    """Runs ``code`` in a fresh interpreter on the CPU, with no XLA_FLAGS (or ``xla_flags``) in its environment, and
    returns the JSON it prints last."""
    environment = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"} | {"JAX_PLATFORMS": "cpu"}
    if xla_flags is not None:
        environment["XLA_FLAGS"] = xla_flags
    done = subprocess.run(
        [sys.executable, "-c", code], env=environment, capture_output=True, text=True, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


WATCH_WARNINGS = """
import json, os, warnings
warnings.simplefilter("always")
caught = warnings.catch_warnings(record=True)
record = caught.__enter__()
"""


def test_mjx_on_a_cpu_sets_the_xla_flag_while_jax_has_not_started():
    code = WATCH_WARNINGS + (
        "import envs\n"
        "from envs import runtime\n"
        "c = envs.make('clevr', physics='c')\n"
        "after_c = os.environ.get('XLA_FLAGS')\n"
        "started_before = runtime.backends_initialised()\n"
        "envs.make('clevr', physics='mjx')\n"
        "print(json.dumps({'after_c': after_c, 'started_before': started_before, 'flags': os.environ['XLA_FLAGS'],"
        " 'started_after': runtime.backends_initialised(), 'warnings': [str(w.message) for w in record]}))\n"
    )
    out = run_fresh(code)
    assert out == {
        "after_c": None,  # C physics needs no flag
        "started_before": False,
        "flags": "--xla_cpu_use_fusion_emitters=false",
        "started_after": True,  # set before JAX started, so XLA read it
        "warnings": [],
    }
    # A user's own value of the option is left as it is, without a warning.
    mine = "--xla_cpu_use_fusion_emitters=true --xla_force_host_platform_device_count=2"
    code = WATCH_WARNINGS + (
        "import envs\nenvs.make('clevr', physics='mjx')\n"
        "print(json.dumps({'flags': os.environ['XLA_FLAGS'], 'warnings': [str(w.message) for w in record]}))\n"
    )
    assert run_fresh(code, xla_flags=mine) == {"flags": mine, "warnings": []}


def test_mjx_on_a_cpu_warns_once_when_jax_has_started_without_the_flag():
    code = WATCH_WARNINGS + (
        "import jax.numpy as jnp\n"
        "jnp.zeros(1).block_until_ready()\n"  # JAX has started: XLA_FLAGS is no longer read
        "import envs\n"
        "assert envs.make('clevr').physics.name == 'c'\n"  # the default on a CPU: no flag needed
        "envs.make('clevr', physics='mjx')\n"
        "envs.make('clevr-arrangement', physics='mjx')\n"
        "print(json.dumps({'flags': os.environ.get('XLA_FLAGS'),"
        " 'warnings': [(str(w.message), w.filename, w.category.__name__) for w in record]}))\n"
    )
    out = run_fresh(code)
    assert out["flags"] is None
    assert len(out["warnings"]) == 1, out["warnings"]
    message, filename, category = out["warnings"][0]
    assert "XLA_FLAGS=--xla_cpu_use_fusion_emitters=false" in message and "twice as long" in message
    assert "\n" not in message and category == "UserWarning"
    assert filename == "<string>"  # it points at the user's line, not into envs


@pytest.mark.parametrize("name", envs.ALL_ENVS)
def test_the_agent_part_of_the_observation_is_the_agent_alone(name):
    """``agent_observation_size`` leading entries describe the agent: moving it for a few steps with no contact
    changes those entries and nothing else of the scene; wrappers read it through."""
    env = envs.make(name, physics="c", noise_ratio=0.0) if name.startswith("kitchen") else envs.make(name, physics="c")
    size = env.agent_observation_size
    assert 0 <= size <= env.state_observation_size
    assert wrap_for_training(env).agent_observation_size == size
    if not name.startswith("kitchen"):
        assert size == 0  # CLEVR's observation is the balls: the pusher is not observed
        return
    still = moved = env.reset(jax.random.key(0))
    for _ in range(5):  # the fingers open in free space, away from every object; the scene settles the same
        still = env.step(still, jnp.zeros(env.action_size))
        moved = env.step(moved, jnp.zeros(env.action_size).at[7:].set(1.0))
    change = np.abs(np.asarray(moved.obs - still.obs))[: env.state_observation_size]
    assert change[:size].max() > 1e-3 and change[size:].max() < 1e-5
