"""Gymnasium adapters (``envs.to_gymnasium``, ``envs.to_gymnasium_vector``): Gymnasium's env checker on every
registered env, the batched step against the JAX env's own vmapped step, seeding, auto-reset, goals by id or name,
the ids registered with Gymnasium (``gymnasium.make("talar_jax/Kitchen-v0")``) and clear errors."""

import re
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.render import RenderError

gym = pytest.importorskip("gymnasium")
check_env = pytest.importorskip("gymnasium.utils.env_checker").check_env

ROOT = Path(__file__).resolve().parents[1]
NUM_ENVS = 8
EPISODE_LENGTH = 4
_adapters: dict[tuple, object] = {}


def single(name: str):
    """One ``to_gymnasium(name)`` adapter per env name for the whole module (each adapter compiles its own step)."""
    if name not in _adapters:
        _adapters[name] = envs.to_gymnasium(name)
    return _adapters[name]


def vector(name: str):
    """One vector adapter per env name for the whole module, of an env built here (CLEVR with its displacement
    failure on, so that random pushes terminate episodes) and a short time limit."""
    if ("vector", name) not in _adapters:
        options = {"fail_on_displacement": True} if name == "clevr" else {}
        env = envs.make(name, physics="c", **options)
        _adapters["vector", name] = envs.to_gymnasium_vector(env, NUM_ENVS, episode_length=EPISODE_LENGTH)
    return _adapters["vector", name]


def random_actions(space, seed: int) -> np.ndarray:
    space.seed(seed)
    return space.sample()


@pytest.mark.parametrize("name", envs.ALL_ENVS)
def test_check_env(name):
    env = single(name)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, skip_render_check=True)
    # The unbounded observation Box is the only thing the checker may warn about.
    unexpected = [str(w.message) for w in caught if "infinity" not in str(w.message)]
    assert not unexpected, unexpected
    assert env.observation_space.shape == (env.jax_env.observation_size,)
    assert isinstance(env.action_space, gym.spaces.Discrete if name.startswith("clevr") else gym.spaces.Box)


