"""Ships one seed of a finished run as an agent in the package: ``python -m experiments.ship RUN --name kitchen``.

The shipped agent is a run folder cut down to what ``talar_jax.agent.load`` reads, for one seed: the method folder's
``config.json`` (one seed), ``encoding.json``, ``language.json``, ``confidence.json`` (``experiments.calibrate``), the
policy's parameters as one msgpack file (``ifp/ppo/policy.msgpack``, in place of the orbax checkpoints), the
encoding's parameters (every seed's translator, the shipped seed's first: the confidence measure weighs their
agreement), TALAR's TL generator of that seed (``task_language/params.msgpack``: chains tell by it that a sub-task was
done) and ``shipped.json``: where it came from (run, seed, command, commit) and the success that run
recorded for that seed, which ``tests/test_shipped_agents.py`` checks the shipped files still reach. ``--seed``
defaults to the run's best seed (mean of its final success on training and test instructions).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import jax
import numpy as np

from experiments.cli import POSITIONAL, checked, command, parse
from experiments.reports import load_agent
from talar_jax import runtime
from talar_jax.agent import (
    CONFIDENCE_FILE,
    GENERATOR_FILE,
    POLICY_FILE,
    SHIPPED_AGENTS_DIR,
    SHIPPED_RECORD,
    AgentError,
    read_config,
    read_policy_params,
)
from talar_jax.checkpoint import load_tree, save_tree, write_json_atomic
from talar_jax.encodings import ENCODING_FILE, FILE_SOURCE, EncodingArtifact


@dataclasses.dataclass(frozen=True)
class ShipArgs:
    """Which run and seed to ship, under which name."""

    run_dir: Path = dataclasses.field(metadata=POSITIONAL)
    """A finished run folder (its root or method folder)."""
    name: str
    """The agent's name (``talar_jax.agent.load(name)``, ``python -m experiments.instruct NAME``): usually the env."""
    seed: int | None = None
    """The seed to ship (default: the run's best on training and test instructions)."""
    out: Path = SHIPPED_AGENTS_DIR
    """Folder of shipped agents (the agent goes to ``<out>/<name>``)."""


TRAINING_ONLY_OPTIONS = ("start", "start_done_probability", "start_arm_noise", "start_arm")
"""Env options that shape how a policy was trained (where its episodes started), not the task: a shipped agent acts
in the env as a user makes it, so they are left out of its config and named in its record."""


def best_seed(summary: dict) -> int:
    """The seed with the highest mean of its final success on training and test instructions (the first of ties)."""
    final = summary["final_success"]
    scores = np.mean([final["train"], final["test"]], axis=0)
    return int(np.argmax(scores))


def _one_seed(tree, seed: int):
    return jax.tree.map(lambda x: np.asarray(x)[seed : seed + 1], tree)


def ship(args: ShipArgs) -> Path:
    """Writes ``<out>/<name>`` from the run; returns that folder."""
    agent = load_agent(args.run_dir, seed=args.seed or 0, check_encoder=True)  # writes encoding.json if missing
    folder, summary = agent.folder, json.loads((agent.folder / "summary.json").read_text())
    seed = best_seed(summary) if args.seed is None else args.seed
    target = args.out / args.name
    if target.exists():
        shutil.rmtree(target)
    method = target / folder.name
    (method / "ifp" / "ppo").mkdir(parents=True)
    config = read_config(folder)
    options = dict(config.get("env_options") or {})
    trained_with = {key: options.pop(key) for key in TRAINING_ONLY_OPTIONS if key in options}
    config["env_options"] = options
    config_seeds = config["seeds"]
    config["seeds"] = 1
    config["ifp"] = {**config["ifp"], "num_seeds": 1}
    write_json_atomic(method / "config.json", config)
    for name in (ENCODING_FILE, "language.json"):
        shutil.copy(folder / name, method / name)
    shutil.copy(folder / "ifp" / "stage.json", method / "ifp" / "stage.json")
    save_tree(method / "ifp" / "ppo" / POLICY_FILE, _one_seed(read_policy_params(folder), seed))
    encoding = EncodingArtifact.read(folder)
    if encoding.params is not None and encoding.params.source == FILE_SOURCE:
        # Every seed's encoding, the shipped seed's first: the agent acts on seed 0's, and its confidence weighs how
        # far the run's translators agree (talar_jax.confidence), which one seed alone does far worse.
        params = load_tree(folder.parent / encoding.params.path)  # seed-stacked, entry and all
        seeds = int(config_seeds)
        order = np.array([seed, *[s for s in range(seeds) if s != seed]])
        (target / encoding.params.path).parent.mkdir(parents=True, exist_ok=True)
        save_tree(target / encoding.params.path, jax.tree.map(lambda x: np.asarray(x)[order], params))
    if (folder / GENERATOR_FILE).is_file():
        # the shipped seed's TL generator (not its receiver): what tells, in a chain, that a sub-task was done
        generator = load_tree(folder / GENERATOR_FILE)["generator"]
        (method / GENERATOR_FILE).parent.mkdir(parents=True, exist_ok=True)
        save_tree(method / GENERATOR_FILE, {"generator": _one_seed(generator, seed)})
    if (folder / CONFIDENCE_FILE).is_file():
        shutil.copy(folder / CONFIDENCE_FILE, method / CONFIDENCE_FILE)
    write_json_atomic(
        method / SHIPPED_RECORD,
        {
            "run": str(args.run_dir),
            "seed": seed,
            "env": summary["env"],
            "method": summary["method"],
            "command": summary.get("command"),
            "commit": summary.get("commit"),
            "ifp_env_steps_per_seed": summary["ifp_env_steps_per_seed"],
            "final_success": {split: rates[seed] for split, rates in summary["final_success"].items()},
            **({"trained_with_env_options": trained_with} if trained_with else {}),
        },
    )
    return target


def check(args: ShipArgs) -> ShipArgs:
    if not args.name or "/" in args.name or args.name.startswith("."):
        raise ValueError(f"--name must be a plain folder name, got {args.name!r}")
    try:
        load_agent(args.run_dir, seed=args.seed or 0, check_encoder=False)
    except AgentError as error:
        raise ValueError(str(error)) from None
    return args


def run_command(argv: list[str] | None = None) -> Path:
    """``python -m experiments.ship`` for Python callers: the shipped agent's folder."""
    runtime.start()
    args = checked(check, parse(ShipArgs, argv, description=__doc__))
    target = ship(args)
    print(f"shipped {args.run_dir} as {target}")
    return target


main = command(run_command)

if __name__ == "__main__":
    raise SystemExit(main())
