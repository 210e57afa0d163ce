"""Give a trained agent a sentence: see its task language, the goal it decodes to, how sure it is, its success, and a
video.

``python -m experiments.instruct RUN_DIR "Open the microwave door" [--seed K] [--episodes N] [--goal G]
[--video out.gif|out.mp4] [--act-anyway] [--json OUT]``; ``python -m experiments.instruct RUN_DIR`` (no sentence)
reads sentences from stdin, one per line, and answers each with the agent loaded and compiled once (an empty line
gets one error line; the session ends at end of input).

RUN_DIR is a finished ``experiments.clevr`` / ``experiments.kitchen`` run (``runs/kitchen`` or its method folder).
Every sentence gets a verdict (``talar_jax.confidence``, calibrated by the run's ``confidence.json``, see
``experiments.calibrate``): the agent acts only on a sentence it understood; on an ambiguous or not understood one
it says why in one line, with the likeliest goals, and runs no episode, unless ``--act-anyway``. The success is
measured on the goal the sentence means: ``--goal`` (an id, or a kitchen sub-task name) when given, otherwise the
goal the sentence's code decodes to (the goal most training instructions with that code have), and the output says
which. The video shows the first episode (needs an OpenGL backend, see ``envs.render``; without one the evaluation
still runs and says that no video was written). ``--json OUT`` writes, per sentence, its code, decoded goal,
confidence, verdict and candidates, and the success when it acted (one object; a list in the stdin mode).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import jax
import numpy as np

from experiments.cli import POSITIONAL, UsageError, check_outputs, print_error
from experiments.recipes import get_recipe
from experiments.reports import agent_command, load_agent
from talar_jax.agent import CONFIDENCE_FILE, Agent, AgentError
from talar_jax.chains import chain_episode, run_chains


@dataclasses.dataclass(frozen=True)
class InstructArgs:
    run_dir: Path = dataclasses.field(metadata=POSITIONAL)
    """A finished run folder (``runs/kitchen``, or a method folder such as ``runs/kitchen/talar``)."""
    sentence: str | None = dataclasses.field(default=None, metadata=POSITIONAL)
    """The instruction, in any words (none: read sentences from stdin, one per line)."""
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
    act_anyway: bool = False
    """Act on a sentence the agent is not sure about (ambiguous or not understood) all the same."""
    json: Path | None = None
    """Write each sentence's code, decoded goal, confidence, verdict, candidates and success here."""


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
    """The checks that need no loading (one ``UsageError`` per bad input), so nothing is loaded or run for a
    command line that cannot succeed."""
    if args.sentence is not None and not args.sentence.strip():
        raise UsageError("the sentence is empty")
    if args.sentence is None and args.video is not None:
        raise UsageError("--video needs a sentence on the command line (not sentences read from stdin)")
    if args.episodes < 1:
        raise UsageError(f"--episodes must be >= 1, got {args.episodes}")
    if args.video is not None and args.video.suffix not in (".gif", ".mp4"):
        raise UsageError(f"--video must end in .gif or .mp4, got {args.video}")
    check_outputs((args.video, "--video", "file"), (args.json, "--json", "file"))
    if args.video is not None and args.video.suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise UsageError(
            f"--video {args.video}: an .mp4 needs the ffmpeg program, not found on PATH; install it or write a .gif"
        )


def instruct(args: InstructArgs) -> dict | list[dict]:
    """Loads the agent and answers the sentence (or each sentence of stdin); returns what it printed as records."""
    check_args(args)
    start = time.perf_counter()
    agent = load_agent(args.run_dir, seed=args.seed)
    names = get_recipe(agent.env_name).goal_names()
    goal = parse_goal(args.goal, names)
    loaded = time.perf_counter()
    print(f"run: {agent.folder} ({agent.method}, {agent.env_name}, seed {agent.seed})")
    if not agent.calibrated:
        print(
            f"confidence: default calibration (no {CONFIDENCE_FILE} in {agent.folder}; "
            f"python -m experiments.calibrate {agent.folder} makes one)"
        )
    if args.sentence is not None:
        result = answer(agent, args, args.sentence, names, goal, loaded - start)
        write_json(args.json, result)
        return result
    results = []
    for sentence in read_sentences():
        if not sentence:
            print_error("the sentence is empty")
            continue
        try:
            results.append(answer(agent, args, sentence, names, goal, None))
        except AgentError as error:  # a sentence the encoder cannot read: one line, and the next sentence
            print_error(str(error))
            continue
        write_json(args.json, results)
        sys.stdout.flush()
    write_json(args.json, results)
    return results


