"""Task dataset: roll out a goal-conditioned policy in many envs; keep (s_i, a_i, s_T, L_N) of successful episodes."""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from envs.wrappers import EpisodeWrapper
from talar_jax.acting import goal_of
from talar_jax.checkpoint import write_json_atomic
from talar_jax.conditioning import Conditioner
from talar_jax.networks import PPONetworks, make_inference_fn

_ARRAYS = ("states", "final_states", "actions", "instruction_ids", "goal_ids", "episode_ids")


@dataclasses.dataclass(frozen=True, eq=False)
class TaskDataset:
    """Tuples from successful episodes only (s_T must show the goal achieved).

    Attributes:
        states: (N, obs) float32 s_i, every state of a successful episode where an action was taken.
        final_states: (N, obs) float32 s_T, the state in which that episode succeeded.
        actions: (N,) int32 or (N, action) float32 a_i taken in s_i (for behaviour cloning), in the full action
            space of the env (CLEVR's 'collect' pushes are stored as 40-way push ids).
        instruction_ids: (N,) int32 L_N, a training instruction of the episode's goal drawn per tuple.
        goal_ids: (N,) int32 goal of the episode.
        episode_ids: (N,) int32 episode each tuple comes from.
        config: how the dataset was made (JSON-ready).
    """

    states: np.ndarray
    final_states: np.ndarray
    actions: np.ndarray
    instruction_ids: np.ndarray
    goal_ids: np.ndarray
    episode_ids: np.ndarray
    config: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        count = len(self.states)
        if any(len(getattr(self, name)) != count for name in _ARRAYS):
            raise ValueError(f"all arrays need {count} rows: " + str({n: len(getattr(self, n)) for n in _ARRAYS}))

    def __len__(self) -> int:
        return len(self.states)

    def save(self, directory: str | Path) -> Path:
        """Writes ``task_dataset.npz`` and ``task_dataset.json`` (config) atomically; returns the npz path."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / "task_dataset.npz"
        handle, temporary = tempfile.mkstemp(dir=directory, prefix=".task_dataset.", suffix=".npz")
        with os.fdopen(handle, "wb") as file:
            np.savez(file, **{name: getattr(self, name) for name in _ARRAYS})
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
        write_json_atomic(directory / "task_dataset.json", {"num_tuples": len(self), **self.config})
        return path

    @classmethod
    def load(cls, directory: str | Path) -> TaskDataset:
        directory = Path(directory)
        path = directory / "task_dataset.npz"
        if not path.exists():
            raise FileNotFoundError(f"no task dataset at {path}")
        with np.load(path) as arrays:
            fields = {name: arrays[name] for name in _ARRAYS}
        meta_path = directory / "task_dataset.json"
        config = json.loads(meta_path.read_text()) if meta_path.exists() else {}
        config.pop("num_tuples", None)
        return cls(**fields, config=config)


def policy_behaviour(
    networks: PPONetworks, params: dict[str, Any], conditioner: Conditioner, deterministic: bool = False
) -> Callable[[Any, jax.Array], jax.Array]:
    """``act(state, rng) -> action`` (one env) of a trained goal-conditioned PPO policy.

    The policy reads ``conditioner.apply`` of an instruction drawn for the state's goal with a fixed key, so an
    episode's conditioning stays constant (for the oracle's ``GoalOneHotConditioner`` it is the goal's one-hot).
    """
    policy = make_inference_fn(networks)(params, deterministic)

    def act(state: Any, rng: jax.Array) -> jax.Array:
        instruction = conditioner.sample(jax.random.PRNGKey(0), goal_of(state), "train")
        return policy(state.obs, conditioner.apply(params["conditioner"], instruction), rng)

    return act


class _Roller:
    """Jitted rounds: reset ``num_envs`` envs, play ``episode_length`` steps with a behaviour, return the record."""

    def __init__(self, env: Any, behaviour: Callable[[Any, jax.Array], jax.Array]):
        self.env = EpisodeWrapper(env)
        self.act = jax.vmap(behaviour)
        # envs with a reduced collection action space (CLEVR's 'collect') record the full-space action id
        self.record_action = getattr(env, "push_action", lambda state, action: action)

    def round(self, rng: jax.Array, num_envs: int) -> dict[str, jax.Array]:
        rng_reset, _, rng_act = jax.random.split(rng, 3)
        state = jax.vmap(self.env.reset)(jax.random.split(rng_reset, num_envs))
        goal = goal_of(state)
        step_envs = jax.vmap(self.env.step)

        def one_step(state, rng_step):
            action = self.act(state, jax.random.split(rng_step, num_envs))
            next_state = step_envs(state, action)
            record = {
                "obs": state.obs,
                "action": jax.vmap(self.record_action)(state, action),
                "next_obs": next_state.obs,
                "done": next_state.done,
                "success": next_state.metrics["success"],
            }
            return next_state, record

        _, record = jax.lax.scan(one_step, state, jax.random.split(rng_act, self.env.episode_length))
        return {**record, "goal": goal}


def _goals_with_instructions(sampler: Any, num_goals: int) -> np.ndarray:
    """(num_goals,) bool: whether the sampler has a training instruction for each goal (others are skipped)."""
    keys = jax.random.split(jax.random.PRNGKey(0), num_goals)
    goals = jnp.arange(num_goals, dtype=jnp.int32)
    return np.asarray(jax.vmap(lambda key, goal: sampler.sample(key, goal, "train"))(keys, goals)) >= 0


class _KeptEpisodes:
    """The tuples kept from the rounds so far, episode by episode (the last one cut to reach ``num_tuples``), and
    the collection's counts."""

    def __init__(self, num_tuples: int, has_language: np.ndarray, successful_only: bool):
        self.num_tuples = num_tuples
        self.has_language = has_language
        self.successful_only = successful_only
        self.parts: dict[str, list[np.ndarray]] = {
            name: [] for name in ("states", "final_states", "actions", "goal_ids", "episode_ids")
        }
        self.kept, self.episodes, self.successes, self.rounds, self.kept_episodes = 0, 0, 0, 0, 0

    def check_rounds(self, max_rounds: int) -> None:
        """Gives up (raises) once ``max_rounds`` rounds have not given ``num_tuples`` tuples."""
        if self.rounds >= max_rounds:
            raise RuntimeError(
                f"only {self.kept} of {self.num_tuples} tuples after {self.rounds} rounds ({self.successes} successes)"
            )

    def add_round(self, record: dict[str, np.ndarray], num_envs: int) -> int:
        """Keeps the chosen episodes of one round's (T, E) ``record`` until ``num_tuples``; returns the tuples added."""
        self.rounds += 1
        done = np.asarray(record["done"]) > 0.5  # (T, E)
        ended = done.any(axis=0)
        end = np.argmax(done, axis=0)
        succeeded = ended & (np.asarray(record["success"])[end, np.arange(num_envs)] > 0.5)
        self.successes += int(succeeded.sum())
        keep = succeeded if self.successful_only else ended
        added = 0
        for env_index in np.flatnonzero(keep & self.has_language[np.asarray(record["goal"])]):
            if self.kept >= self.num_tuples:
                break
            added += self._add_episode(record, env_index, end[env_index])
        self.episodes += num_envs
        return added

    def _add_episode(self, record: dict[str, np.ndarray], env_index: int, end: int) -> int:
        """Keeps env ``env_index``'s episode, which ended at step ``end``: each step's (s_i, a_i) with its s_T."""
        length = min(int(end) + 1, self.num_tuples - self.kept)
        final = record["next_obs"][end, env_index]
        self.parts["states"].append(record["obs"][:length, env_index])
        self.parts["actions"].append(record["action"][:length, env_index])
        self.parts["final_states"].append(np.broadcast_to(final, (length, final.shape[-1])))
        self.parts["goal_ids"].append(np.full(length, record["goal"][env_index], np.int32))
        self.parts["episode_ids"].append(np.full(length, self.kept_episodes, np.int32))
        self.kept_episodes += 1
        self.kept += length
        return length

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: np.concatenate(chunks) for name, chunks in self.parts.items()}

    def statistics(self, num_envs: int, seconds: float) -> dict[str, Any]:
        """The dataset's ``config["collection"]``."""
        return {
            "episodes": self.episodes,
            "successful_episodes": self.successes,
            "kept_episodes": self.kept_episodes,
            "goals_without_train_instructions": np.flatnonzero(~self.has_language).tolist(),
            "rounds": self.rounds,
            "success_rate": self.successes / max(self.episodes, 1),
            "seconds": seconds,
            "num_envs": num_envs,
            "kept": "successful episodes" if self.successful_only else "all episodes (hindsight s_T)",
        }


