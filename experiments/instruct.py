"""Give a trained agent a sentence: see its task language, the goal it decodes to, its success, and a video.

``python -m experiments.instruct RUN_DIR "Open the microwave door" [--seed K] [--episodes N] [--goal G]
[--video out.gif|out.mp4]``

RUN_DIR is a finished ``experiments.clevr`` / ``experiments.kitchen`` run (``runs/kitchen`` or its method folder).
The success is measured on the goal the sentence means: ``--goal`` (an id, or a kitchen sub-task name) when given,
otherwise the goal the sentence's code decodes to (the goal most training instructions with that code have), and
the output says which. The video shows the first episode (needs an OpenGL backend, see ``envs.render``; without
one the evaluation still runs and says that no video was written).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import Annotated

import jax
import numpy as np
import tyro

from experiments.cli import output_path_problem, parse_or_exit
from experiments.recipes import get_recipe
from experiments.reports import load_agent
from talar_jax import runtime
from talar_jax.agent import Agent, AgentError


@dataclasses.dataclass(frozen=True)
class InstructArgs:
    run_dir: Annotated[Path, tyro.conf.Positional]
    """A finished run folder (``runs/kitchen``, or a method folder such as ``runs/kitchen/talar``)."""
    sentence: Annotated[str, tyro.conf.Positional]
    """The instruction, in any words."""
    seed: int = 0
    """Which of the run's seeds acts."""
    episodes: int = 20
    """Episodes to measure success on (vmapped in one call)."""
    goal: str | None = None
    """The goal the sentence means: a goal id, or a kitchen sub-task name (default: the decoded goal)."""
    video: Path | None = None
    """Write the first episode as a .gif or .mp4."""
    deterministic: bool = False
    """Act by the policy's mode instead of sampling (the experiments evaluate sampled actions)."""
    rng_seed: int = 0
    """Seed of the episodes' randomness."""


def format_code(agent: Agent, code: np.ndarray) -> str:
    """A TL as ``predicates | argument 1 | argument 2 ...`` (other codes as plain numbers)."""
    values = [f"{v:g}" for v in np.round(code, 3)]
    if agent.method != "talar":
        return " ".join(values)
    spec = agent.config["talar"]["spec"]
    npn, size = spec["num_predicates"], spec["arg_size"]
    parts = [" ".join(values[:npn])] + [
        " ".join(values[npn + i * size : npn + (i + 1) * size]) for i in range(spec["num_arguments"])
    ]
    return " | ".join(parts)


def parse_goal(goal: str | None, names: list[str]) -> int | None:
    """A goal id from an id or a goal name (None stays None)."""
    if goal is None:
        return None
    if goal.strip().lstrip("-").isdigit():
        value = int(goal)
        if not 0 <= value < len(names):
            raise AgentError(f"--goal must lie in 0..{len(names) - 1}, got {value}")
        return value
    lowered = [name.lower() for name in names]
    if goal.strip().lower() in lowered:
        return lowered.index(goal.strip().lower())
    raise AgentError(f"unknown goal {goal!r}; give an id in 0..{len(names) - 1} or a name such as {names[0]!r}")


def check_args(args: InstructArgs) -> None:
    """The checks that need no loading (one ``AgentError`` per bad input)."""
    if not args.sentence.strip():
        raise AgentError("the sentence is empty")
    if args.episodes < 1:
        raise AgentError(f"--episodes must be >= 1, got {args.episodes}")
    if args.video is not None and args.video.suffix not in (".gif", ".mp4"):
        raise AgentError(f"--video must end in .gif or .mp4, got {args.video}")
    if args.video is not None and output_path_problem(args.video, "file"):
        raise AgentError(f"--video: {output_path_problem(args.video, 'file')}")


def instruct(args: InstructArgs) -> dict:
    """Loads the agent, translates the sentence, runs the episodes and writes the video; returns what it printed."""
    check_args(args)
    start = time.perf_counter()
    agent = load_agent(args.run_dir, seed=args.seed)
    names = get_recipe(agent.env_name).goal_names()
    goal = parse_goal(args.goal, names)
    loaded = time.perf_counter()
    code = agent.translate(args.sentence)[0]
    decoded = agent.nearest_goal(code)
    translated = time.perf_counter()
    print(f"run: {agent.folder} ({agent.method}, {agent.env_name}, seed {agent.seed})")
    print(f'sentence: "{args.sentence}"')
    print(f"code: {format_code(agent, code)}")
    if decoded is None:
        print("decodes to: no goal (no training instruction has this code)")
    else:
        print(f"decodes to: goal {decoded} ({names[decoded]}), the goal most training instructions with this code have")
    scored = goal if goal is not None else decoded
    result = {"code": code.tolist(), "decoded_goal": decoded, "goal": scored}
    if scored is None:
        print("success: not measured: give the goal the sentence means with --goal")
        return result
    how = "given with --goal" if goal is not None else "decoded from the sentence"
    rng = jax.random.key(args.rng_seed)
    goals = np.full(args.episodes, scored, np.int32)
    success = agent.success_rate(np.broadcast_to(code, (args.episodes, code.size)), goals, rng, args.deterministic)
    episodes_done = time.perf_counter()
    rate = float(success.mean())
    print(
        f"success: {int(success.sum())}/{args.episodes} episodes ({100 * rate:.1f} %) on goal {scored} "
        f"({names[scored]}, {how})"
    )
    result.update(success=rate)
    if args.video is not None:
        first_key = jax.random.split(rng, args.episodes)[0]  # the key success_rate gave its first episode
        episode = agent.rollout(args.sentence, first_key, scored, args.deterministic)
        try:
            from envs.render import RenderError, caption, write_video

            frames = caption(agent.env.render(episode.qpos[: episode.length + 1]), args.sentence)
            frames += [frames[-1]] * 5  # linger on the last frame
            write_video(frames, args.video, fps=5.0 if agent.env_name.startswith("clevr") else 12.5)
            outcome = "success" if episode.success else "no success"
            print(f"video: {args.video} (the first episode, {episode.length} steps, {outcome})")
            result["video"] = str(args.video)
        except RenderError as error:
            print(f"video: not written ({error})")
    print(
        f"time: load {loaded - start:.1f} s, translate {translated - loaded:.2f} s, "
        f"{args.episodes} episodes {episodes_done - translated:.1f} s (compile included)"
    )
    return result


def agent_command(cls, function, argv: list[str] | None, description: str | None):
    """Parses ``cls`` and calls ``function``; an ``AgentError`` prints one ``error:`` line and exits with status 2."""
    args = parse_or_exit(cls, argv, description=description)
    try:
        return function(args)
    except AgentError as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from None


def main(argv: list[str] | None = None) -> dict:
    runtime.start()
    return agent_command(InstructArgs, instruct, argv, __doc__)


if __name__ == "__main__":
    main()
