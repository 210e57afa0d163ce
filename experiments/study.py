"""The paper's appendix studies of one method's settings: ``python -m experiments.study NAME --env kitchen --seeds 5``.

NAME is one of

* ``ablation`` (paper Fig. 7, section 5.4): TALAR with N_pn in ``--predicates`` (2, 4, 6) x N_a in ``--arguments``
  (2, 3, 4) predicate and argument networks; the paper finds larger better, N_pn = 6, N_a = 4 sufficient.
* ``dataset-size`` (paper Fig. 13, Appendix E.4): TALAR with task datasets of ``--dataset-sizes`` tuples (10k, 25k,
  50k); the paper finds 10k tuples already give 76 %+ on kitchen, above every baseline.
* ``aligned`` (paper Fig. 12, Appendix E.3): TALAR against the BERT baselines whose encoding layer has the TL
  generator's architecture (``--method aligned-bert-binary`` / ``aligned-bert-continuous``) and the plain BERT-binary /
  BERT-continuous; the paper finds the aligned baselines better than the plain ones but below TALAR.
* ``end-to-end`` (paper Fig. 15, Appendix E.6): TALAR against ``--method end-to-end`` (generator, receiver and
  translator trained jointly); the paper finds the two-stage training better.
* ``finetuned-bert`` (paper Fig. 14, Appendix E.5): BERT-binary / BERT-continuous against ``--method
  finetuned-bert-binary`` / ``finetuned-bert-continuous``, whose BERT the policy's loss trains too (the one place
  the language model runs inside a training loop: one batched forward pass over the training instructions per
  minibatch, and one over every instruction per rollout); ``--talar.finetuned-bert-first-layer K`` trains only
  the encoder layers from K up (cheaper). The paper finds the fine-tuned baselines struggle to succeed at all.

Each setting is one experiment folder under ``--out`` (default ``runs/study-<name>-<env>``) with every stage cached,
so an interrupted study resumes where it stopped. The ablation's settings share the first one's oracle and task
dataset (a link to its ``oracle`` folder), as do the methods of the aligned and end-to-end studies; dataset sizes
collect their own. Writes ``study.png`` (final success per setting, train and test instructions, mean ± std over
seeds), ``study-curves.png`` (success over env steps per setting, as the paper's figures draw them), ``study.md``
(final success, and how fast each setting learns: the env steps at which the mean over seeds first reaches 80 % on
training instructions and the mean success over the curve) and ``summary.json`` (env, method, IFP env steps per seed,
seeds, command and commit beside every setting's final success per seed and its learning-speed figures).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Literal

from experiments.cli import FLATTEN, POSITIONAL, UsageError, check_outputs, checked, command, parse, peek
from experiments.config import ExperimentConfig, default_config
from experiments.lock import hold
from experiments.pipeline import check_inputs, finished_summary, run, stage_oracle_key
from experiments.recipes import recipe_names
from experiments.study_report import write_outputs
from talar_jax import runtime
from talar_jax.language import build_cache

STUDIES: tuple[str, ...] = ("ablation", "dataset-size", "aligned", "end-to-end", "finetuned-bert")
ALIGNED_METHODS: tuple[str, ...] = (
    "talar",
    "aligned-bert-binary",
    "aligned-bert-continuous",
    "bert-binary",
    "bert-continuous",
)
FINETUNED_METHODS: tuple[str, ...] = (
    "bert-binary",
    "bert-continuous",
    "finetuned-bert-binary",
    "finetuned-bert-continuous",
)
METHOD_STUDIES: dict[str, tuple[str, ...]] = {
    "aligned": ALIGNED_METHODS,
    "end-to-end": ("talar", "end-to-end"),
    "finetuned-bert": FINETUNED_METHODS,
}
"""Studies that compare methods (one setting per method) rather than TALAR's settings."""


@dataclasses.dataclass(frozen=True)
class StudyArgs:
    """Which study, over which settings, on the experiment settings every run shares."""

    name: Literal["ablation", "dataset-size", "aligned", "end-to-end", "finetuned-bert"] = dataclasses.field(
        metadata=POSITIONAL
    )
    """The study: ablation (Fig. 7), dataset-size (Fig. 13), aligned (Fig. 12), end-to-end (Fig. 15) or
    finetuned-bert (Fig. 14)."""
    experiment: ExperimentConfig = dataclasses.field(default=ExperimentConfig(env="kitchen"), metadata=FLATTEN)
    """The shared settings, as the env commands take them (``--env``, ``--seeds``, ``--talar.*``, ...; defaults: the
    env's recipe; ``--out`` defaults to runs/study-<name>-<env>)."""
    predicates: tuple[int, ...] = (2, 4, 6)
    """ablation: numbers of predicate networks N_pn."""
    arguments: tuple[int, ...] = (2, 3, 4)
    """ablation: numbers of argument networks N_a."""
    dataset_sizes: tuple[int, ...] = (10_000, 25_000, 50_000)
    """dataset-size: task-dataset sizes (tuples)."""
    ifp_env_steps: int | None = None
    """IFP env steps per seed and setting (default: the env command's, the paper's budget)."""
    only: tuple[str, ...] = ()
    """Settings to run in this call (labels as in study.md: npn6-na4, tuples10000, aligned-bert-binary, ...; default:
    all). The outputs cover every setting whose run finished with the study's settings, so a long study can be run
    a few settings at a time."""
    report_only: bool = False
    """Run nothing: rewrite the study's figures, table and summary over the settings already finished (after
    restoring recorded runs with ``python -m experiments.records restore``, or after a change to the report)."""


