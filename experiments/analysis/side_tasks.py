"""Does a kitchen IFP reach its goal directly, or by doing other sub-tasks on the way?

    python -m experiments.analysis.side_tasks RUN_DIR [--seeds 0 3] [--episodes 10] [--json OUT.json]

A kitchen episode (TALAR's protocol) ends when the named sub-task succeeds or after 280 steps, and nothing is lost by
completing other sub-tasks first. So a policy whose task language gives several sub-tasks one code can still succeed
on all of them by doing them in a fixed order, each episode stopping when the named one is done. For every seed this
groups the sub-tasks by the code most of their training instructions translate to, then runs ``--episodes``
stochastic episodes per sub-task on that code and prints the success rate, the mean episode length and the mean
number of other sub-tasks completed on the way (those not already done at reset). Needs a finished run with a
translator or an encoding layer (TALAR, Handcrafted, GLA, BERT-*; see ``talar_jax.agent``).
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np

from envs.kitchen.tasks import BONUS_THRESH, task_distances
from experiments.cli import ArgumentParser, check_outputs, command
from experiments.reports import load_agent
from talar_jax import runtime
from talar_jax.agent import AgentError, find_method_folder


def side_tasks(observations: np.ndarray, valid: np.ndarray, goals: np.ndarray) -> np.ndarray:
    """(E,) number of sub-tasks besides each episode's goal first satisfied during its valid steps.

    Args:
        observations: (E, T, obs) the observation of every step (the first is the reset's).
        valid: (E, T) True for the steps of the episode.
        goals: (E,) each episode's goal.
    """
    satisfied = np.asarray(task_distances(observations)) < BONUS_THRESH  # (E, T, tasks)
    done = (satisfied & valid[..., None]).any(1) & ~satisfied[:, 0]
    done[np.arange(len(goals)), goals] = False
    return done.sum(1)


def seed_report(run_dir: str, seed: int, episodes: int) -> dict:
    """Code groups and, per sub-task, success, episode length and side sub-tasks over ``episodes`` episodes."""
    agent = load_agent(run_dir, seed=seed)
    if agent.env_name != "kitchen":
        raise AgentError(f"{run_dir} is a {agent.env_name} run; this probe reads kitchen sub-tasks")
    names = agent.env.task_names
    codes = np.stack([agent.goal_code(goal) for goal in range(agent.env.num_goals)])
    groups: dict[tuple, list[str]] = {}
    for goal, code in enumerate(codes):
        groups.setdefault(tuple(np.round(code, 3)), []).append(names[goal])
    goals = np.repeat(np.arange(len(names)), episodes)
    observations, valid, success = agent.episodes(codes[goals], goals, jax.random.PRNGKey(seed))
    side = side_tasks(observations, valid, goals)
    per_task = {
        names[goal]: {
            "success": float(success[goals == goal].mean()),
            "episode_length": float(valid[goals == goal].sum(1).mean()),
            "side_tasks_per_episode": float(side[goals == goal].mean()),
        }
        for goal in range(len(names))
    }
    return {"seed": seed, "code_groups": list(groups.values()), "per_task": per_task}


def run_command(argv: list[str] | None = None) -> None:
    runtime.start()
    parser = ArgumentParser(prog="python -m experiments.analysis.side_tasks", description=__doc__)
    parser.add_argument("run_dir", help="a finished kitchen run folder (or its method folder)")
    parser.add_argument("--seeds", type=int, nargs="+", help="seeds to probe (default: all of the run's)")
    parser.add_argument("--episodes", type=int, default=10, help="episodes per sub-task and seed")
    parser.add_argument("--json", type=Path, help="also write the reports to this JSON file")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    check_outputs((args.json, "--json", "file"))
    config = json.loads((find_method_folder(args.run_dir, prefer="talar") / "config.json").read_text())
    seeds = args.seeds if args.seeds is not None else range(int(config["seeds"]))
    reports = [seed_report(args.run_dir, seed, args.episodes) for seed in seeds]
    for report in reports:
        print(f"seed {report['seed']}: sub-tasks sharing a code: {report['code_groups']}")
        for name, row in report["per_task"].items():
            print(
                f"  {name:14s} success {100 * row['success']:5.1f} %  length {row['episode_length']:5.1f}  "
                f"other sub-tasks done {row['side_tasks_per_episode']:.2f}"
            )
    if args.json:
        args.json.write_text(json.dumps({"run": args.run_dir, "episodes": args.episodes, "seeds": reports}, indent=1))


main = command(run_command, bad_input=(AgentError, ValueError))

if __name__ == "__main__":
    raise SystemExit(main())
