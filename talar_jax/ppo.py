"""End-to-end jitted PPO (PureJaxRL shape) shared by the oracle and every language-conditioned method.

``make_train(config, env, conditioner)`` returns a ``Learner``, whose methods are pure functions of one seed:
``init(rng)``, ``chunk(state)`` (a ``lax.scan`` over ``updates_per_chunk`` updates: rollout, reward normalisation,
GAE, epochs x minibatches), ``evaluate(params, rng, split)`` and ``train(rng)`` (all chunks in one program).
``run_ppo`` vmaps them over seeds, jits them, and runs the host loop: progress bar, evaluation on the train/test
instruction splits, JSON-lines logging, orbax checkpoints after each chunk and resume from the latest one. Discrete
or continuous actions are chosen by the env's action spec (``networks.make_distribution``), nothing else.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm.auto import tqdm

from envs.runtime import program_compiler_options
from talar_jax.acting import ConditionedEnv, evaluate_episodes, generate_unroll
from talar_jax.checkpoint import Checkpointer, write_json_atomic
from talar_jax.conditioning import SPLITS, Conditioner, check_split
from talar_jax.logging import JsonLinesLogger, Logger, MultiLogger, NoOpLogger
from talar_jax.losses import compute_gae, compute_ppo_loss, init_return_normalizer, normalize_rollout_rewards
from talar_jax.networks import (
    OBS_NORMALIZER,
    init_observation_stats,
    make_inference_fn,
    make_ppo_networks,
    network_inputs,
    update_observation_stats,
)
from talar_jax.permutation import shuffled_order
from talar_jax.sharding import shard_seeds
from talar_jax.types import TrainingState


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters. The class defaults are the paper's Table 2 where it gives them (SB3 otherwise); the
    experiment commands start from their env recipe's values."""

    num_envs: int = 64
    """Parallel environments per seed."""
    rollout_length: int = 64
    """Env steps per environment per update."""
    total_env_steps: int = 2_000_000
    """Env steps per seed (rounded up to whole chunks)."""
    num_epochs: int = 10
    """Passes over each rollout (Table 2)."""
    minibatch_size: int = 128
    """Transitions per gradient step (Table 2)."""
    learning_rate: float = 3e-4
    """Adam step size (Table 2)."""
    gamma: float = 0.99
    """Discount."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    clip_eps: float = 0.2
    """Probability-ratio clip range."""
    ent_coef: float = 0.0
    """Entropy bonus weight (SB3 default 0)."""
    vf_coef: float = 0.5
    """Value loss weight."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip."""
    hidden_sizes: tuple[int, ...] = (32, 64, 64)
    """Hidden layers of both the policy and the value MLP (tanh; Table 2)."""
    normalize_rewards: bool = True
    """Divide rewards by the running std of the discounted return (SB3 VecNormalize, rewards only)."""
    reward_clip: float = 10.0
    """Clip of the normalised reward."""
    normalize_advantages: bool = True
    """Normalise advantages per minibatch."""
    normalize_observations: bool = False
    """Feed the networks observations standardised by running mean/std statistics (SB3 ``VecNormalize``'s
    observation part, Brax's ``normalize_observations``); the statistics live in ``params["obs_normalizer"]``,
    get no gradient, and are updated after each update's SGD with that update's rollout. TALAR's original
    normalised rewards only (the default)."""
    num_seeds: int = 1
    """Independent seeds, vmapped in one compiled program."""
    seed: int = 0
    """Base seed; seed i of the run uses split(PRNGKey(seed), num_seeds)[i]."""
    updates_per_chunk: int = 10
    """Updates per jitted chunk (host work - eval, logging, checkpoints - happens between chunks)."""
    eval_every_chunks: int = 1
    """Evaluate every this many chunks (and after the last one)."""
    eval_episodes: int = 160
    """Parallel evaluation episodes per seed and split (the learning curve's evaluations)."""
    final_eval_episodes: int = 0
    """Episodes per seed and split of the evaluation after the last chunk, the one a run reports (0: as
    ``eval_episodes``). A dense final evaluation with sparse curve evaluations keeps evaluation a small part of a
    run; evaluation keys never touch training's, so the trained parameters do not depend on either."""
    eval_deterministic: bool = True
    """Evaluate the policy's mode (True) or samples (False)."""

    def __post_init__(self):
        positive = (
            "num_envs",
            "rollout_length",
            "total_env_steps",
            "num_epochs",
            "minibatch_size",
            "num_seeds",
            "updates_per_chunk",
            "eval_every_chunks",
            "eval_episodes",
        )
        for name in positive:
            if getattr(self, name) < 1:
                raise ValueError(f"PPOConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.final_eval_episodes < 0:
            raise ValueError(f"PPOConfig.final_eval_episodes must be >= 0, got {self.final_eval_episodes}")
        if (self.num_envs * self.rollout_length) % self.minibatch_size:
            raise ValueError(
                f"num_envs * rollout_length ({self.num_envs * self.rollout_length}) must be a multiple of "
                f"minibatch_size ({self.minibatch_size})"
            )
        object.__setattr__(self, "hidden_sizes", tuple(int(size) for size in self.hidden_sizes))


class PPODerived(NamedTuple):
    """Sizes derived from a ``PPOConfig`` (never stored back into it)."""

    env_steps_per_update: int
    """Env steps of one seed's update: the rows of the flat rollout its epochs learn on."""
    num_minibatches: int
    env_steps_per_chunk: int
    num_chunks: int
    num_updates: int
    total_env_steps: int


def derive(config: PPOConfig) -> PPODerived:
    """Batch and loop sizes of a config; total env steps round up to whole chunks."""
    per_update = config.num_envs * config.rollout_length
    per_chunk = per_update * config.updates_per_chunk
    num_chunks = max(1, math.ceil(config.total_env_steps / per_chunk))
    return PPODerived(
        env_steps_per_update=per_update,
        num_minibatches=per_update // config.minibatch_size,
        env_steps_per_chunk=per_chunk,
        num_chunks=num_chunks,
        num_updates=num_chunks * config.updates_per_chunk,
        total_env_steps=num_chunks * per_chunk,
    )


class Minibatch(NamedTuple):
    """Flat (B, ...) learner inputs."""

    obs: jax.Array
    instruction: jax.Array
    action: jax.Array
    log_prob: jax.Array
    advantages: jax.Array
    returns: jax.Array


class Learner:
    """PPO for one seed: holds the constants of a run, and every method is a pure function of its arguments (vmap
    ``init``, ``chunk``, ``evaluate``, ``learn`` or ``train`` over seeds, then jit)."""

    def __init__(self, config: PPOConfig, env: Any, conditioner: Conditioner):
        self.config = config
        self.sizes = derive(config)
        self.conditioner = conditioner
        self.env = ConditionedEnv(env, conditioner, "train")
        self.eval_envs = {split: ConditionedEnv(env, conditioner, split) for split in SPLITS}
        self.networks = make_ppo_networks(env.observation_size, conditioner.size, env.action_spec, config.hidden_sizes)
        self.distribution = self.networks.distribution
        self.make_policy = make_inference_fn(self.networks)
        self.optimizer = optax.chain(
            optax.clip_by_global_norm(config.max_grad_norm), optax.adam(config.learning_rate, eps=1e-5)
        )
        # XLA options for compiling ``chunk`` and ``evaluate`` (``Lowered.compile(compiler_options=...)``): the env's
        # physics decides (``envs.runtime.program_compiler_options``); one that does not name its physics may step MJX.
        steps_mjx = getattr(getattr(env, "unwrapped", env), "backend", None) != "c"
        self.compiler_options = program_compiler_options(steps_mjx)

    # --- network application -------------------------------------------------------------------
    def _inputs(self, params: dict[str, Any], obs: jax.Array, instruction: jax.Array) -> jax.Array:
        cond = self.conditioner.apply_batch(params["conditioner"], instruction)
        return network_inputs(params, obs, cond)

    def _acting(self, params: dict[str, Any]) -> dict[str, Any]:
        """``params`` with the conditioner's acting form (``Conditioner.freeze``): fixed during a rollout."""
        return {**params, "conditioner": self.conditioner.freeze(params["conditioner"])}

    def policy_step(self, params: dict[str, Any], obs: jax.Array, instruction: jax.Array, rng: jax.Array):
        """Batched acting: (action, log_prob, value) for (N, obs) observations."""
        inputs = self._inputs(params, obs, instruction)
        dist_params = self.networks.policy.apply(params["policy"], inputs)
        action = self.distribution.sample(rng, dist_params)
        value = self.networks.value.apply(params["value"], inputs)
        return action, self.distribution.log_prob(dist_params, action), value

    def _loss(self, params: dict[str, Any], batch: Minibatch) -> tuple[jax.Array, dict[str, jax.Array]]:
        inputs = self._inputs(params, batch.obs, batch.instruction)
        dist_params = self.networks.policy.apply(params["policy"], inputs)
        c = self.config
        return compute_ppo_loss(
            log_prob=self.distribution.log_prob(dist_params, batch.action),
            old_log_prob=batch.log_prob,
            advantages=batch.advantages,
            values=self.networks.value.apply(params["value"], inputs),
            returns=batch.returns,
            entropy=self.distribution.entropy(dist_params),
            clip_eps=c.clip_eps,
            vf_coef=c.vf_coef,
            ent_coef=c.ent_coef,
            normalize_advantages=c.normalize_advantages,
        )

    # --- the update ----------------------------------------------------------------------------
    def init(self, rng: jax.Array) -> TrainingState:
        rng, rng_policy, rng_conditioner, rng_env = jax.random.split(rng, 4)
        params = {**self.networks.init(rng_policy), "conditioner": self.conditioner.init(rng_conditioner)}
        if self.config.normalize_observations:
            params[OBS_NORMALIZER] = init_observation_stats(self.networks.observation_size)
        env_carry = jax.vmap(self.env.reset)(jax.random.split(rng_env, self.config.num_envs))
        return TrainingState(
            params=params,
            opt_state=self.optimizer.init(self._trainable(params)),
            normalizer=init_return_normalizer(self.config.num_envs),
            env=env_carry,
            rng=rng,
            env_steps=jnp.zeros((), jnp.int32),
            updates=jnp.zeros((), jnp.int32),
        )

    def _trainable(self, params: dict[str, Any]) -> dict[str, Any]:
        """The parameters PPO optimises: all but observation statistics and a frozen conditioner's."""
        frozen = {OBS_NORMALIZER} | (set() if self.conditioner.trainable else {"conditioner"})
        return {k: v for k, v in params.items() if k not in frozen}

    def _minibatch_step(self, carry: tuple[Any, Any], batch: Minibatch):
        params, opt_state = carry
        trainable = self._trainable(params)

        def loss(trainable):
            return self._loss({**params, **trainable}, batch)

        (_, metrics), grads = jax.value_and_grad(loss, has_aux=True)(trainable)
        updates, opt_state = self.optimizer.update(grads, opt_state, trainable)
        metrics["losses/grad_norm"] = optax.global_norm(grads)
        return ({**params, **optax.apply_updates(trainable, updates)}, opt_state), metrics

    def _epoch(self, batch: Minibatch, carry: tuple[Any, Any], rng: jax.Array):
        order = shuffled_order(rng, self.sizes.env_steps_per_update)
        shape = (self.sizes.num_minibatches, self.config.minibatch_size)
        minibatches = jax.tree.map(lambda x: x[order].reshape(shape + x.shape[1:]), batch)
        return jax.lax.scan(self._minibatch_step, carry, minibatches)

    def learn(self, params: dict[str, Any], opt_state: Any, batch: Minibatch, rng: jax.Array):
        """An update's SGD alone: ``num_epochs`` passes of minibatch SGD over a flat rollout ``batch``, each in a
        fresh random order; returns ``(params, opt_state, loss metrics)`` (what ``chunk`` runs after each rollout;
        benchmarks time it apart)."""
        epoch = functools.partial(self._epoch, batch)
        (params, opt_state), metrics = jax.lax.scan(
            epoch, (params, opt_state), jax.random.split(rng, self.config.num_epochs)
        )
        return params, opt_state, metrics

    def update(self, state: TrainingState, _: Any = None) -> tuple[TrainingState, dict[str, jax.Array]]:
        """One PPO update: rollout, normalised rewards, GAE, ``num_epochs`` x minibatch SGD."""
        c = self.config
        rng, rng_unroll, rng_sgd = jax.random.split(state.rng, 3)
        policy_step = functools.partial(self.policy_step, self._acting(state.params))
        env_carry, traj = generate_unroll(self.env, state.env, policy_step, rng_unroll, c.rollout_length)
        _, _, bootstrap = policy_step(env_carry.state.obs, env_carry.instruction, rng)
        normalizer, rewards = state.normalizer, traj.reward
        if c.normalize_rewards:
            normalizer, rewards = normalize_rollout_rewards(
                normalizer, rewards, traj.episode_done, c.gamma, c.reward_clip
            )
        advantages, returns = compute_gae(
            rewards, traj.value, bootstrap, traj.termination, traj.truncation, c.gamma, c.gae_lambda
        )
        batch = Minibatch(traj.obs, traj.instruction, traj.action, traj.log_prob, advantages, returns)
        batch = jax.tree.map(lambda x: x.reshape((self.sizes.env_steps_per_update,) + x.shape[2:]), batch)
        params, opt_state, loss_metrics = self.learn(state.params, state.opt_state, batch, rng_sgd)
        if c.normalize_observations:  # the rollout was acted and learned on with the old statistics
            params = {**params, OBS_NORMALIZER: update_observation_stats(params[OBS_NORMALIZER], traj.obs)}
        metrics = {key: jnp.mean(value) for key, value in loss_metrics.items()}
        if "log_std" in params["policy"]["params"]:
            metrics["policy/std"] = jnp.mean(jnp.exp(params["policy"]["params"]["log_std"]))
        metrics |= {
            "train/episodes": jnp.sum(traj.episode_done),
            "train/successes": jnp.sum(traj.episode_done * traj.success),
            "train/return_sum": jnp.sum(traj.episode_return),
            "train/reward_std": jnp.sqrt(normalizer.var),
        }
        new_state = TrainingState(
            params=params,
            opt_state=opt_state,
            normalizer=normalizer,
            env=env_carry,
            rng=rng,
            env_steps=state.env_steps + self.sizes.env_steps_per_update,
            updates=state.updates + 1,
        )
        return new_state, metrics

    def chunk(self, state: TrainingState) -> tuple[TrainingState, dict[str, jax.Array]]:
        """``updates_per_chunk`` updates under ``lax.scan``; metrics have a leading (updates_per_chunk,) axis."""
        return jax.lax.scan(self.update, state, None, length=self.config.updates_per_chunk)

    def evaluate(
        self, params: dict[str, Any], rng: jax.Array, split: str = "train", num_episodes: int | None = None
    ) -> dict[str, jax.Array]:
        """``num_episodes`` (default ``eval_episodes``) fresh episodes with instructions from ``split`` (see
        ``evaluate_episodes``)."""
        policy = self.make_policy(params, self.config.eval_deterministic)
        conditioner_params = self.conditioner.freeze(params["conditioner"])

        def act(obs: jax.Array, instruction: jax.Array, rng_act: jax.Array) -> jax.Array:
            cond = self.conditioner.apply_batch(conditioner_params, instruction)
            return policy(obs, cond, rng_act)

        episodes = self.config.eval_episodes if num_episodes is None else num_episodes
        return evaluate_episodes(self.eval_envs[check_split(split)], act, rng, episodes)

    def train(self, rng: jax.Array) -> tuple[TrainingState, dict[str, jax.Array]]:
        """The whole run in one program (no host work): metrics (num_chunks, updates_per_chunk)."""
        return jax.lax.scan(lambda state, _: self.chunk(state), self.init(rng), None, length=self.sizes.num_chunks)


def make_train(config: PPOConfig, env: Any, conditioner: Conditioner) -> Learner:
    """The per-seed PPO ``Learner`` of an (unwrapped) env and a conditioner."""
    return Learner(config, env, conditioner)


# ------------------------------------------------------------------------------------------------
# Host loop
# ------------------------------------------------------------------------------------------------
@dataclasses.dataclass
class PPOResult:
    """What ``run_ppo`` returns. Arrays carry a leading (num_seeds,) axis."""

    state: TrainingState
    history: list[dict[str, Any]]
    """Every chunk's row of metrics (as ``metrics.jsonl`` holds them), of the chunks this call ran."""
    last_eval: dict[str, dict[str, Any]]
    """The run's last evaluation, split -> ``summarize_eval``: after the last chunk (``final_eval_episodes``), or
    the one that reached the target when the run stopped there."""
    env_steps: int
    wall_s: float
    target_reached: dict[str, float] | None
    learner: Learner

    @property
    def params(self) -> dict[str, Any]:
        return self.state.params


def summarize_eval(record: dict[str, np.ndarray], num_goals: int) -> dict[str, Any]:
    """Success over seeds and per goal; episodes whose goal has no instruction in the split are left out.

    Args:
        record: ``evaluate`` output with (num_seeds, E) arrays.
        num_goals: number of goal ids.
    """
    valid = np.asarray(record["instruction"]) >= 0
    success = np.asarray(record["success"], np.float64) * valid
    goal = np.asarray(record["goal"])
    counts = np.bincount(goal[valid], minlength=num_goals).astype(np.float64)
    per_goal = np.bincount(goal[valid], weights=success[valid], minlength=num_goals) / np.maximum(counts, 1)
    return {
        "success": float(success.sum() / max(valid.sum(), 1)),
        "success_per_seed": (success.sum(1) / np.maximum(valid.sum(1), 1)).tolist(),
        "success_per_goal": [float(v) if n else None for v, n in zip(per_goal, counts, strict=True)],
        "success_per_seed_goal": _success_per_seed_goal(success, goal, valid, num_goals),
        "episode_return": float(np.mean(record["episode_return"])),
        "episode_return_per_seed": np.mean(np.asarray(record["episode_return"], np.float64), axis=1).tolist(),
        "episode_length": float(np.mean(record["episode_length"])),
    }


def _success_per_seed_goal(
    success: np.ndarray, goal: np.ndarray, valid: np.ndarray, num_goals: int
) -> list[list[float | None]]:
    """(num_seeds, num_goals) success of each seed on each goal (None where a seed had no such episode): the
    table that shows one seed failing one goal, which the per-seed and per-goal margins average away."""
    table = []
    for seed_success, seed_goal, seed_valid in zip(success, goal, valid, strict=True):
        counts = np.bincount(seed_goal[seed_valid], minlength=num_goals)
        sums = np.bincount(seed_goal[seed_valid], weights=seed_success[seed_valid], minlength=num_goals)
        table.append([float(v / n) if n else None for v, n in zip(sums, counts, strict=True)])
    return table


def _chunk_metrics(metrics: dict[str, np.ndarray]) -> dict[str, Any]:
    """Per-update metrics (num_seeds, updates_per_chunk) -> chunk means over seeds and updates."""
    out = {key: float(np.mean(value)) for key, value in metrics.items() if key.startswith(("losses/", "policy/"))}
    episodes = float(np.sum(metrics["train/episodes"]))
    out["train/episodes"] = episodes
    out["train/success"] = float(np.sum(metrics["train/successes"]) / max(episodes, 1.0))
    out["train/episode_return"] = float(np.sum(metrics["train/return_sum"]) / max(episodes, 1.0))
    out["train/reward_std"] = float(np.mean(metrics["train/reward_std"]))
    return out


def initial_state(learner: Learner, initial_params: dict[str, Any] | None = None) -> TrainingState:
    """Fresh seed-stacked training states (``num_seeds`` leading axis, sharded over devices), with
    ``initial_params`` (same structure, by key) replacing the freshly initialised parameters."""
    config = learner.config
    seed_keys = jax.random.split(jax.random.PRNGKey(config.seed), config.num_seeds)
    state = jax.jit(jax.vmap(learner.init))(seed_keys)
    if initial_params:
        params = dict(state.params)
        for name, value in initial_params.items():
            if name not in params or jax.tree.structure(value) != jax.tree.structure(params[name]):
                raise ValueError(f"initial_params[{name!r}] must match the structure of params[{name!r}]")
            params[name] = jax.tree.map(jnp.asarray, value)
        state = state.replace(params=params)
    return shard_seeds(state, config.num_seeds)


@dataclasses.dataclass(frozen=True)
class Progress:
    """How far a run has got: what ``progress.json`` holds beside each checkpoint, and what a resumed run starts
    from."""

    chunks: int = 0
    """Chunks trained."""
    wall_s: float = 0.0
    """Seconds spent in those chunks (compilation and evaluation left out)."""
    target_reached: dict[str, float] | None = None
    """The first evaluation whose success reached ``target_success``: its ``env_steps``, ``wall_s`` and
    ``success`` (None: not reached, or no target)."""


class RunFiles:
    """A run folder: orbax checkpoints after each chunk, ``progress.json`` and ``metrics.jsonl``; resume from it."""

    def __init__(self, out_dir: str | Path, config: PPOConfig):
        self.checkpointer = Checkpointer(out_dir, config)
        self.progress_path = Path(out_dir) / "progress.json"
        self.logger = JsonLinesLogger(Path(out_dir) / "metrics.jsonl")

    def restore(self, state: TrainingState) -> tuple[TrainingState, Progress]:
        """The latest checkpoint's state and progress, or ``(state, Progress())`` when the folder has none."""
        latest = self.checkpointer.latest_step()
        if latest is None:
            return state, Progress()
        saved = json.loads(self.progress_path.read_text()) if self.progress_path.exists() else {}
        progress = Progress(latest, float(saved.get("wall_s", 0.0)), saved.get("target_reached"))
        return self.checkpointer.restore(latest, state), progress

    def save(self, state: TrainingState, progress: Progress) -> None:
        self.checkpointer.save(progress.chunks, state)
        write_json_atomic(self.progress_path, dataclasses.asdict(progress))

    def close(self) -> None:
        self.checkpointer.close()


def make_evaluator(
    learner: Learner, splits: Sequence[str], num_goals: int, params: dict[str, Any]
) -> Callable[..., dict[str, dict[str, Any]]]:
    """``evaluate(seed_params, index, final=False) -> split -> summarize_eval(...)``: fresh episodes per split
    (``eval_episodes``, or ``final_eval_episodes`` when ``final``), keys from ``config.seed`` and ``index`` (so a
    resumed run evaluates exactly as an uninterrupted one). The curve's programs are compiled here for seed-stacked
    ``params`` of this structure, so an evaluation's wall-clock is its episodes; the final one's on first use."""
    config = learner.config
    eval_root = jax.random.PRNGKey(config.seed + 1_000_003)
    keys = jax.random.split(eval_root, config.num_seeds)

    def compile_programs(num_episodes: int) -> dict[str, Any]:
        return {
            split: jax.jit(jax.vmap(functools.partial(learner.evaluate, split=split, num_episodes=num_episodes)))
            .lower(params, keys)
            .compile(compiler_options=learner.compiler_options)
            for split in splits
        }

    programs = {config.eval_episodes: compile_programs(config.eval_episodes)}

    def evaluate(params: dict[str, Any], index: int, final: bool = False) -> dict[str, dict[str, Any]]:
        episodes = (config.final_eval_episodes or config.eval_episodes) if final else config.eval_episodes
        if episodes not in programs:
            programs[episodes] = compile_programs(episodes)
        keys = jax.random.split(jax.random.fold_in(eval_root, index), config.num_seeds)
        records = {split: jax.device_get(fn(params, keys)) for split, fn in programs[episodes].items()}
        return {split: summarize_eval(record, num_goals) for split, record in records.items()}

    return evaluate


def run_ppo(
    config: PPOConfig,
    env: Any,
    conditioner: Conditioner,
    out_dir: str | Path | None = None,
    *,
    progress: bool = True,
    logger: Logger | None = None,
    eval_splits: Sequence[str] = SPLITS,
    target_success: float | None = None,
    stop_at_target: bool = False,
    initial_params: dict[str, Any] | None = None,
) -> PPOResult:
    """Trains ``config.num_seeds`` seeds in one compiled program, chunk by chunk, with host work between chunks.

    Args:
        config: PPO config.
        env: the unwrapped env (time limit and auto-reset are added here).
        conditioner: instruction sampler and conditioning vector.
        out_dir: where ``config.json``, ``checkpoints/``, ``metrics.jsonl`` and ``progress.json`` go; a run
            found there is resumed from its latest checkpoint (``None``: no checkpoints, no resume).
        progress: show a tqdm bar.
        logger: receives every chunk's metrics (in addition to ``metrics.jsonl``).
        eval_splits: instruction splits to evaluate on.
        target_success: record the env steps and wall-clock at which evaluation success (training instructions,
            else the first split) first reaches this.
        stop_at_target: stop training once the target is reached.
        initial_params: seed-stacked parameters replacing freshly initialised ones, by key ("policy", "value",
            "conditioner"; same structure), e.g. one frozen instruction table per seed or behaviour-cloned
            policy weights. The optimiser state starts fresh.

    Returns:
        ``PPOResult``; ``history`` holds the metrics of the chunks run by this call.
    """
    for split in eval_splits:
        check_split(split)
    learner = make_train(config, env, conditioner)
    sizes = learner.sizes
    run_files = RunFiles(out_dir, config) if out_dir is not None else None
    state, start = initial_state(learner, initial_params), Progress()
    if run_files is not None:
        state, start = run_files.restore(state)
    log = MultiLogger(logger or NoOpLogger(), *([run_files.logger] if run_files is not None else []))

    compile_start = time.perf_counter()
    chunk = jax.jit(jax.vmap(learner.chunk)).lower(state).compile(compiler_options=learner.compiler_options)
    evaluate = make_evaluator(learner, eval_splits, env.num_goals, state.params)
    compile_s = time.perf_counter() - compile_start

    history: list[dict[str, Any]] = []
    last_eval: dict[str, dict[str, Any]] = {}
    wall_s, target_reached = start.wall_s, start.target_reached
    bar = tqdm(total=sizes.num_chunks, initial=start.chunks, disable=not progress, unit="chunk", desc="ppo")
    for chunk_index in range(start.chunks, sizes.num_chunks):
        if stop_at_target and target_reached is not None:
            break
        chunk_start = time.perf_counter()
        state, metrics = chunk(state)
        metrics = jax.device_get(metrics)
        chunk_s = time.perf_counter() - chunk_start
        wall_s += chunk_s
        row = {
            "train/env_steps": (chunk_index + 1) * sizes.env_steps_per_chunk,
            "train/sps": sizes.env_steps_per_chunk * config.num_seeds / chunk_s,
            "train/chunk_s": chunk_s,
            "train/wall_s": wall_s,
            **_chunk_metrics(metrics),
        }
        if chunk_index == start.chunks:
            row["train/compile_s"] = compile_s

        last = chunk_index == sizes.num_chunks - 1
        if eval_splits and ((chunk_index + 1) % config.eval_every_chunks == 0 or last):
            eval_start = time.perf_counter()
            last_eval = evaluate(state.params, chunk_index, final=last)
            row["eval/seconds"] = time.perf_counter() - eval_start
            for split, summary in last_eval.items():
                row |= {f"eval/{split}/{key}": value for key, value in summary.items()}
            success = last_eval.get("train", next(iter(last_eval.values())))["success"]
            if target_success is not None and target_reached is None and success >= target_success:
                target_reached = {"env_steps": row["train/env_steps"], "wall_s": wall_s, "success": success}

        if run_files is not None:
            run_files.save(state, Progress(chunk_index + 1, wall_s, target_reached))
        history.append(row)
        log.write(chunk_index + 1, row)
        bar.update(1)
        shown = ("eval/train/success", "train/success")
        bar.set_postfix({key: f"{row[key]:.3g}" for key in shown if key in row})
    bar.close()

    if not last_eval and eval_splits:  # a resumed run that had finished (or stopped at its target) before
        last_eval = evaluate(state.params, sizes.num_chunks, final=True)
    if run_files is not None:
        run_files.close()
    log.close()
    return PPOResult(
        state=state,
        history=history,
        last_eval=last_eval,
        env_steps=int(np.max(jax.device_get(state.env_steps))),
        wall_s=wall_s,
        target_reached=target_reached,
        learner=learner,
    )
