"""Every figure and table of the paper at its budget, one command after another: ``python -m experiments.paper``.

Runs the commands below in order, each into its own folder under ``--root`` (default ``runs/paper``); every stage
is cached and resumable and each command copies the stages an earlier one finished (``--reuse-stages``), so an
interrupted call continues where it stopped when run again. ``--dry-run`` prints the commands; ``--only NAME ...``
runs some of them. The physics defaults to MuJoCo C on a CPU and MJX on an accelerator (``--physics``).

On the 2-core CPU of results/README.md this is several days of compute (a 4M-step kitchen policy of 5 seeds takes
50-75 minutes, and the kitchen studies need 13 of them); Fig. 14 (``finetuned-bert``: BERT trained inside the policy
loop, about 63 h per seed there) runs only with ``--finetuned-bert``, meant for a GPU.
"""

from __future__ import annotations

import dataclasses
import shlex
import subprocess
import sys
from pathlib import Path

from experiments.cli import EXIT_INTERRUPTED, CommandError, check_outputs, checked, command, parse
from experiments.lock import hold
from talar_jax import runtime
from talar_jax.language.encoder import ENCODER_VARIANTS

ENCODER_EXPERIMENT_METHODS: tuple[str, ...] = ("talar", "bert-binary", "bert-continuous")
"""What each encoder of the encoder experiment trains: TALAR and the two BERT baselines. One-hot reads no encoder, so
its row comes from ``compare-clevr``, as does the default encoder's point."""


@dataclasses.dataclass(frozen=True)
class Job:
    """One command of the reproduction."""

    name: str
    paper: str
    """The paper's figures and tables it makes."""
    argv: tuple[str, ...]
    """``python -m`` arguments, without ``--reuse-stages``."""
    reuse: tuple[Path, ...] = ()
    """Earlier jobs' folders whose finished stages it copies (those that exist when it starts)."""

    def command(self, existing_only: bool) -> list[str]:
        reuse = [str(p) for p in self.reuse if not existing_only or p.is_dir()]
        return [*self.argv, *(["--reuse-stages", *reuse] if reuse else [])]


@dataclasses.dataclass(frozen=True)
class PaperArgs:
    """Reproduce the paper's results at its budgets."""

    root: Path = Path("runs/paper")
    """Folder of every run."""
    seeds: int = 5
    """Seeds per method and setting (the paper: 5)."""
    physics: str | None = None
    """Physics backend of every run (default: C on a CPU, MJX on an accelerator)."""
    only: tuple[str, ...] = ()
    """Names of the jobs to run (default: all; see --dry-run)."""
    finetuned_bert: bool = False
    """Also run Fig. 14 (BERT fine-tuned by the policy's loss; a GPU job)."""
    dry_run: bool = False
    """Print the commands and stop."""


