"""End-to-end ``--quick`` runs of the experiment commands: every stage runs, writes its outputs, and is reused.

The runs use the small BERT folder shipped with the tests (the default encoder is covered by
tests/test_language.py) so that building the language caches takes seconds.
"""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from experiments import clevr, kitchen
from experiments.cli import parse
from experiments.compare import CompareArgs, base_config, compare, parse_args
from experiments.config import ExperimentConfig, default_config, resolve
from tests.conftest import QUICK, TINY_BERT


def rows_steps(folder: Path) -> int:
    """Env steps per seed at the IFP's last evaluation."""
    rows = [json.loads(line) for line in (folder / "talar" / "ifp" / "ppo" / "metrics.jsonl").read_text().splitlines()]
    return int([r for r in rows if "eval/train/success_per_seed" in r][-1]["train/env_steps"])


def _check_run(folder: Path, seeds: int, num_instructions: int, num_goals: int, tl_size: int = 14):
    summary = json.loads((folder / "talar" / "summary.json").read_text())
    # what budget a number had, readable without the folder name
    assert summary["env"] in ("clevr", "kitchen") and summary["method"] == "talar" and summary["seeds"] == seeds
    assert summary["ifp_env_steps_per_seed"] == rows_steps(folder) and summary["num_patterns"] is None
    assert "commit" in summary and summary["command"].startswith("python ")
    for split in ("train", "test"):
        rates = np.asarray(summary["final_success"][split])
        assert rates.shape == (seeds,) and np.all((rates >= 0) & (rates <= 1))
    for name in ("config.json", "results.md", "curves.png", "tsne.png"):
        assert (folder / "talar" / name).stat().st_size > 0, name
    tables = np.load(folder / "talar" / "translator" / "tables.npy")
    assert tables.shape == (seeds, num_instructions, tl_size)
    assert set(np.unique(tables).tolist()) <= {0.0, 1.0}
    np.testing.assert_array_equal(tables[:, :, 4:].reshape(seeds, -1, 2, 5).sum(-1), 1)  # one-hot arguments
    rows = [json.loads(line) for line in (folder / "talar" / "ifp" / "ppo" / "metrics.jsonl").read_text().splitlines()]
    assert rows and all(np.isfinite(r["losses/policy"]) for r in rows)
    assert "| TALAR |" in (folder / "talar" / "results.md").read_text()
    # Every stage's wall-clock is recorded, the method's own stages included.
    assert set(summary["stage_seconds"]) == {"oracle", "talar/task_language", "talar/translator", "ifp"}
    assert all(seconds > 0 for seconds in summary["stage_seconds"].values())
    assert (folder / "oracle" / "dataset" / "task_dataset.npz").exists()
    for split, per_goal in summary["final_success_per_goal"].items():  # the last evaluation, per goal
        assert len(per_goal) == num_goals and all(v is None or 0 <= v <= 1 for v in per_goal), split
        assert per_goal == [r for r in rows if "eval/train/success_per_goal" in r][-1][f"eval/{split}/success_per_goal"]
    return summary


def test_clevr_quick_end_to_end(clevr_run, capsys):
    out, summary = clevr_run
    _check_run(out, seeds=2, num_instructions=1440, num_goals=80)
    assert summary["method"] == "talar"
    # Running the same command again reuses every stage and reports the same result.
    again = clevr.run_command([*QUICK, "--out", str(out)])
    assert "up to date" in capsys.readouterr().out
    assert again["final_success"] == summary["final_success"]


def _copy_of(run_folder, tmp_path):
    """A copy of a finished run folder: a test that adds methods to it leaves the shared fixture as it was."""
    return Path(shutil.copytree(run_folder, tmp_path / "run", symlinks=True))


@pytest.mark.parametrize(
    ("methods", "names"),
    [
        (("talar", "bert-binary"), {"TALAR", "BERT-binary"}),
        pytest.param(("talar", "onehot", "gla"), {"TALAR", "One-hot", "GLA"}, marks=pytest.mark.slow),
    ],
)
def test_compare_quick_runs_baselines_on_shared_stages(clevr_run, methods, names, tmp_path):
    out = _copy_of(clevr_run[0], tmp_path)
    experiment = default_config("clevr", seeds=2, out=out, quick=True, encoder=TINY_BERT, progress=False)
    final = compare(CompareArgs(experiment=experiment, methods=methods))
    assert set(final) == names
    assert (out / "compare.png").stat().st_size > 0
    table = (out / "compare.md").read_text()
    assert all(f"| {name} |" in table for name in names)
    assert "TALAR over the best baseline (paper: +13.4 points" in table


