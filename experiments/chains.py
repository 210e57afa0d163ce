"""Chains of sub-tasks scored as CALVIN scores them: success at 1/L ... L/L and the average length, per seed.

``python -m experiments.chains kitchen|clevr|RUN [--chains 1000] [--length 4] [--seed S ...] [--json OUT]``

RUN is a shipped agent's name or a finished run folder. Each chain is L distinct goals in random order, each clause a
held-out test phrasing of its goal given on its own. ``--clauses sentence`` says the chain as one sentence instead:
test phrasings (or held-out verb phrases) joined by held-out connectives (``talar_jax.language.compound``), which the
agent splits with its clause parser and judges (``Agent.plans``); a chain it does not act on counts as nothing done.
The agent runs the whole chain in one episode
with no reset (``talar_jax.chains``): clause k's code until sub-task k holds, then clause k+1's, each clause with
the single-task step budget, the chain ending at its first failed clause. Whether a sub-task holds is told by the
env's success test (what the scores count) and, for agents that carry their task-language generator, by the task
language too (the generator's code of the change since the clause began equals the clause's code): the scores of
chains moved on by that test, and how often the two tests agree, are printed beside the first. In the kitchen the
chain of all six sub-tasks (the paper's long-horizon task) is measured too, ``--all-chains`` times.

``--json OUT`` writes ``{"length", "chains", "success_at", "average_length"}`` (the first seed's, env test) with
every seed's numbers under ``"seeds"`` and the six-task chain under ``"all_goals"``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from experiments.cli import POSITIONAL, UsageError, check_outputs, write_output
from experiments.reports import agent_command, load_agent
from talar_jax.agent import Agent
from talar_jax.chains import ADVANCE_ON, ChainResult, run_chains
from talar_jax.language.compound import compound_sentences

CLAUSE_MODES = ("sentence", "separate")
TRANSITION_GOALS = 10
"""Envs with at most this many goals (the kitchen's six sub-tasks, not CLEVR's 80) get the table of clauses reached by
the sub-task before and their own."""


@dataclasses.dataclass(frozen=True)
class ChainsArgs:
    run_dir: Path = dataclasses.field(metadata=POSITIONAL)
    """A shipped agent's name (kitchen, clevr) or a finished run folder."""
    chains: int = 1000
    """Chains per seed."""
    length: int = 4
    """Clauses per chain (distinct goals; at most the env's number of goals with test phrasings)."""
    seed: tuple[int, ...] = (0,)
    """The run's seeds to measure (one row each)."""
    clauses: str = "separate"
    """How a chain is said: 'separate' (each clause given on its own, translated directly: the policy alone) or
    'sentence' (one compound sentence of held-out phrasings and connectives, split by the agent's clause parser,
    ``Agent.plans``; a chain the agent does not act on, or parses into other goals, fails where it goes wrong)."""
    all_chains: int = 1000
    """Kitchen only: chains of all six sub-tasks, in random order, per seed (0: none)."""
    budget: int | None = None
    """Steps each clause may take (default: the env's single-task episode length: kitchen 280, CLEVR 50)."""
    rng_seed: int = 0
    """Seed of the chains' goals, phrasings, resets and actions."""
    deterministic: bool = False
    """Act by the policy's mode instead of sampling (the experiments evaluate sampled actions)."""
    json: Path | None = None
    """Also write the numbers here."""


def check_args(args: ChainsArgs) -> None:
    """The checks that need no loading, so that a command line that cannot succeed loads and runs nothing."""
    if args.chains < 1:
        raise UsageError(f"--chains must be >= 1, got {args.chains}")
    if args.length < 1:
        raise UsageError(f"--length must be >= 1, got {args.length}")
    if not args.seed:
        raise UsageError("--seed needs at least one seed")
    if args.all_chains < 0:
        raise UsageError(f"--all-chains must be >= 0, got {args.all_chains}")
    if args.clauses not in CLAUSE_MODES:
        raise UsageError(f"--clauses must be one of {', '.join(CLAUSE_MODES)}, got {args.clauses!r}")
    if args.budget is not None and args.budget < 1:
        raise UsageError(f"--budget must be >= 1, got {args.budget}")
    check_outputs((args.json, "--json", "file"))


def test_phrasings(agent: Agent) -> dict[int, list[str]]:
    """goal id -> the held-out test phrasings of that goal (the language cache's test split)."""
    cache = agent.cache
    phrasings: dict[int, list[str]] = {}
    for row in np.flatnonzero(~np.asarray(cache.is_train)):
        phrasings.setdefault(int(cache.goal_ids[row]), []).append(cache.sentences[row])
    return phrasings


def sample_chains(
    phrasings: dict[int, list[str]], chains: int, length: int, rng: np.random.Generator
) -> tuple[np.ndarray, list[list[str]]]:
    """(goals (N, L), sentences N x L): L distinct goals per chain in random order, each a random phrasing of its
    goal."""
    goal_ids = np.array(sorted(phrasings))
    goals = np.stack([rng.permutation(goal_ids)[:length] for _ in range(chains)]).astype(np.int32)
    sentences = [[phrasings[int(g)][rng.integers(len(phrasings[int(g)]))] for g in row] for row in goals]
    return goals, sentences


