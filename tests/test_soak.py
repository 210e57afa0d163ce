"""The soak test (``benchmarks.soak``), shortened: random actions through the training wrappers, the counts it
reports, and the table and JSON it writes."""

import json

from benchmarks import soak


def test_soak_counts_and_writes_its_table(tmp_path, capsys):
    out = tmp_path / "soak"
    argv = ["--envs", "clevr", "--physics", "c", "--steps", "200", "--batch", "2", "--out", str(out)]
    assert soak.main(argv) == 0
    (row,) = json.loads((out / "soak.json").read_text())["rows"]
    assert row["env"] == "clevr" and row["physics"] == "c" and row["steps"] == 200 and row["batch"] == 2
    assert row["nonfinite_obs"] == row["nonfinite_reward"] == row["nonfinite_qpos"] == row["nonfinite_qvel"] == 0
    assert row["blowups"] == 0 and row["max_limit_violation"] < soak.BLOWUP and row["steps_per_s"] > 0
    table = (out / "soak.md").read_text()
    assert "| clevr | c | 200 | 0 / 0 / 0 / 0 |" in table and table in capsys.readouterr().out