def test_compare_shows_every_method_finished_with_its_settings(clevr_run, monkeypatch, tmp_path):
    """Methods run one call at a time still make one table; a policy trained with other settings is left out."""
    from experiments.compare import finished_methods

    out = _copy_of(clevr_run[0], tmp_path)
    experiment = default_config("clevr", seeds=2, out=out, quick=True, encoder=TINY_BERT, progress=False)
    final = compare(CompareArgs(experiment=experiment, methods=("bert-binary",)))  # TALAR: the fixture's run
    assert {"TALAR", "BERT-binary"} <= set(final)
    table = (out / "compare.md").read_text()
    assert "| TALAR |" in table and "- test instructions: " in table and "best baseline BERT-binary" in table
    base = base_config(CompareArgs(experiment=experiment, methods=("bert-binary",)))
    assert "talar" in finished_methods(base, ("bert-binary",))
    fewer_steps = base_config(CompareArgs(experiment=experiment, methods=("bert-binary",), ifp_env_steps=512))
    assert "talar" not in finished_methods(fewer_steps, ("bert-binary",))


def test_kitchen_quick_end_to_end(kitchen_run):
    tmp_path, printed = kitchen_run
    # The report's deployment strip: one learned episode per sub-task (or one line saying why there is none).
    assert (tmp_path / "talar" / "deployment.png").exists() or "deployment strip: not written" in printed
    _check_run(tmp_path, seeds=2, num_instructions=120, num_goals=6)
    results = (tmp_path / "talar" / "results.md").read_text()
    assert "Final success per sub-task" in results and "| microwave |" in results and "| kettle |" in results
    oracle = json.loads((tmp_path / "oracle" / "oracle.json").read_text())
    assert oracle["collector"] == "scripted"  # kitchen's default collector covers all six sub-tasks