def clause_codes(agent: Agent, sentences: list[list[str]]) -> np.ndarray:
    """(N, L, code_size) the code each clause is followed by when each clause is given on its own: each translated
    alone (``Agent.translate``), each distinct sentence once."""
    distinct = sorted({sentence for chain in sentences for sentence in chain})
    codes = dict(zip(distinct, agent.translate(distinct), strict=True))
    return np.stack([np.stack([codes[sentence] for sentence in chain]) for chain in sentences])


def parsed_codes(agent: Agent, sentences: list[str], goals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The agent's reading of one compound sentence per chain (``Agent.plans``): (N, L, code_size) the code of each
    clause it parsed (a chain parsed into fewer clauses follows its last one to the end), (N,) whether it acts on
    the sentence and (N,) whether its clauses name the chain's goals in the chain's order."""
    plans = agent.plans(sentences)
    length = goals.shape[1]
    texts = [[step.sentence for step in plan.steps][:length] for plan in plans]
    texts = [row + [row[-1]] * (length - len(row)) for row in texts]
    acted = np.array([plan.acts for plan in plans])
    right = np.array([plan.goals == tuple(int(g) for g in row) for plan, row in zip(plans, goals, strict=True)])
    return clause_codes(agent, texts), acted, right


def chain_inputs(agent: Agent, goals: np.ndarray, phrasings: list[list[str]], args: ChainsArgs, seed: int):
    """(codes (N, L, code_size), acted (N,), parsing record or None) of the chains, as ``--clauses`` says them."""
    if args.clauses == "separate":
        return clause_codes(agent, phrasings), np.ones(len(goals), bool), None
    said = compound_sentences(agent.env_name, goals, held_out=True, seed=seed)
    codes, acted, right = parsed_codes(agent, [s.text for s in said], goals)
    parsing = {"sentences": len(said), "acted": float(acted.mean()), "right_goals_in_order": float(right.mean())}
    parsing["examples"] = [s.text for s in said[:3]]
    print(
        f"parsed: {len(said)} compound sentences; acted on {100 * parsing['acted']:.1f} %, right goals in the right "
        f'order {100 * parsing["right_goals_in_order"]:.1f} % (e.g. "{said[0].text}")'
    )
    return codes, acted, parsing


def measure(
    agent: Agent, goals: np.ndarray, codes: np.ndarray, key: jax.Array, args: ChainsArgs, acted: np.ndarray
) -> tuple[dict[str, ChainResult], dict[str, float]]:
    """The chains moved on by the env's test and, when the agent has its TL generator, by the task language (the
    same goals, resets and action keys), with the seconds each took (compile included). A chain the agent did not
    act on (``acted`` False) counts as none of its clauses done."""
    results, seconds = {}, {}
    for test in ADVANCE_ON:
        start = time.perf_counter()
        result = run_chains(agent, codes, goals, key, test, args.budget, args.deterministic)
        seconds[test] = time.perf_counter() - start
        refused = ~np.asarray(acted)[:, None]
        results[test] = dataclasses.replace(
            result,
            reached_step=np.where(refused, -1, result.reached_step),
            env_step=np.where(refused, -1, result.env_step),
            language_step=np.where(refused, -1, result.language_step),
        )
        if not results[test].language_available:
            break
    return results, seconds


def record(measured: tuple[dict[str, ChainResult], dict[str, float]], num_goals: int) -> dict[str, Any]:
    """JSON of one seed's chains: the env test's CALVIN numbers, the TL test's and the two tests' agreement, and
    for envs of at most ``TRANSITION_GOALS`` goals the clauses begun and reached by the goal before and their own."""
    results, seconds = measured
    env = results["env"]
    out: dict[str, Any] = {**env.summary(), "budget": env.budget, "seconds": seconds}
    if num_goals <= TRANSITION_GOALS:
        begun, reached = env.transitions(num_goals)
        out["transitions"] = {"begun": begun.tolist(), "reached": reached.tolist()}
    if "language" in results:
        language = results["language"]
        out["language"] = {
            **language.summary(),
            "env_confirmed_success_at": language.confirmed_success_at,
            "env_confirmed_average_length": float(np.mean(language.confirmed)),
            "agreement": language.agreement(),
        }
        out["agreement"] = env.agreement()
    else:
        out["language"] = None
    return out


def table(rows: list[tuple[str, dict[str, Any]]], length: int) -> str:
    """Markdown table: one row per (seed, test), success at 1..L and the average length."""
    head = "| seed | test | " + " | ".join(f"{i}/{length}" for i in range(1, length + 1)) + " | average length |"
    lines = [head, "|" + "---|" * (length + 3)]
    for seed, numbers in rows:
        tests = [("env", numbers["success_at"], numbers["average_length"])]
        if numbers["language"]:
            language = numbers["language"]
            tests.append(("task language", language["success_at"], language["average_length"]))
            confirmed = (language["env_confirmed_success_at"], language["env_confirmed_average_length"])
            tests.append(("task language, env-confirmed", *confirmed))
        for name, rates, average in tests:
            shown = " | ".join(f"{100 * rate:.1f} %" for rate in rates)
            lines.append(f"| {seed} | {name} | {shown} | {average:.3f} |")
    return "\n".join(lines)


def transition_table(numbers: dict[str, Any], names: tuple[str, ...]) -> str:
    """Markdown table: the share of begun clauses reached, by the sub-task before (rows; "(reset)": a chain's first
    clause) and the clause's own (columns), in the chains moved on by the env's test."""
    begun, reached = (np.asarray(numbers["transitions"][k]) for k in ("begun", "reached"))
    names = names[: begun.shape[1]]
    lines = ["| before \\ then | " + " | ".join(names) + " |", "|" + "---|" * (len(names) + 1)]
    for row, before in enumerate([*names, "(reset)"]):
        cells = [f"{100 * r / b:.0f} % of {b}" if b else "-" for b, r in zip(begun[row], reached[row], strict=True)]
        lines.append(f"| {before} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def agreement_line(numbers: dict[str, Any]) -> str:
    agreement = numbers.get("agreement")
    if agreement is None:
        return "task-language test: unavailable (the agent carries no TL generator)"
    return (
        f"tests agree on {100 * agreement['reached']:.1f} % of {agreement['clauses']} begun clauses (same step "
        f"{100 * agreement['same_step']:.1f} %; env saw {100 * agreement['env_done']:.1f} % done, task language "
        f"{100 * agreement['language_done']:.1f} %), in the chains moved on by the env's test"
    )


def chains(args: ChainsArgs) -> dict[str, Any]:
    """Runs the command; returns what ``--json`` holds."""
    check_args(args)
    agents = [load_agent(args.run_dir, seed=seed) for seed in args.seed]
    first = agents[0]
    phrasings = test_phrasings(first)
    if args.length > len(phrasings):
        raise UsageError(f"--length {args.length}: {first.env_name} has test phrasings of {len(phrasings)} goals")
    all_chains = args.all_chains if first.env_name == "kitchen" else 0
    print(f"run: {first.folder} ({first.method}, {first.env_name}); seeds {', '.join(map(str, args.seed))}")
    budget = args.budget if args.budget is not None else first.env.episode_length
    print(f"chains: {args.chains} of {args.length} distinct goals, test phrasings, {budget} steps per clause")
    rng = np.random.default_rng(args.rng_seed)
    goals, sentences = sample_chains(phrasings, args.chains, args.length, rng)
    everything = sample_chains(phrasings, all_chains, len(phrasings), rng) if all_chains else None
    per_seed, all_rows = [], []
    for agent in agents:
        key = jax.random.fold_in(jax.random.key(args.rng_seed), agent.seed)
        codes, acted, parsing = chain_inputs(agent, goals, sentences, args, args.rng_seed)
        numbers = record(measure(agent, goals, codes, key, args, acted), agent.env.num_goals)
        per_seed.append((agent.seed, {**numbers, "parsing": parsing}))
        if everything is not None:
            all_goals, all_sentences = everything
            codes, acted, parsing = chain_inputs(agent, all_goals, all_sentences, args, args.rng_seed + 1)
            numbers = record(
                measure(agent, all_goals, codes, jax.random.fold_in(key, 1), args, acted), agent.env.num_goals
            )
            all_rows.append((agent.seed, {**numbers, "parsing": parsing}))
    print(table(per_seed, args.length))
    for seed, numbers in per_seed:
        print(f"seed {seed}: {agreement_line(numbers)}")
    if first.env.num_goals <= TRANSITION_GOALS:
        for seed, numbers in per_seed:
            print(f"\nseed {seed}: clauses reached, by the sub-task before and the clause's own (env's test)")
            print(transition_table(numbers, first.env.goal_names))
    if all_rows:
        print(f"\nthe chain of all {len(phrasings)} sub-tasks, {all_chains} chains:")
        print(table(all_rows, len(phrasings)))
        for seed, numbers in all_rows:
            print(f"seed {seed}: {agreement_line(numbers)}")
    for seed, numbers in per_seed:
        spent = ", ".join(f"{seconds:.0f} s moved on by the {test}" for test, seconds in numbers["seconds"].items())
        print(f"time, seed {seed}: {args.chains} chains of {args.length}: {spent} (compile included)")
    out = {
        **{k: v for k, v in per_seed[0][1].items() if k in ("length", "chains", "success_at", "average_length")},
        "run": str(args.run_dir),
        "env": first.env_name,
        "budget": budget,
        "seeds": {str(seed): numbers for seed, numbers in per_seed},
        "all_goals": {str(seed): numbers for seed, numbers in all_rows} or None,
        "rng_seed": args.rng_seed,
    }
    if args.json is not None:
        write_output(args.json, json.dumps(out, indent=2) + "\n")
        print(f"json: {args.json}")
    return out


run_command, main = agent_command(ChainsArgs, chains, __doc__)

if __name__ == "__main__":
    raise SystemExit(main())