def jobs(args: PaperArgs) -> list[Job]:
    """The reproduction's commands, in the order they run (later ones reuse earlier ones' stages)."""
    root = args.root
    common = ("--seeds", str(args.seeds), *(("--physics", args.physics) if args.physics else ()))
    clevr, kitchen = root / "clevr", root / "kitchen"
    compare_clevr, compare_kitchen = root / "compare-clevr", root / "compare-kitchen"
    out = []
    for env, folder in (("clevr", clevr), ("kitchen", kitchen)):
        out.append(
            Job(env, f"Fig. 4 / 5 / 17-18, TALAR on {env}", (f"experiments.{env}", *common, "--out", str(folder)))
        )
    out += [
        Job(
            "compare-clevr",
            "Fig. 4 / 11 / 16, CLEVR: the eight methods",
            ("experiments.compare", "--env", "clevr", *common, "--out", str(compare_clevr)),
            (clevr,),
        ),
        Job(
            "table3",
            "Table 3: 1 / 5 / 9 training patterns",
            ("experiments.patterns", *common, "--out", str(compare_clevr)),
            (clevr,),
        ),
        *(
            Job(
                f"encoder-{name}",
                f"TALAR's lead against the encoder, CLEVR: {name}",
                (
                    "experiments.compare",
                    "--env",
                    "clevr",
                    *common,
                    "--encoder",
                    name,
                    "--methods",
                    *ENCODER_EXPERIMENT_METHODS,
                    "--out",
                    str(root / "encoders-clevr" / name),
                ),  # fmt: skip
                (clevr,),
            )
            for name in ENCODER_VARIANTS
        ),
        Job(
            "compare-kitchen",
            "Fig. 4 / 11 / 16, kitchen: the eight methods",
            ("experiments.compare", "--env", "kitchen", *common, "--out", str(compare_kitchen)),
            (kitchen,),
        ),
    ]
    studies = [
        ("end-to-end", "Fig. 15"),
        ("aligned", "Fig. 12"),
        ("dataset-size", "Fig. 13"),
        ("ablation", "Fig. 7"),
        *([("finetuned-bert", "Fig. 14")] if args.finetuned_bert else []),
    ]
    for study, figure in studies:
        argv = ("experiments.study", study, "--env", "kitchen", *common, "--out", str(root / f"study-{study}"))
        out.append(Job(study, f"{figure}, kitchen", argv, (kitchen, compare_kitchen)))
    for env, folder in (("clevr", clevr), ("kitchen", kitchen)):
        argv = ("experiments.hrl", "--env", env, *common, "--run-dir", str(folder), "--out", str(root / f"hrl-{env}"))
        out.append(Job(f"hrl-{env}", f"Fig. 6, {env}", argv))
    return out


def selected(args: PaperArgs) -> list[Job]:
    """The jobs to run (validated: one ValueError per bad input)."""
    if args.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    every = jobs(args)
    names = [job.name for job in every]
    unknown = [name for name in args.only if name not in names]
    if unknown:
        raise ValueError(f"unknown --only job(s) {unknown}; the jobs: {', '.join(names)}")
    return [job for job in every if not args.only or job.name in args.only]


def run_command(argv: list[str] | None = None) -> int:
    """``python -m experiments.paper`` for Python callers: 0 once every job ran (a job that fails raises
    ``experiments.cli.CommandError`` with its status; bad input raises ``experiments.cli.UsageError``)."""
    runtime.start()
    args = parse(PaperArgs, argv, description=__doc__)
    todo = checked(selected, args)
    if args.dry_run:
        return run_jobs(args, todo)
    check_outputs((args.root, "--root", "folder"))
    with hold(args.root):  # one reproduction per root at a time (each command also holds its own folder)
        return run_jobs(args, todo)


def run_job(command: list[str]) -> int:
    """Runs one job's command to its end; its exit status. A Ctrl-C reaches the job too (one process group): the job
    stops at its next step, says so in its one line and ends with status 130, which is returned as it is."""
    with subprocess.Popen(command) as process:
        try:
            return process.wait()
        except KeyboardInterrupt:
            return process.wait()


def run_jobs(args: PaperArgs, todo: list[Job]) -> int:
    """Runs (or with --dry-run prints) the jobs one after another; 0, or 130 when a job was stopped by Ctrl-C (it
    said so itself); a job that fails otherwise raises ``CommandError`` with its status."""
    for index, job in enumerate(todo):
        command = [sys.executable, "-m", *job.command(existing_only=not args.dry_run)]
        line = shlex.join(["python", *command[1:]])
        print(f"[paper {index + 1}/{len(todo)}] {job.name} ({job.paper}): {line}", flush=True)
        if args.dry_run:
            continue
        status = run_job(command)
        if status == EXIT_INTERRUPTED:
            return status
        if status != 0:
            raise CommandError(f"{job.name} stopped with status {status}; run the same command again to resume", status)
    return 0


main = command(run_command, resumes=True)

if __name__ == "__main__":
    raise SystemExit(main())
