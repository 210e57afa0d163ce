"""Records the arm postures in which a kitchen policy ends each sub-task in chains, for the env's
``start_arm='ended'`` option: ``python -m experiments.ended_postures kitchen [--chains 600] [--per-task 64]``.

A policy trained from the scripted controller's posture at a sub-task's success (``start='after_subtask'``) meets, in
a chain, the posture in which it ended the sub-task itself, which can lie a radian or more away per joint: the 7-DoF
arm reaches a handle in many ways. This runs the agent's chains of distinct sub-tasks in random order (each clause the
code of its goal's training instructions, the env's success test moving the chain on), keeps the arm's 9 joint
positions at each step at which a sub-task held, and writes ``--per-task`` of them per sub-task, drawn without
replacement, with where they came from, to ``--out`` (default: the file the env reads).
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
from pathlib import Path

import jax
import numpy as np

from experiments.cli import POSITIONAL, checked, command, parse
from experiments.reports import load_agent
from talar_jax import runtime
from talar_jax.chains import chain_endings

ARM_JOINTS = 9


@dataclasses.dataclass(frozen=True)
class EndedPosturesArgs:
    run_dir: Path = dataclasses.field(metadata=POSITIONAL)
    """A shipped kitchen agent's name or a finished kitchen run folder."""
    seed: int = 0
    """The run's seed whose policy runs the chains."""
    chains: int = 600
    """Chains run."""
    length: int = 4
    """Sub-tasks per chain."""
    per_task: int = 64
    """Postures kept per sub-task."""
    rng_seed: int = 0
    """Draws the chains, their resets and actions, and the postures kept."""
    out: Path | None = None
    """Output file (default: envs/kitchen/ended_postures.npz, which ``start_arm`` reads)."""


def check(args: EndedPosturesArgs) -> EndedPosturesArgs:
    if args.chains < 1 or args.per_task < 1:
        raise ValueError("--chains and --per-task must be >= 1")
    if not 1 <= args.length <= 6:
        raise ValueError(f"--length must lie in 1..6 (the kitchen's sub-tasks), got {args.length}")
    return args


def record(args: EndedPosturesArgs) -> tuple[Path, np.ndarray]:
    """Runs the chains and writes the file; returns its path and the (sub-tasks,) count of endings found."""
    from envs.kitchen.env import ENDED_POSTURES_FILE

    agent = load_agent(args.run_dir, seed=args.seed)
    if agent.env_name != "kitchen":
        raise ValueError(f"ended postures are a kitchen start; {args.run_dir} is a {agent.env_name} agent")
    num_goals = agent.env.num_goals
    rng = np.random.default_rng(args.rng_seed)
    goals = np.stack([rng.permutation(num_goals)[: args.length] for _ in range(args.chains)]).astype(np.int32)
    goal_codes = np.stack([agent.goal_code(goal) for goal in range(num_goals)])
    print(f"running {args.chains} chains of {args.length} ...", flush=True)
    reached, qpos = chain_endings(agent, goal_codes[goals], goals, jax.random.key(args.rng_seed))
    postures = np.zeros((num_goals, args.per_task, ARM_JOINTS), np.float32)
    found = np.zeros(num_goals, np.int64)
    for goal in range(num_goals):
        ends = qpos[:, :, :ARM_JOINTS][(goals == goal) & (reached >= 0)]
        found[goal] = len(ends)
        if len(ends) < args.per_task:
            raise RuntimeError(f"only {len(ends)} chains ended sub-task {goal}; run more --chains")
        postures[goal] = ends[rng.choice(len(ends), args.per_task, replace=False)]
    out = args.out or ENDED_POSTURES_FILE
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip() or None
    source = {
        "agent": str(args.run_dir),
        "seed": args.seed,
        "chains": args.chains,
        "length": args.length,
        "rng_seed": args.rng_seed,
        "commit": commit,
        "endings_found": found.tolist(),
        "command": "python -m experiments.ended_postures "
        f"{args.run_dir} --chains {args.chains} --length {args.length} --per-task {args.per_task}",
    }
    np.savez_compressed(out, postures=postures, source=np.array(json.dumps(source)))
    return out, found


def run_command(argv: list[str] | None = None) -> Path:
    runtime.start()
    args = checked(check, parse(EndedPosturesArgs, argv, description=__doc__))
    out, found = record(args)
    print(f"wrote {out}: {args.per_task} postures per sub-task, from {found.tolist()} endings")
    return out


main = command(run_command)

if __name__ == "__main__":
    raise SystemExit(main())
