"""Chains of sub-tasks in one episode: the policy follows clause k's code until sub-task k holds, then clause k+1's.

This is how CALVIN scores long-horizon instruction following (Mees et al. 2022): a chain of L instructions runs in
one episode with no reset between them, each instruction gets the single-task step budget (``env.episode_length``),
and the chain stops at its first failed instruction. ``run_chains(agent, codes, goals, rng)`` runs N chains at once
(vmapped, one compiled program per chain length and mode) and returns a ``ChainResult``.

Whether sub-task k holds is known two ways, recorded side by side for every clause:

- ``env_step``: the env's own success test of goal k (``state.metrics["success"]`` after ``env.retarget`` gave the
  running episode goal k): an oracle the agent does not have outside a simulator;
- ``language_step``: the task language itself, the inside-out way: the TL generator's code of the change since the
  clause began, g(s_clause_start, s_now), equals the clause's code, with the agent's own entries of s_now
  (``env.agent_observation_size``: the kitchen's arm) held at the clause's start, so that the code reads what the
  scene did, not where the arm went. This needs no oracle, only the generator the translator was trained against
  (``Agent.task_language``); agents without one record -1 throughout (``ChainResult.language_available`` False).

``advance_on`` picks which of the two moves the chain on to the next clause; the other is only watched. The step
numbers count the env steps from the start of the chain (the first step is 1); -1: not reached.

``chain_episode(agent, codes, goals, key)`` runs one chain the same way and keeps its physics positions and the clause
each step followed: what a video of the chain shows.
"""

from __future__ import annotations

import dataclasses
import weakref
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

ADVANCE_ON: tuple[str, ...] = ("env", "language")
"""What tells a chain that its current sub-task holds: the env's success test or the task language."""


@dataclasses.dataclass(frozen=True)
class ChainResult:
    """What N chains of L clauses did (arrays over chains and clauses).

    Attributes:
        goals: (N, L) the goal of each clause.
        reached_step: (N, L) the step at which the chain moved on from each clause (by ``advance_on``'s test), -1
            for the failed clause and the clauses after it.
        env_step: (N, L) the first step of each clause's time at which the env's success test held, -1 if never.
        language_step: (N, L) the same for the task-language test (all -1 when ``language_available`` is False).
        advance_on: "env" or "language".
        language_available: whether the agent has a TL generator (``Agent.generator_params``).
        budget: the steps each clause may take.
    """

    goals: np.ndarray
    reached_step: np.ndarray
    env_step: np.ndarray
    language_step: np.ndarray
    advance_on: str
    language_available: bool
    budget: int

    @property
    def chains(self) -> int:
        return int(self.goals.shape[0])

    @property
    def length(self) -> int:
        return int(self.goals.shape[1])

    @property
    def completed(self) -> np.ndarray:
        """(N,) clauses completed in a row (the chain stops at its first failure, so the reached ones lead)."""
        return (self.reached_step >= 0).sum(axis=1)

    @property
    def success_at(self) -> list[float]:
        """The share of chains completing at least 1, 2, ..., L clauses in a row (CALVIN's success rates)."""
        return [float(np.mean(self.completed >= i)) for i in range(1, self.length + 1)]

    @property
    def average_length(self) -> float:
        """The average number of clauses completed in a row (CALVIN's average length)."""
        return float(np.mean(self.completed))

    @property
    def confirmed(self) -> np.ndarray:
        """(N,) clauses completed in a row whose sub-task the env's test also saw done during the clause: the
        truth of chains moved on by the task language (equal to ``completed`` when the env's test moves them)."""
        confirmed = (self.reached_step >= 0) & (self.env_step >= 0)
        return np.cumprod(confirmed, axis=1).sum(axis=1)

    @property
    def confirmed_success_at(self) -> list[float]:
        """``success_at`` of ``confirmed``."""
        return [float(np.mean(self.confirmed >= i)) for i in range(1, self.length + 1)]

    @property
    def attempted(self) -> np.ndarray:
        """(N, L) whether each clause was begun (the first one, and each one after a reached clause)."""
        reached = self.reached_step >= 0
        return np.concatenate([np.ones_like(reached[:, :1]), reached[:, :-1]], axis=1)

    def transitions(self, num_goals: int) -> tuple[np.ndarray, np.ndarray]:
        """(begun, reached): (num_goals + 1, num_goals) counts of begun clauses and of those reached, by the goal of
        the clause before (row num_goals: a chain's first clause, from the reset state) and the clause's own goal:
        which sub-task a policy fails to do after which."""
        begun = np.zeros((num_goals + 1, num_goals), np.int64)
        reached = np.zeros_like(begun)
        before = np.concatenate([np.full_like(self.goals[:, :1], num_goals), self.goals[:, :-1]], axis=1)
        mask = self.attempted
        np.add.at(begun, (before[mask], self.goals[mask]), 1)
        np.add.at(reached, (before[mask], self.goals[mask]), (self.reached_step >= 0)[mask].astype(np.int64))
        return begun, reached

    def agreement(self) -> dict[str, float] | None:
        """How often the two tests tell the same about the begun clauses: ``reached`` (both saw the sub-task done
        during the clause's time, or neither did), ``same_step`` (both first saw it at the same step, or neither
        did), and the share of begun clauses each test saw done. None without a TL generator."""
        if not self.language_available:
            return None
        begun = self.attempted
        env_done, language_done = self.env_step >= 0, self.language_step >= 0
        return {
            "clauses": int(begun.sum()),
            "reached": float(np.mean((env_done == language_done)[begun])),
            "same_step": float(np.mean((self.env_step == self.language_step)[begun])),
            "env_done": float(np.mean(env_done[begun])),
            "language_done": float(np.mean(language_done[begun])),
        }

    def summary(self) -> dict[str, Any]:
        """The CALVIN numbers as JSON: ``length``, ``chains``, ``success_at``, ``average_length``."""
        return {
            "length": self.length,
            "chains": self.chains,
            "success_at": self.success_at,
            "average_length": self.average_length,
        }


