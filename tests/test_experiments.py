"""End-to-end ``--quick`` runs of the experiment commands: every stage runs, writes its outputs, and is reused.

The runs use the small BERT folder shipped with the tests (the default encoder is covered by
tests/test_language.py) so that building the language caches takes seconds.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import tyro

from experiments import clevr, kitchen
from experiments.compare import CompareArgs, base_config, compare

TINY_BERT = str(Path(__file__).parent / "data" / "tiny_bert_mlm")
QUICK = ["--quick", "--seeds", "2", "--no-progress", "--encoder", TINY_BERT]


def _check_run(folder: Path, seeds: int, num_instructions: int, num_goals: int, tl_size: int = 14):
    summary = json.loads((folder / "talar" / "summary.json").read_text())
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


@pytest.fixture(scope="module")
def clevr_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("clevr")
    summary = clevr.main([*QUICK, "--out", str(out)])
    return out, summary


def test_clevr_quick_end_to_end(clevr_run, capsys):
    out, summary = clevr_run
    _check_run(out, seeds=2, num_instructions=1440, num_goals=80)
    assert summary["method"] == "talar"
    # Running the same command again reuses every stage and reports the same result.
    again = clevr.main([*QUICK, "--out", str(out)])
    assert "up to date" in capsys.readouterr().out
    assert again["final_success"] == summary["final_success"]


def test_compare_quick_runs_baselines_on_shared_stages(clevr_run):
    out, _ = clevr_run
    final = compare(CompareArgs(env="clevr", methods=("talar", "onehot", "bert-binary"), seeds=2, out=out,
                                quick=True, encoder=TINY_BERT, progress=False))  # fmt: skip
    assert set(final) == {"TALAR", "One-hot", "BERT-binary"}
    assert (out / "compare.png").stat().st_size > 0
    assert "| One-hot |" in (out / "compare.md").read_text()


def test_kitchen_quick_end_to_end(tmp_path):
    kitchen.main([*QUICK, "--out", str(tmp_path)])
    _check_run(tmp_path, seeds=2, num_instructions=120, num_goals=6)
    results = (tmp_path / "talar" / "results.md").read_text()
    assert "Final success per sub-task" in results and "| microwave |" in results and "| kettle |" in results
    oracle = json.loads((tmp_path / "oracle" / "oracle.json").read_text())
    assert oracle["collector"] == "scripted"  # kitchen's default collector covers all six sub-tasks


def test_bad_experiment_options_fail_clearly(tmp_path):
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        clevr.main(["--method", "nope", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="unknown sentence readout 'cls'"):
        clevr.main(["--sentence-readout", "cls", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="num-patterns"):
        kitchen.main(["--num-patterns", "3", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="valid methods"):
        compare(CompareArgs(methods=("talar", "bogus"), out=tmp_path))
    with pytest.raises(ValueError, match="--ifp-env-steps must be >= 1"):
        compare(CompareArgs(ifp_env_steps=0, out=tmp_path))
    assert base_config(CompareArgs(ifp_env_steps=300_000, out=tmp_path)).ifp.total_env_steps == 300_000
    assert base_config(CompareArgs(out=tmp_path)).talar == clevr.DEFAULT.talar  # same TL settings as the command
    parsed = tyro.cli(CompareArgs, args=["--talar.gumbel-temperature", "2"])
    assert base_config(parsed).talar.gumbel_temperature == 2.0
    assert base_config(CompareArgs(out=tmp_path)).sentence_readout == clevr.DEFAULT.sentence_readout
    assert base_config(CompareArgs(out=tmp_path, sentence_readout="sentence")).sentence_readout == "sentence"