def _draw_train_instructions(sampler: Any, rng: jax.Array, goal_ids: np.ndarray) -> np.ndarray:
    """(N,) int32: a training instruction of each tuple's goal, one key per tuple split from ``rng``."""
    draw = jax.jit(jax.vmap(lambda key, goal: sampler.sample(key, goal, "train")))
    keys = jax.random.split(rng, len(goal_ids))
    return np.asarray(draw(keys, jnp.asarray(goal_ids)), np.int32)


def collect_task_dataset(
    env: Any,
    behaviour: Callable[[Any, jax.Array], jax.Array],
    num_tuples: int,
    rng: jax.Array,
    instruction_sampler: Any,
    *,
    num_envs: int = 256,
    max_rounds: int = 1000,
    progress: bool = False,
    config: dict[str, Any] | None = None,
    successful_only: bool = True,
) -> TaskDataset:
    """Rolls out a goal-conditioned behaviour and keeps the tuples of its successful episodes.

    Args:
        env: the unwrapped env (a time limit is added).
        behaviour: ``act(state, rng) -> action`` for one env: a scripted controller, or a trained policy
            (``policy_behaviour``); it reads the goal from the state.
        num_tuples: tuples to keep (the last episode is cut to reach exactly this many).
        rng: PRNG key.
        instruction_sampler: has ``sample(rng, goal, split)``; draws each tuple's L_N from the goal's training
            instructions (goals without one are skipped).
        num_envs: parallel episodes per round.
        max_rounds: give up (raise) after this many rounds.
        progress: show a tqdm bar over tuples.
        config: stored in the dataset (with the collection statistics added).
        successful_only: keep only successful episodes (the task dataset's meaning). ``False`` keeps every
            episode with its last state as s_T (hindsight), for smoke runs with an untrained policy.

    Returns:
        The ``TaskDataset``; ``config["collection"]`` has episodes, successes, rounds and seconds.
    """
    if num_tuples < 1:
        raise ValueError(f"num_tuples must be >= 1, got {num_tuples}")
    round_fn = jax.jit(_Roller(env, behaviour).round, static_argnums=1)
    start = time.perf_counter()
    collected = _KeptEpisodes(num_tuples, _goals_with_instructions(instruction_sampler, env.num_goals), successful_only)
    bar = tqdm(total=num_tuples, disable=not progress, unit="tuple", desc="collect")
    while collected.kept < num_tuples:
        collected.check_rounds(max_rounds)
        rng, rng_round = jax.random.split(rng)
        bar.update(collected.add_round(jax.device_get(round_fn(rng_round, num_envs)), num_envs))
    bar.close()
    arrays = collected.arrays()
    rng, rng_language = jax.random.split(rng)
    instruction_ids = _draw_train_instructions(instruction_sampler, rng_language, arrays["goal_ids"])
    collection = collected.statistics(num_envs, time.perf_counter() - start)
    return TaskDataset(
        states=arrays["states"].astype(np.float32),
        final_states=arrays["final_states"].astype(np.float32),
        actions=arrays["actions"],
        instruction_ids=instruction_ids,
        goal_ids=arrays["goal_ids"],
        episode_ids=arrays["episode_ids"],
        config={**(config or {}), "collection": collection},
    )