def _chain_fn(
    agent: Any, length: int, budget: int, advance_on: str, deterministic: bool, language: bool, trajectory: bool = False
):
    """``chain(key, codes (L, C), goals (L,)) -> (reached_step, env_step, language_step)``, each (L,) int32; with
    ``trajectory`` also ``(qpos (L * budget + 1, nq), clause (L * budget,), valid (L * budget,))``: the physics
    positions from the reset on, the clause each step followed and whether the chain was still running."""
    env = agent.env
    obs_size = env.state_observation_size

    agent_size = env.agent_observation_size

    def holds_by_language(start: jax.Array, now: jax.Array, code: jax.Array) -> jax.Array:
        if not language:
            return jnp.bool_(False)
        # The generator reads the scene's change, with the agent's own entries (the arm) held at the clause's start:
        # it was trained on (s_i, s_T) of successful episodes, all of which end with the hand at the object, so it
        # learnt the arm's posture as a cue and named a sub-task as soon as the arm set off towards it (a scripted
        # microwave episode had the microwave's code from step 2, the env's success at step 160; arm held: step 108)
        now = now.at[:agent_size].set(start[:agent_size])
        return jnp.all(jnp.abs(agent.task_language(start, now) - code) < 0.5)

    def chain(key: jax.Array, codes: jax.Array, goals: jax.Array):
        rng_reset, rng_steps = jax.random.split(key)
        state = env.reset(rng_reset, goals[0])
        never = jnp.full((length,), -1, jnp.int32)
        zero = jnp.int32(0)
        carry = (state, state.obs[:obs_size], zero, zero, zero, jnp.bool_(False), rng_steps, never, never, never)

        def running(carry) -> jax.Array:
            clause, failed = carry[2], carry[5]
            return (clause < length) & ~failed

        def step(carry):
            state, start, clause, used, total, failed, rng, reached, by_env, by_language = carry
            rng, rng_action = jax.random.split(rng)
            code = codes[clause]
            action = agent.act(state.obs, code, rng_action, deterministic)
            stepped = env.step(state, action)
            used, total = used + 1, total + 1
            now = stepped.obs[:obs_size]
            env_holds = stepped.metrics["success"] > 0.5
            language_holds = holds_by_language(start, now, code)
            by_env = by_env.at[clause].set(jnp.where(env_holds & (by_env[clause] < 0), total, by_env[clause]))
            by_language = by_language.at[clause].set(
                jnp.where(language_holds & (by_language[clause] < 0), total, by_language[clause])
            )
            holds = env_holds if advance_on == "env" else language_holds
            reached = reached.at[clause].set(jnp.where(holds, total, -1))
            failed = ~holds & (used >= budget)
            following = clause + holds.astype(jnp.int32)
            # the next clause's goal from the state the last one left: no reset, the physics goes on as it is
            retargeted = env.retarget(stepped, goals[jnp.minimum(following, length - 1)])
            move_on = holds & (following < length)
            state = jax.tree.map(lambda new, old: jnp.where(move_on, new, old), retargeted, stepped)
            start = jnp.where(holds, now, start)
            used = jnp.where(holds, 0, used)
            return state, start, following, used, total, failed, rng, reached, by_env, by_language

        if not trajectory:  # stop as soon as the chain ends (under vmap: as soon as every chain has)
            carry = jax.lax.while_loop(running, step, carry)
            return carry[7], carry[8], carry[9]

        def guarded(carry, _):  # every one of the L x budget steps, frozen once the chain has ended
            active, clause = running(carry), carry[2]  # the clause whose code this step follows
            stepped = step(carry)
            carry = jax.tree.map(lambda new, old: jnp.where(active, new, old), stepped, carry)
            return carry, (carry[0].data.qpos, clause, active)

        final, (qpos, clause, valid) = jax.lax.scan(guarded, carry, None, length * budget)
        return (final[7], final[8], final[9]), (jnp.concatenate([state.data.qpos[None], qpos]), clause, valid)

    return chain