def read_sentences() -> Iterator[str]:
    """The sentences of standard input, one per line (stripped) until its end; at a terminal each is asked for
    with a ``> `` prompt, and the end (Ctrl-D) ends the line the prompt began."""
    interactive = sys.stdin.isatty()
    while True:
        if interactive:
            print("> ", end="", flush=True)
        line = sys.stdin.readline()
        if not line:
            if interactive:
                print()
            return
        yield line.strip()


def write_json(path: Path | None, payload) -> None:
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(payload, indent=2) + "\n")


def answer(agent: Agent, args: InstructArgs, sentence: str, names: list[str], goal: int | None, load_s) -> dict:
    """Translates and judges one sentence, acts on it when the verdict (or ``--act-anyway``) says so; prints the
    lines and returns the record ``--json`` writes. A sentence the clause parser splits into several tasks is a
    chain (``answer_chain``)."""
    begun = time.perf_counter()
    plan = agent.plan(sentence)
    if len(plan.steps) > 1:
        return answer_chain(agent, args, plan, names, goal, load_s)
    code = agent.translate(sentence)[0]
    decoded = agent.nearest_goal(code)
    verdict = plan.steps[0]
    translated = time.perf_counter()
    print(f'sentence: "{sentence}"')
    print(f"code: {format_code(agent, code)}")
    if decoded is None:
        print("decodes to: no goal (no training instruction has this code)")
    else:
        print(f"decodes to: goal {decoded} ({names[decoded]}), the goal most training instructions with this code have")
    candidates = ", ".join(f"{names[g]} {score:.2f}" for g, score in verdict.candidates)
    print(f"confidence: {verdict.confidence:.2f} ({verdict.verdict}; candidates: {candidates})")
    judged = verdict.to_json(names)
    judged["understood_goal"], judged["understood_goal_name"] = judged.pop("goal"), judged.pop("goal_name")
    result = {**judged, "code": code.tolist(), "decoded_goal": decoded, "goal": goal if goal is not None else decoded}
    result.update(acted=False, plan=plan.to_json(names)["plan"])
    if not verdict.acts and not args.act_anyway:
        print(verdict.describe(names))
        return result
    if not verdict.acts:
        print(f"acting anyway (--act-anyway): the verdict was {verdict.verdict}")
    scored = goal if goal is not None else decoded
    if scored is None:
        print("success: not measured: give the goal the sentence means with --goal")
        return result
    how = "given with --goal" if goal is not None else "decoded from the sentence"
    rng = jax.random.key(args.rng_seed)
    goals = np.full(args.episodes, scored, np.int32)
    _, valid, success = agent.episodes(
        np.broadcast_to(code, (args.episodes, code.size)), goals, rng, args.deterministic
    )
    episodes_done = time.perf_counter()
    rate = float(success.mean())
    print(
        f"success: {int(success.sum())}/{args.episodes} episodes ({100 * rate:.1f} %) on goal {scored} "
        f"({names[scored]}, {how})"
    )
    result.update(acted=True, goal=scored, success=rate)
    result["plan"][0]["reached_step"] = int(valid[0].sum()) if success[0] else None  # the first episode's
    if args.video is not None:
        result.update(write_episode_video(agent, args, sentence, scored, jax.random.split(rng, args.episodes)[0]))
    loading = f"load {load_s:.1f} s, " if load_s is not None else ""
    print(
        f"time: {loading}translate {translated - begun:.2f} s, "
        f"{args.episodes} episodes {episodes_done - translated:.1f} s (compile included)"
    )
    return result