def settings(args: StudyArgs) -> dict[str, ExperimentConfig]:
    """Label -> resolved experiment of every setting of the study (validated: one ValueError per bad input)."""
    base = args.experiment
    if base.method != "talar":
        if args.name in METHOD_STUDIES:
            raise ValueError(f"the {args.name} study sets each setting's method itself; drop --method {base.method}")
        raise ValueError(f"the {args.name} study varies TALAR's task language; got --method {base.method}")
    if args.ifp_env_steps is not None and args.ifp_env_steps < 1:
        raise ValueError(f"--ifp-env-steps must be >= 1, got {args.ifp_env_steps}")
    out = base.out if base.out is not None else Path(f"runs/study-{args.name}-{base.env}")
    variants: dict[str, ExperimentConfig] = {}
    if args.name == "ablation":
        if not args.predicates or not args.arguments or min(args.predicates + args.arguments) < 1:
            raise ValueError("--predicates and --arguments need positive counts")
        talar = check_inputs(base).talar
        for predicates in args.predicates:
            for arguments in args.arguments:
                spec = dataclasses.replace(talar.spec, num_predicates=predicates, num_arguments=arguments)
                variant = dataclasses.replace(base, talar=dataclasses.replace(talar, spec=spec))
                variants[f"npn{predicates}-na{arguments}"] = variant
    elif args.name in METHOD_STUDIES:
        for method in METHOD_STUDIES[args.name]:
            variants[method] = dataclasses.replace(base, method=method)
    else:
        if not args.dataset_sizes or min(args.dataset_sizes) < 1:
            raise ValueError("--dataset-sizes needs positive sizes")
        for size in args.dataset_sizes:
            variants[f"tuples{size}"] = dataclasses.replace(base, num_tuples=size)
    if args.report_only and args.only:
        raise ValueError("--report-only runs no setting: drop --only")
    unknown = [label for label in args.only if label not in variants]
    if unknown:
        raise ValueError(f"unknown --only setting(s) {unknown}; this study's settings: {', '.join(variants)}")
    resolved = {}
    for label, variant in variants.items():
        config = check_inputs(dataclasses.replace(variant, out=out / label))
        if args.ifp_env_steps is not None:
            config = dataclasses.replace(
                config, ifp=dataclasses.replace(config.ifp, total_env_steps=args.ifp_env_steps)
            )
        resolved[label] = config
    return resolved


def share_oracle(first: Path, target: Path) -> None:
    """Links ``target/oracle`` to ``first/oracle`` (same oracle settings: its stage key matches, nothing reruns)."""
    source = first / "oracle"
    if (target / "oracle").exists() or not (source / "stage.json").is_file():
        return
    target.mkdir(parents=True, exist_ok=True)
    os.symlink(os.path.relpath(source.resolve(), target.resolve()), target / "oracle")


def study(args: StudyArgs, configs: dict[str, ExperimentConfig] | None = None) -> dict[str, dict[str, Any]]:
    """Runs the settings of ``--only`` (default: all; reusing finished stages) and writes the study's figure, table
    and summary over every setting finished with the study's settings; ``configs``: ``settings(args)`` when already
    computed (each resolves its encoder folder)."""
    configs = configs if configs is not None else settings(args)
    first = next(iter(configs.values())).out
    selected = [] if args.report_only else [label for label in configs if not args.only or label in args.only]
    finals = {}
    for index, label in enumerate(selected):
        config = configs[label]
        print(f"[study {args.name}] setting {index + 1}/{len(selected)}: {label} -> {config.out}", flush=True)
        if (args.name == "ablation" or args.name in METHOD_STUDIES) and config.out != first:
            share_oracle(first, config.out)
        finals[label] = run(config)
    rest = [label for label in configs if label not in finals]
    if rest:  # the language cache is the same for every setting: read its key once
        cache_key = build_cache(configs[rest[0]].env, configs[rest[0]].encoder, progress=False).key
        for label in rest:
            summary = finished_summary(configs[label], (stage_oracle_key(configs[label]), cache_key))
            if summary is not None:
                finals[label] = summary
    finals = {label: finals[label] for label in configs if label in finals}
    if not finals:
        where = first.parent
        raise UsageError(f"no setting of the {args.name} study has finished in {where}: nothing to report")
    print(write_outputs(args, configs, finals))
    return finals


def run_command(argv: list[str] | None = None) -> dict[str, dict[str, Any]]:
    """``python -m experiments.study`` for Python callers: the final success of every finished setting."""
    runtime.start()
    env = peek(argv, "--env", default="kitchen")
    default = None
    if env in recipe_names():  # the study's name stays a required argument: a default is only needed for the rest
        default = StudyArgs(STUDIES[0], experiment=dataclasses.replace(default_config(env), out=None))
    args = parse(StudyArgs, argv, default=default, description=__doc__)
    configs = checked(settings, args)
    out = next(iter(configs.values())).out.parent  # the settings' folders lie in the study's
    check_outputs((out, "--out", "folder"))
    if args.report_only and not out.is_dir():
        raise UsageError(f"no setting of the {args.name} study has finished in {out}: nothing to report")
    with hold(out):
        return study(args, configs)


main = command(run_command, resumes=True)

if __name__ == "__main__":
    raise SystemExit(main())