def _error_line(capsys, main, argv) -> str:
    """Runs a command's ``main`` expecting exit status 2; returns its single stderr line."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err, err
    return err


def test_bad_experiment_options_fail_with_one_line_before_any_stage(tmp_path, capsys):
    from experiments import compare as compare_module
    from experiments import oracle

    out = tmp_path / "never"
    assert "unknown method 'nope'" in _error_line(capsys, clevr.main, ["--method", "nope", "--out", str(out)])
    assert "unknown sentence readout 'cls'" in _error_line(
        capsys, clevr.main, ["--sentence-readout", "cls", "--out", str(out)]
    )
    assert "num-patterns" in _error_line(capsys, kitchen.main, ["--num-patterns", "3", "--out", str(out)])
    # the encoder folder is checked before the oracle stage runs
    assert "no config.json" in _error_line(capsys, kitchen.main, ["--encoder", str(tmp_path), "--out", str(out)])
    assert "posture_targets" in _error_line(
        capsys, kitchen.main, ["--env-options", "posture_targets", "bogus", "--out", str(out)]
    )
    argv = ["--methods", "talar", "bogus", "--out", str(out)]
    assert "valid methods" in _error_line(capsys, compare_module.main, argv)
    assert "unknown experiment env" in _error_line(capsys, oracle.main, ["--env", "nowhere", "--out", str(out)])
    assert not out.exists()  # nothing ran


def test_compare_nests_the_env_commands_config(tmp_path):
    base = ExperimentConfig(out=tmp_path)
    with pytest.raises(ValueError, match="--ifp-env-steps must be >= 1"):
        base_config(CompareArgs(experiment=base, ifp_env_steps=0))
    assert base_config(CompareArgs(experiment=base, ifp_env_steps=300_000)).ifp.total_env_steps == 300_000
    assert base_config(CompareArgs(experiment=base)).talar == clevr.DEFAULT.talar  # same TL settings as the command
    parsed = parse_args(CompareArgs, ["--talar.gumbel-temperature", "2"])
    assert base_config(parsed).talar.gumbel_temperature == 2.0
    assert base_config(CompareArgs(experiment=base)).sentence_readout == clevr.DEFAULT.sentence_readout
    readout = dataclasses.replace(base, sentence_readout="sentence")
    assert base_config(CompareArgs(experiment=readout)).sentence_readout == "sentence"
    kitchen_base = base_config(CompareArgs(experiment=ExperimentConfig(env="kitchen", out=tmp_path)))
    assert kitchen_base.ifp == resolve(kitchen.DEFAULT).ifp and kitchen_base.env_options == kitchen.DEFAULT.env_options
    # On the command line the experiment's defaults are the --env's recipe (the kitchen's shorter referential game).
    for argv in (["--env", "kitchen"], ["--env=kitchen", "--seeds", "2"]):
        parsed_kitchen = base_config(parse_args(CompareArgs, argv))
        assert parsed_kitchen.talar == resolve(kitchen.DEFAULT).talar and parsed_kitchen.out == Path(
            "runs/compare-kitchen"
        )
    assert base_config(parse_args(CompareArgs, [])).talar == resolve(clevr.DEFAULT).talar
    # ... and so are the Python API's (the class default once pinned the shared EXPERIMENT_TALAR, not CLEVR's recipe)
    assert dataclasses.replace(base_config(CompareArgs()), out=None) == dataclasses.replace(
        resolve(clevr.DEFAULT), out=None
    )


def test_python_api_and_command_line_make_the_same_run():
    for env, command_default in (("clevr", clevr.DEFAULT), ("kitchen", kitchen.DEFAULT)):
        assert resolve(ExperimentConfig(env=env)) == resolve(command_default)
        parsed = parse(ExperimentConfig, [], default=command_default)
        assert resolve(parsed) == resolve(ExperimentConfig(env=env))


def test_table3_shows_its_methods_per_pattern_count(monkeypatch, tmp_path):
    """Each column is one comparison; the table keeps the paper's rows and columns, fills cells of runs finished in
    earlier calls, marks the rest "-", and leaves out other methods the comparison's folder holds."""
    from experiments import patterns as patterns_module

    seen, looked_up = [], []

    def fake_compare(args):
        seen.append((args.experiment.num_patterns, args.methods))
        k = args.experiment.num_patterns
        return {
            "TALAR": {"train": np.array([1.0, 1.0 - 0.1 * (k == 9)])},
            "One-hot": {"train": np.array([0.5, 0.5])},
            "GLA": {"train": np.array([0.9, 0.9])},
        }

    def fake_finished(base):
        looked_up.append(base.num_patterns)
        final = {"final_success": {"train": [0.6, 0.8]}}
        return {"bert-binary": final, "gla": final} if base.num_patterns == 5 else {}

    monkeypatch.setattr(patterns_module, "compare", fake_compare)
    monkeypatch.setattr(patterns_module, "finished_summaries", fake_finished)
    experiment = default_config("clevr", out=tmp_path)
    table = patterns_module.patterns(
        patterns_module.PatternsArgs(experiment=experiment, patterns=(1, 9), methods=("talar", "onehot"))
    )
    assert [k for k, _ in seen] == [1, 9] and all(methods == ("talar", "onehot") for _, methods in seen)
    assert looked_up == [5]  # only the column this call did not run is read from the folder
    assert "| method | 1 pattern | 5 patterns | 9 patterns | paper (1 / 5 / 9) |" in table
    assert "| TALAR | 100.0 ± 0.0 | - | 95.0 ± 5.0 | 100 / 100 / 99.9 |" in table
    assert "| One-hot | 50.0 ± 0.0 | - | 50.0 ± 0.0 | 98.2 / 91.8 / 86.5 |" in table
    assert "| BERT-binary | - | 70.0 ± 10.0 | - | 82 / 60.9 / 64 |" in table
    assert "| BERT-continuous | - | - | - | 95.3 / 63.1 / 60.7 |" in table and "GLA" not in table
    assert (tmp_path / "table3.md").read_text() == table


def test_compile_cache_is_per_host_cpu(monkeypatch, tmp_path):
    from talar_jax import runtime

    avx512 = "processor : 0\nmodel name : Xeon\nflags : fpu avx2 avx512f\n"
    avx2 = "processor : 0\nmodel name : Xeon\nflags : fpu avx2\n"
    assert runtime.host_cpu_fingerprint(avx512) != runtime.host_cpu_fingerprint(avx2)
    assert runtime.host_cpu_fingerprint(avx512) == runtime.host_cpu_fingerprint(avx512 + avx512.replace("0", "1"))
    monkeypatch.delenv(runtime.COMPILE_CACHE_ENV_VAR, raising=False)
    monkeypatch.setenv("TALAR_JAX_CACHE", str(tmp_path / "language"))  # the language cache's variable: not this one
    monkeypatch.setattr(runtime, "COMPILE_CACHE_DIR", str(tmp_path))
    assert Path(runtime.compile_cache_dir()) == tmp_path / runtime.host_cpu_fingerprint()
    monkeypatch.setenv(runtime.COMPILE_CACHE_ENV_VAR, str(tmp_path / "jax"))
    assert Path(runtime.compile_cache_dir()) == tmp_path / "jax" / runtime.host_cpu_fingerprint()