def answer_chain(agent: Agent, args: InstructArgs, plan, names: list[str], goal: int | None, load_s) -> dict:
    """A sentence that asks for several tasks: prints the plan (each clause, its code, goal and verdict); when the
    agent acts on every clause (or ``--act-anyway``), runs ``--episodes`` chains (``talar_jax.chains``: one episode,
    each clause until its sub-task holds, then the next) and prints the step at which the first chain reached each
    sub-task and how many chains did all of them."""
    if goal is not None:
        raise AgentError("--goal names one goal; the goals of a chain come from its clauses")
    begun = time.perf_counter()
    clauses = [step.sentence for step in plan.steps]
    codes = agent.translate(clauses)
    print(f'sentence: "{plan.sentence}"')
    print(f"plan: {len(clauses)} tasks, in the order they are to be done")
    for index, (step, code) in enumerate(zip(plan.steps, codes, strict=True)):
        meant = names[step.goal] if step.goal is not None else "no goal"
        print(f'  {index + 1}. "{step.sentence}" -> {meant} ({step.verdict}, confidence {step.confidence:.2f})')
        print(f"     code: {format_code(agent, code)}")
    result = {**plan.to_json(names), "codes": codes.tolist()}
    if not plan.acts and not args.act_anyway:
        print(plan.describe(names).splitlines()[0])
        return result
    if not plan.acts:
        print("acting anyway (--act-anyway): a clause was not understood; its likeliest goal is pursued")
    goals = np.array([step.goal if step.goal is not None else step.likeliest for step in plan.steps], np.int32)
    rng = jax.random.key(args.rng_seed)
    episodes = args.episodes
    chains = run_chains(
        agent,
        np.broadcast_to(codes, (episodes, *codes.shape)),
        np.broadcast_to(goals, (episodes, goals.size)),
        rng,
        deterministic=args.deterministic,
    )
    done = time.perf_counter()
    first = chains.reached_step[0]
    print(f"first chain ({chains.budget} steps at most per task):")
    for index, (goal_id, step) in enumerate(zip(goals, first, strict=True)):
        where = f"reached at step {step}" if step >= 0 else "not reached: the chain stops here"
        print(f"  {index + 1}. {names[goal_id]}: {where}")
    complete = int((chains.completed == len(goals)).sum())
    print(
        f"chains: all {len(goals)} tasks done in {complete}/{episodes} episodes ({100 * complete / episodes:.1f} %); "
        f"average {chains.average_length:.2f} of {len(goals)} done in a row"
    )
    for record, step in zip(result["plan"], first, strict=True):
        record["reached_step"] = int(step) if step >= 0 else None
    result.update(acted=True, goals=goals.tolist(), chains=chains.summary())
    if args.video is not None:
        result.update(write_chain_video(agent, args, plan, codes, goals, jax.random.split(rng, episodes)[0]))
    loading = f"load {load_s:.1f} s, " if load_s is not None else ""
    print(f"time: {loading}{episodes} chains {done - begun:.1f} s (compile included)")
    return result


def write_chain_video(agent: Agent, args: InstructArgs, plan, codes, goals, key) -> dict:
    """Writes the first chain (``key``: its key in ``run_chains``) to ``--video``, each frame captioned with the
    clause it follows; ``{"video": path}`` when written."""
    episode = chain_episode(agent, codes, goals, key, deterministic=args.deterministic)
    steps = int(episode.valid.sum())
    clauses = [step.sentence for step in plan.steps]
    try:
        from envs.render import RenderError, caption, write_video

        frames = agent.env.render(episode.qpos[: steps + 1])
        # frame t shows the state after step t; it is captioned with the clause step t (or, first, step 1) followed
        shown = [int(episode.clause[max(t - 1, 0)]) for t in range(len(frames))]
        frames = [caption([f], f"{k + 1}/{len(clauses)}: {clauses[k]}")[0] for f, k in zip(frames, shown, strict=True)]
        frames += [frames[-1]] * 5  # linger on the last frame
        write_video(frames, args.video, fps=5.0 if agent.env_name.startswith("clevr") else 12.5)
    except RenderError as error:
        print(f"video: not written ({error})")
        return {}
    reached = int((episode.result.reached_step[0] >= 0).sum())
    print(f"video: {args.video} (the first chain, {steps} steps, {reached} of {len(clauses)} tasks reached)")
    return {"video": str(args.video)}


def write_episode_video(agent: Agent, args: InstructArgs, sentence: str, goal: int, key) -> dict:
    """Writes the episode of ``key`` (the first episode's key) to ``--video``; ``{"video": path}`` when written."""
    episode = agent.rollout(sentence, key, goal, args.deterministic)
    try:
        from envs.render import RenderError, caption, write_video

        frames = caption(agent.env.render(episode.qpos[: episode.length + 1]), sentence)
        frames += [frames[-1]] * 5  # linger on the last frame
        write_video(frames, args.video, fps=5.0 if agent.env_name.startswith("clevr") else 12.5)
    except RenderError as error:
        print(f"video: not written ({error})")
        return {}
    outcome = "success" if episode.success else "no success"
    print(f"video: {args.video} (the first episode, {episode.length} steps, {outcome})")
    return {"video": str(args.video)}


run_command, main = agent_command(InstructArgs, instruct, __doc__)

if __name__ == "__main__":
    raise SystemExit(main())