@pytest.mark.parametrize("name", ["clevr", "kitchen"])
def test_vector_step_equals_jax_step(name):
    """Same states and actions: the adapter's one-call batched step == ``jax.vmap(env.step)`` of the JAX env,
    through time limits and (CLEVR) terminations, whose sub-envs restart at once."""
    vec = vector(name)
    assert vec.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    jax_step = jax.jit(jax.vmap(vec.jax_env.step))
    obs, _ = vec.reset(seed=0)
    np.testing.assert_array_equal(obs, np.asarray(vec.state.obs))
    steps = np.zeros(NUM_ENVS, int)
    ended_by = {"terminated": 0, "truncated": 0}
    for t in range(2 * EPISODE_LENGTH):
        actions = random_actions(vec.action_space, t)
        if name == "clevr":  # half the sub-envs push their goal's source ball: fewer failures, some time limits
            half = NUM_ENVS // 2
            actions[:half] = np.asarray(vec.state.task.source)[:half] * 8 + actions[:half] % 8
        expected = jax_step(vec.state, jnp.asarray(actions))
        obs, reward, terminated, truncated, info = vec.step(actions)
        steps += 1
        exp_terminated = np.asarray(expected.done) > 0.5
        np.testing.assert_array_equal(terminated, exp_terminated)
        np.testing.assert_array_equal(truncated, ~exp_terminated & (steps == EPISODE_LENGTH))
        np.testing.assert_allclose(reward, np.asarray(expected.reward), rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(info["success"], np.asarray(expected.metrics["success"]))
        assert obs.dtype == np.float32 and obs.shape == vec.observation_space.shape
        ended = terminated | truncated
        np.testing.assert_allclose(obs[~ended], np.asarray(expected.obs)[~ended], rtol=1e-6, atol=1e-6)
        if ended.any():  # the ending observations are in final_obs, obs starts the next episode
            final_obs = np.stack(info["final_obs"][ended])
            np.testing.assert_allclose(final_obs, np.asarray(expected.obs)[ended], rtol=1e-6, atol=1e-6)
            assert all(o is None for o in info["final_obs"][~ended])
            np.testing.assert_array_equal(info["_final_obs"], ended)
            np.testing.assert_array_equal(info["final_info"]["_success"], ended)
            np.testing.assert_array_equal(obs[ended], np.asarray(vec.state.obs)[ended])
            assert not np.allclose(obs[ended], final_obs)
            np.testing.assert_array_equal(np.asarray(vec.state.metrics["success"])[ended], 0.0)  # fresh episodes
        steps[ended] = 0
        ended_by["terminated"] += terminated.sum()
        ended_by["truncated"] += truncated.sum()
    assert ended_by["truncated"] > 0
    if name == "clevr":
        assert ended_by["terminated"] > 0, "no sub-env terminated: the auto-reset after termination went untested"


def test_seeding_determinism():
    env = single("kitchen")  # observation noise and goals come from the seed
    actions = [random_actions(env.action_space, t) for t in range(3)]

    def episode(seed):
        obs = [env.reset(seed=seed)[0]]
        obs += [env.step(a)[0] for a in actions]
        return np.stack(obs)

    first = episode(7)
    np.testing.assert_array_equal(first, episode(7))
    assert not np.array_equal(first, episode(8))
    # Without a seed, reset continues from the internal key: a new episode, itself reproducible after the seed.
    env.reset(seed=7)
    unseeded = env.reset()[0]
    assert not np.array_equal(unseeded, first[0])
    env.reset(seed=7)
    np.testing.assert_array_equal(env.reset()[0], unseeded)

    vec = vector("clevr")
    a, b = vec.reset(seed=3)[0], vec.reset(seed=3)[0]
    np.testing.assert_array_equal(a, b)
    assert len({tuple(row) for row in a}) == NUM_ENVS  # sub-envs get different keys


def test_goals():
    env = single("clevr")
    for goal in (0, 41, 79):
        _, info = env.reset(seed=0, options={"goal": goal})
        assert info["goal"] == goal
    vec = vector("clevr")
    goals = [5, None, 7, 7] * (NUM_ENVS // 4)
    assert vec.reset(seed=0, options={"goal": goals})[1]["goal"][[0, 2, 3]].tolist() == [5, 7, 7]
    assert vec.reset(seed=0, options={"goal": 9})[1]["goal"].tolist() == [9] * NUM_ENVS
    for _ in range(EPISODE_LENGTH):  # the auto-resets keep the reset's goal
        info = vec.step(np.zeros(NUM_ENVS, int))[-1]
    assert "final_obs" in info and info["goal"].tolist() == [9] * NUM_ENVS
    assert vec.reset(seed=0)[1]["goal"].tolist() != [9] * NUM_ENVS  # back to the adapter's goal (sampled)
    fixed = envs.to_gymnasium("clevr", goal=12)
    assert fixed.reset(seed=0)[1]["goal"] == 12


def test_goal_names():
    """Goals by name, as the env's tasks module names them (``env.goal_names``), anywhere a goal id is taken."""
    kitchen = envs.to_gymnasium("kitchen", goal="microwave")
    assert kitchen.goal == 0 and kitchen.reset(seed=0)[1]["goal"] == 0
    assert kitchen.reset(seed=0, options={"goal": "Top Burner"})[1]["goal"] == 4
    assert kitchen.reset(seed=0, options={"goal": "light_switch"})[1]["goal"] == 2
    env = single("clevr")
    name = env.jax_env.goal_names[41]
    assert env.reset(seed=0, options={"goal": name})[1]["goal"] == 41
    vec = vector("clevr")
    names = [name, None, "7", 7] * (NUM_ENVS // 4)
    assert vec.reset(seed=0, options={"goal": names})[1]["goal"][[0, 2, 3]].tolist() == [41, 7, 7]
    assert vec.reset(seed=0, options={"goal": name})[1]["goal"].tolist() == [41] * NUM_ENVS
    hinge = envs.to_gymnasium("kitchen", goal="hinge cabinet", hinge_cabinet_task=True)
    assert hinge.goal == 6
    with pytest.raises(ValueError, match="unknown goal 'hinge cabinet' for KitchenEnv"):
        envs.to_gymnasium("kitchen", goal="hinge cabinet")


def test_the_physics_is_the_default_physics_unless_chosen():
    assert single("clevr").jax_env.physics.name == envs.default_physics()
    assert envs.to_gymnasium("kitchen", physics="mjx").jax_env.physics.name == "mjx"  # an explicit physics wins


REGISTERED_IDS = {
    "clevr": "talar_jax/Clevr-v0",
    "clevr-arrangement": "talar_jax/ClevrArrangement-v0",
    "kitchen": "talar_jax/Kitchen-v0",
    "kitchen-all": "talar_jax/KitchenAll-v0",
}


def test_every_env_is_registered_with_gymnasium():
    from envs.gymnasium_adapter import GymnasiumEnv, GymnasiumVectorEnv

    assert {name: envs.gymnasium_id(name) for name in envs.ALL_ENVS} == REGISTERED_IDS
    for name, env_id in REGISTERED_IDS.items():
        spec = gym.spec(env_id)
        assert spec.entry_point == "envs.gymnasium_adapter:to_gymnasium" and spec.kwargs == {"name_or_env": name}
        assert spec.vector_entry_point == "envs.gymnasium_adapter:to_gymnasium_vector"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert envs.register_with_gymnasium()  # again: nothing new, and no "overriding" warning
    env = gym.make("talar_jax/Kitchen-v0", goal="microwave")
    assert env.spec.id == "talar_jax/Kitchen-v0"
    assert env.spec.kwargs == {"name_or_env": "kitchen", "goal": "microwave"}
    assert isinstance(env.unwrapped, GymnasiumEnv) and env.unwrapped.jax_env.physics.name == envs.default_physics()
    obs, info = env.reset(seed=0)
    assert obs.shape == (30,) and info["goal"] == 0
    arrangement = gym.make("talar_jax/ClevrArrangement-v0", episode_length=3)
    assert arrangement.unwrapped.jax_env.config.task == "arrangement" and arrangement.unwrapped.episode_length == 3
    vec = gym.make_vec("talar_jax/Clevr-v0", num_envs=2, goal="red ball behind the blue ball")
    assert isinstance(vec, GymnasiumVectorEnv)
    assert vec.spec.id == "talar_jax/Clevr-v0" and vec.spec.kwargs["goal"] == "red ball behind the blue ball"
    assert vec.reset(seed=0)[1]["goal"].tolist() == [1, 1]


def test_gymnasium_make_imports_envs_itself_in_a_fresh_interpreter():
    """Gymnasium 1.x loads no plugins: an id is known once the package registering it is imported. The module prefix
    of the id (``"envs:..."``) has Gymnasium import ``envs`` itself, so nothing else needs importing first. Every
    ``gymnasium.make`` id the README shows is made here as written."""
    readme_ids = re.findall(r'gymnasium\.make\("([^"]+)"\)', (ROOT / "README.md").read_text())
    assert readme_ids
    code = (
        "import sys, gymnasium\n"
        f"for env_id in {readme_ids!r}:\n"
        "    gymnasium.make(env_id, physics='c').reset(seed=0)\n"
        "env = gymnasium.make('envs:talar_jax/Kitchen-v0', physics='c', goal='microwave')\n"
        "assert env.spec.id == 'talar_jax/Kitchen-v0' and env.reset(seed=0)[1]['goal'] == 0\n"
        "vec = gymnasium.make_vec('envs:talar_jax/Clevr-v0', num_envs=2, physics='c')\n"
        "assert vec.reset(seed=0)[0].shape == (2, 10)\n"
        "print('envs' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split() == ["True"]


def test_an_env_registered_later_is_registered_with_gymnasium_too():
    from envs.clevr import ClevrEnv

    envs.register_environment("clevr-collect-test", ClevrEnv, action_type="collect")
    try:
        spec = gym.spec("talar_jax/ClevrCollectTest-v0")
        assert spec.kwargs == {"name_or_env": "clevr-collect-test"}
    finally:  # leave both registries as they were for the other tests
        envs.registry._REGISTRY.pop("clevr-collect-test")
        gym.registry.pop("talar_jax/ClevrCollectTest-v0")


def test_clear_errors():
    env = single("clevr")
    for bad_goal in (80, -1, 1.5, True, "purple ball", np.zeros(2, int)):
        with pytest.raises(ValueError, match=r"for ClevrEnv.*; give an id in 0\.\.79 or a name such as"):
            envs.to_gymnasium("clevr", goal=bad_goal)
        with pytest.raises(ValueError, match=r"give an id in 0\.\.79"):
            env.reset(options={"goal": bad_goal})
    with pytest.raises(ValueError, match="unknown goal 'fridge' for KitchenEnv; .* one of the names 'microwave'"):
        envs.to_gymnasium_vector("kitchen", 2, goal=["microwave", "fridge"])
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"task": 3})
    with pytest.raises(ValueError, match="unknown option"):
        envs.to_gymnasium("clevr", bogus=1)
    with pytest.raises(ValueError, match="already built"):
        envs.to_gymnasium(env.jax_env, task="arrangement")
    with pytest.raises(ValueError, match="goal has 2 entries"):
        envs.to_gymnasium_vector("clevr", NUM_ENVS, goal=[1, 2])
    with pytest.raises(ValueError, match="render_mode"):
        envs.to_gymnasium("clevr", render_mode="human")
    env.reset(seed=0)
    for bad_action in (40, -1, 2.0, np.zeros(40)):
        with pytest.raises(ValueError, match=r"invalid action .* int\(s\) in \[0, 40\)"):
            env.step(bad_action)
    kitchen = single("kitchen")
    kitchen.reset(seed=0)
    for bad_action in (np.full(9, 1.5), np.zeros(8), np.full(9, np.nan)):
        with pytest.raises(ValueError, match="invalid action"):
            kitchen.step(bad_action)
    kitchen.step(np.zeros(9))  # float64 and int vectors inside the bounds are accepted
    kitchen.step(np.zeros(9, int))


def test_render_rgb_array():
    env = envs.to_gymnasium("clevr", render_mode="rgb_array")
    assert env.metadata["render_fps"] == pytest.approx(2.5)
    assert single("kitchen").metadata["render_fps"] == pytest.approx(12.5)
    env.reset(seed=0)
    try:
        frame = env.render()
    except RenderError as error:
        pytest.skip(f"no OpenGL: {error}")
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.std() > 0


def test_import_envs_without_gymnasium():
    code = (
        "import sys; sys.modules['gymnasium'] = None\n"
        "import envs\n"
        "assert 'envs.gymnasium_adapter' not in sys.modules and not envs.register_with_gymnasium()\n"
        "try:\n    envs.to_gymnasium('clevr')\nexcept ImportError:\n    pass\nelse:\n    raise SystemExit(1)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