_COMPILED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""agent -> {(length, budget, advance_on, deterministic, language): compiled vmapped chains}, dropped with the agent."""


@dataclasses.dataclass(frozen=True)
class ChainEpisode:
    """One chain's episode, for showing it (``chain_episode``).

    Attributes:
        result: its ``ChainResult`` (one chain).
        qpos: (T + 1, nq) physics positions from the reset on (``env.render`` draws them); T = L x budget, the steps
            after the chain ended repeat its last state.
        clause: (T,) the clause whose code each step followed.
        valid: (T,) True for the steps of the chain (before and at its end).
    """

    result: ChainResult
    qpos: np.ndarray
    clause: np.ndarray
    valid: np.ndarray

    @property
    def length(self) -> int:
        """Steps the chain took."""
        return int(self.valid.sum())


def _checked(
    agent: Any, codes: np.ndarray, goals: np.ndarray, advance_on: str, budget: int | None
) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """(codes, goals, budget, language available) checked for ``run_chains`` (a ``ValueError`` naming the problem)."""
    if advance_on not in ADVANCE_ON:
        raise ValueError(f"advance_on must be one of {', '.join(ADVANCE_ON)}, got {advance_on!r}")
    codes = np.asarray(codes, np.float32)
    goals = np.asarray(goals, np.int32)
    if codes.ndim != 3 or goals.ndim != 2 or codes.shape[:2] != goals.shape:
        raise ValueError(f"codes (N, L, code_size) and goals (N, L) must agree, got {codes.shape} and {goals.shape}")
    if codes.shape[2] != agent.code_size:
        raise ValueError(f"codes have {codes.shape[2]} entries, the agent's have {agent.code_size}")
    if goals.size and (goals.min() < 0 or goals.max() >= agent.env.num_goals):
        raise ValueError(f"goals must lie in 0..{agent.env.num_goals - 1}")
    budget = int(agent.env.episode_length if budget is None else budget)
    if budget < 1:
        raise ValueError(f"budget must be >= 1, got {budget}")
    language = agent.generator_params is not None and not agent.continuous_codes
    if advance_on == "language" and not language:
        raise ValueError("advance_on='language' needs the agent's TL generator, and this agent has none")
    return codes, goals, budget, language


def run_chains(
    agent: Any,
    codes: np.ndarray,
    goals: np.ndarray,
    rng: jax.Array,
    advance_on: str = "env",
    budget: int | None = None,
    deterministic: bool = False,
) -> ChainResult:
    """Runs one chain per row of ``codes`` (N, L, code_size) and ``goals`` (N, L), all vmapped in one call.

    Each chain is one episode of ``agent.env`` reset into goal ``goals[:, 0]``; when clause k's sub-task holds (by
    ``advance_on``'s test) the episode goes on with ``env.retarget`` to goal k+1 and clause k+1's code. Each clause
    may take ``budget`` steps (default: ``env.episode_length``, the single-task budget); a clause that runs out ends
    its chain. ``rng`` draws the resets and the sampled actions (``deterministic``: the policy's mode instead).
    """
    codes, goals, budget, language = _checked(agent, codes, goals, advance_on, budget)
    length = int(goals.shape[1])
    compiled = _COMPILED.setdefault(agent, {})
    key = (length, budget, advance_on, deterministic, language)
    if key not in compiled:  # one compiled program per agent and chain shape, reused call after call
        compiled[key] = jax.jit(jax.vmap(_chain_fn(agent, length, budget, advance_on, deterministic, language)))
    keys = jax.random.split(rng, len(goals))
    reached, by_env, by_language = jax.device_get(compiled[key](keys, jnp.asarray(codes), jnp.asarray(goals)))
    return ChainResult(
        goals=goals,
        reached_step=np.asarray(reached),
        env_step=np.asarray(by_env),
        language_step=np.asarray(by_language),
        advance_on=advance_on,
        language_available=language,
        budget=budget,
    )


def chain_episode(
    agent: Any,
    codes: np.ndarray,
    goals: np.ndarray,
    key: jax.Array,
    advance_on: str = "env",
    budget: int | None = None,
    deterministic: bool = False,
) -> ChainEpisode:
    """One chain (``codes`` (L, code_size), ``goals`` (L,)) as ``run_chains`` runs it with this chain's ``key`` (row i
    of ``run_chains`` uses ``jax.random.split(rng, N)[i]``), with its physics positions and the clause of each step:
    what a video of the chain shows. It always takes L x budget steps (the ones after the chain ended are padding)."""
    codes, goals, budget, language = _checked(
        agent, np.asarray(codes)[None], np.asarray(goals)[None], advance_on, budget
    )
    length = int(goals.shape[1])
    chain = _chain_fn(agent, length, budget, advance_on, deterministic, language, trajectory=True)
    compiled = _COMPILED.setdefault(agent, {})
    cache_key = ("episode", length, budget, advance_on, deterministic, language)
    if cache_key not in compiled:
        compiled[cache_key] = jax.jit(chain)
    steps, (qpos, clause, valid) = jax.device_get(
        compiled[cache_key](key, jnp.asarray(codes[0]), jnp.asarray(goals[0]))
    )
    result = ChainResult(goals, *(np.asarray(x)[None] for x in steps), advance_on, language, budget)
    return ChainEpisode(result, np.asarray(qpos), np.asarray(clause), np.asarray(valid))


def chain_endings(
    agent: Any,
    codes: np.ndarray,
    goals: np.ndarray,
    rng: jax.Array,
    budget: int | None = None,
    deterministic: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The chains ``run_chains`` runs (env test), with the physics positions at which each clause's sub-task held:
    ``(reached_step (N, L), qpos (N, L, nq))``, qpos undefined where ``reached_step`` is -1. What a start drawn from a
    policy's own endings is built from (``experiments.ended_postures``)."""
    codes, goals, budget, language = _checked(agent, codes, goals, "env", budget)
    length = int(goals.shape[1])
    chain = _chain_fn(agent, length, budget, "env", deterministic, False, trajectory=True)

    def ending(key, chain_codes, chain_goals):
        (reached, _, _), (qpos, _, _) = chain(key, chain_codes, chain_goals)
        return reached, qpos[jnp.maximum(reached, 0)]  # qpos[t]: after t steps, the step at which the clause held

    keys = jax.random.split(rng, len(goals))
    reached, qpos = jax.device_get(jax.jit(jax.vmap(ending))(keys, jnp.asarray(codes), jnp.asarray(goals)))
    return np.asarray(reached), np.asarray(qpos)
