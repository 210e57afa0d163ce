"""``experiments.paper``: the reproduction's commands are valid for their own commands, run in order, and resume."""

from __future__ import annotations

import pytest

from experiments import compare, hrl, paper, patterns, pipeline, study
from talar_jax.language.encoder import ENCODER_VARIANTS


def _validate(argv: list[str], monkeypatch) -> object:
    """Parses and validates one job's command line as its module does, without running it."""
    module, rest = argv[0], argv[1:]
    done = []
    monkeypatch.setattr(pipeline, "run", done.append)
    monkeypatch.setattr(study, "study", lambda args, configs: done.append(configs))
    monkeypatch.setattr(hrl, "hrl", done.append)
    if module in ("experiments.clevr", "experiments.kitchen"):
        pipeline.run_command(module.split(".")[1], rest)
    elif module == "experiments.compare":
        compare.run_parsed(compare.CompareArgs, done.append, rest, None)
    elif module == "experiments.patterns":
        compare.run_parsed(patterns.PatternsArgs, done.append, rest, None)
    elif module == "experiments.study":
        study.run_command(rest)
    else:
        hrl.run_command(rest)
    assert len(done) == 1
    return done[0]


def test_every_command_is_valid_for_its_module(tmp_path, monkeypatch):
    args = paper.PaperArgs(root=tmp_path, seeds=3, physics="c", finetuned_bert=True)
    jobs = paper.jobs(args)
    names = [job.name for job in jobs]
    encoders = [f"encoder-{name}" for name in ENCODER_VARIANTS]
    assert names[:9] == ["clevr", "kitchen", "compare-clevr", "table3", *encoders, "compare-kitchen"]
    assert {"ablation", "dataset-size", "aligned", "end-to-end", "finetuned-bert", "hrl-clevr"} <= {
        j.name for j in jobs
    }
    for job in jobs:
        for folder in job.reuse:
            folder.mkdir(parents=True, exist_ok=True)
        parsed = _validate(job.command(existing_only=True), monkeypatch)
        configs = parsed.values() if isinstance(parsed, dict) else [parsed]
        for config in configs:
            experiment = getattr(config, "experiment", config)
            assert experiment.seeds == 3 and experiment.physics == "c"
            assert str(experiment.out if experiment.out is not None else "").startswith(str(tmp_path))
    # later jobs reuse only what earlier jobs make
    made = {str(tmp_path / name) for name in ("clevr", "kitchen", "compare-clevr", "compare-kitchen")}
    assert all(str(folder) in made for job in jobs for folder in job.reuse)
    assert "finetuned-bert" not in [job.name for job in paper.jobs(paper.PaperArgs(root=tmp_path))]


def test_runs_in_order_reusing_what_exists_and_stops_at_a_failure(tmp_path, monkeypatch, capsys):
    calls = []

    def fake_run(command):
        calls.append(command)
        return 1 if "experiments.patterns" in command else 0

    monkeypatch.setattr(paper, "run_job", fake_run)
    (tmp_path / "clevr").mkdir()
    status = paper.main(["--root", str(tmp_path), "--only", "compare-clevr", "table3", "compare-kitchen"])
    assert status == 1 and len(calls) == 2  # stopped at the failing Table 3, compare-kitchen not started
    assert calls[0][-2:] == ["--reuse-stages", str(tmp_path / "clevr")]
    assert "error: table3 stopped with status 1; run the same command again to resume" in capsys.readouterr().err
    calls.clear()
    assert paper.main(["--root", str(tmp_path), "--only", "compare-kitchen"]) == 0
    assert "--reuse-stages" not in calls[0]  # the kitchen run does not exist: nothing to reuse


def test_dry_run_prints_every_command_and_runs_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(paper, "run_job", lambda *a, **k: pytest.fail("dry run ran a command"))
    assert paper.main(["--root", str(tmp_path / "paper"), "--dry-run"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == len(paper.jobs(paper.PaperArgs())) and all("python -m experiments." in ln for ln in lines)
    assert not (tmp_path / "paper").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [(["--only", "fig99"], "unknown --only job(s) ['fig99']; the jobs: clevr, kitchen"), (["--seeds", "0"], ">= 1")],
)
def test_bad_options_fail_with_one_line(argv, message, capsys):
    assert paper.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and message in err and "\n" not in err


def test_a_job_stopped_by_ctrl_c_stops_the_reproduction_without_a_second_line(tmp_path, monkeypatch, capsys):
    calls = []

    def interrupted(command):  # the job got the same Ctrl-C, printed its one line and ended with 130
        calls.append(command)
        return 130

    monkeypatch.setattr(paper, "run_job", interrupted)
    assert paper.main(["--root", str(tmp_path), "--only", "clevr", "kitchen"]) == 130
    assert len(calls) == 1 and capsys.readouterr().err == ""  # kitchen not started; the job's line is the only one
