"""``experiments.study``: the settings each study runs, its outputs, errors, and (with --all) a quick end-to-end run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from experiments import study
from experiments.cli import UsageError
from experiments.config import default_config
from tests.conftest import QUICK, TINY_BERT


def test_studies_vary_exactly_their_setting(tmp_path):
    base = default_config("kitchen", seeds=2, out=tmp_path, encoder=TINY_BERT)
    ablation = study.settings(study.StudyArgs("ablation", base, predicates=(2, 6), arguments=(3,), ifp_env_steps=4096))
    assert list(ablation) == ["npn2-na3", "npn6-na3"]
    for label, config in ablation.items():
        assert config.out == tmp_path / label and config.ifp.total_env_steps == 4096
        assert config.talar.spec.num_arguments == 3 and config.talar.spec.arg_size == base.talar.spec.arg_size
        # everything but the spec is the env command's setting
        assert config.talar.rg_steps == base.talar.rg_steps and config.num_tuples == ablation["npn2-na3"].num_tuples
    assert [c.talar.spec.num_predicates for c in ablation.values()] == [2, 6]
    sizes = study.settings(study.StudyArgs("dataset-size", base, dataset_sizes=(1000, 5000)))
    assert [c.num_tuples for c in sizes.values()] == [1000, 5000]
    assert len({c.talar for c in sizes.values()}) == 1
    aligned = study.settings(study.StudyArgs("aligned", base))
    assert [c.method for c in aligned.values()] == list(study.ALIGNED_METHODS)
    assert len({(c.talar, c.ifp, c.num_tuples) for c in aligned.values()}) == 1  # only the method differs
    joint = study.settings(study.StudyArgs("end-to-end", base))
    assert [c.method for c in joint.values()] == ["talar", "end-to-end"]
    finetuned = study.settings(study.StudyArgs("finetuned-bert", base))
    assert [c.method for c in finetuned.values()] == [
        "bert-binary",
        "bert-continuous",
        "finetuned-bert-binary",
        "finetuned-bert-continuous",
    ]
    assert len({(c.talar, c.ifp, c.num_tuples) for c in finetuned.values()}) == 1


def test_study_outputs_state_their_budget(tmp_path):
    base = default_config("kitchen", seeds=2, out=tmp_path, encoder=TINY_BERT)
    args = study.StudyArgs("dataset-size", base, dataset_sizes=(1000, 5000))
    configs = study.settings(args)
    finals = {
        label: {
            "final_success": {"train": [0.5, 1.0], "test": [0.25, 0.75]},
            "ifp_env_steps_per_seed": 8192,
            "stage_seconds": {"oracle": 10.0, "ifp": 90.0},
        }
        for label in configs
    }
    # tuples5000's IFP logged three evaluations: mean over seeds 0.25, 0.875, 1.0 on training instructions
    ppo = configs["tuples5000"].out / "talar" / "ifp" / "ppo"
    ppo.mkdir(parents=True)
    rows = [(2048, [0.0, 0.5]), (4096, [0.75, 1.0]), (8192, [1.0, 1.0])]
    lines = [{"train/env_steps": n, "eval/train/success_per_seed": r, "eval/test/success_per_seed": r} for n, r in rows]
    (ppo / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in [{"train/sps": 1.0}, *lines]))
    table = study.write_outputs(args, configs, finals)
    assert "| tuples1000 | 75.0 ± 25.0 | 50.0 ± 25.0 | 8,192 | 1.5 | - | - |" in table and "Paper:" in table
    assert "| tuples5000 | 75.0 ± 25.0 | 50.0 ± 25.0 | 8,192 | 1.5 | 4,096 | 70.8 |" in table
    assert (tmp_path / "study-curves.png").stat().st_size > 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["env"] == "kitchen" and summary["seeds"] == 2 and summary["method"] == "talar"
    assert summary["ifp_env_steps_per_seed"] == {"tuples1000": 8192, "tuples5000": 8192} and "commit" in summary
    assert summary["settings"]["tuples1000"]["learning_speed"] is None
    assert summary["settings"]["tuples5000"]["learning_speed"] == {
        "env_steps_to_80_percent": 4096,
        "curve_mean_success": pytest.approx(0.7083333),
    }
    assert (tmp_path / "study.png").stat().st_size > 0
    partial = study.write_outputs(args, configs, {"tuples5000": finals["tuples5000"]})
    assert "tuples1000 |" not in partial and "Not run yet (**partial study**): tuples1000." in partial
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert list(summary["settings"]) == ["tuples5000"] and summary["not_run"] == ["tuples1000"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["ablation", "--method", "onehot"], "varies TALAR's task language"),
        (["end-to-end", "--method", "onehot"], "drop --method onehot"),
        (["ablation", "--predicates", "0"], "positive counts"),
        (["dataset-size", "--dataset-sizes", "0"], "positive sizes"),
        (["ablation", "--ifp-env-steps", "0"], "--ifp-env-steps must be >= 1"),
        (["ablation", "--reuse-stages", "/no/such/run"], "--reuse-stages /no/such/run: no such run folder"),
        (["ablation", "--only", "npn9-na2"], "unknown --only setting(s) ['npn9-na2']; this study's settings: npn2-na2"),
        (["end-to-end", "--report-only", "--only", "talar"], "--report-only runs no setting: drop --only"),
    ],
)
def test_bad_study_options_fail_with_one_line(argv, message, capsys, tmp_path):
    assert study.main([*argv, "--out", str(tmp_path / "never")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and message in err and "\n" not in err
    assert not (tmp_path / "never").exists()


def test_report_only_runs_nothing_and_says_when_nothing_finished(tmp_path):
    base = default_config("kitchen", seeds=2, out=tmp_path, encoder=TINY_BERT)
    args = study.StudyArgs("end-to-end", base, report_only=True)
    with pytest.raises(UsageError) as error:
        study.study(args)
    message = str(error.value)
    assert message.startswith("no setting of the end-to-end study has finished") and "\n" not in message
    assert not any((tmp_path / label).exists() for label in ("talar", "end-to-end"))


@pytest.mark.slow
def test_ablation_quick_end_to_end_shares_the_oracle(tmp_path):
    argv = ["ablation", "--env", "clevr", *QUICK, "--predicates", "2", "--arguments", "1", "2", "--out", str(tmp_path)]
    assert list(study.run_command([*argv, "--only", "npn2-na1"])) == ["npn2-na1"]
    assert "Not run yet (**partial study**): npn2-na2." in (tmp_path / "study.md").read_text()
    finals = study.run_command([*argv, "--only", "npn2-na2"])  # the first setting's finished run joins the outputs
    assert list(finals) == ["npn2-na1", "npn2-na2"]
    assert "Not run yet" not in (tmp_path / "study.md").read_text()
    assert (tmp_path / "npn2-na2" / "oracle").is_symlink()
    tables = np.load(tmp_path / "npn2-na1" / "talar" / "translator" / "tables.npy")
    assert tables.shape[-1] == 2 + 5  # N_pn + N_a * arg_size
    assert (tmp_path / "study.md").is_file() and json.loads((tmp_path / "summary.json").read_text())[
        "study"
    ] == "ablation"
