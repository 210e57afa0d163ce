"""The analysis commands (``experiments.analysis``) and Fig. 11's t-SNE (``experiments.tsne``): their measures on
synthetic codes and metrics, and their handling of finished runs and bad input."""

import json

import jax
import numpy as np
import pytest

from experiments import tsne
from experiments.reports import trained_codes
from tests.helpers import one_line_error as _error


def test_fig11_reads_each_runs_codes_and_leaves_out_one_hot(clevr_run, tmp_path, capsys, monkeypatch):
    out, _ = clevr_run
    tables = np.load(out / "talar" / "translator" / "tables.npy")
    np.testing.assert_array_equal(trained_codes(out / "talar", seed=1), tables[1])
    config = json.loads((out / "talar" / "config.json").read_text())
    onehot = tmp_path / "runs" / "onehot"
    (onehot / "ifp").mkdir(parents=True)
    (onehot / "ifp" / "stage.json").write_text("{}")
    (onehot / "config.json").write_text(json.dumps({**config, "method": "onehot"}))
    assert trained_codes(onehot) is None
    drawn = {}

    def fake_grid(encodings, labels, is_train, path, title="", label_names=None):
        drawn.update(encodings=encodings, labels=labels, is_train=is_train, path=path, names=label_names)
        return path

    monkeypatch.setattr(tsne, "plot_tsne_grid", fake_grid)
    figure = tmp_path / "fig11.png"
    tsne.run_command([str(out), str(onehot), "--out", str(figure), "--seed", "1"])
    (name,) = drawn["encodings"]
    assert name.startswith("TALAR (NN goal ") and drawn["path"] == figure
    np.testing.assert_array_equal(drawn["encodings"][name], tables[1])
    record = json.loads(figure.with_suffix(".json").read_text())
    is_train = np.asarray(drawn["is_train"])
    expected = tsne.nearest_training_goal_accuracy(tables[1], np.asarray(drawn["labels"]), is_train)
    assert record["nearest_training_goal"] == {"TALAR": expected} and record["seed"] == 1
    assert drawn["labels"].shape == (1440,) and drawn["is_train"].sum() == 720 and len(drawn["names"]) == 80
    assert "left out, no sentence encoding: One-hot" in capsys.readouterr().out
    # Bad input: one line each.
    assert "does not exist" in _error(capsys, tsne.main, [str(tmp_path / "nowhere")])
    assert "--seed must lie in 0..1" in _error(capsys, tsne.main, [str(out), "--seed", "2"])
    assert "none of the runs has instruction codes" in _error(capsys, tsne.main, [str(onehot)])
    kitchen = tmp_path / "runs" / "kitchen"
    (kitchen / "ifp").mkdir(parents=True)
    (kitchen / "ifp" / "stage.json").write_text("{}")
    (kitchen / "config.json").write_text(json.dumps({**config, "env": "kitchen"}))
    assert "different envs" in _error(capsys, tsne.main, [str(out), str(kitchen)])


def test_nearest_training_goal_accuracy_counts_ties_fractionally():
    goals = np.array([0, 1, 0, 1, 2])
    is_train = np.array([True, True, False, False, False])
    codes = np.array([[0.0, 0], [1, 1], [0.1, 0], [0.5, 0.5], [5, 5]])
    # test rows: nearest to goal 0 (right), a tie between goals 0 and 1 (half right), nearest to goal 1 (wrong: goal 2)
    assert tsne.nearest_training_goal_accuracy(codes, goals, is_train) == pytest.approx((1 + 0.5 + 0) / 3)


def test_kitchen_side_tasks_counts_other_sub_tasks_done_during_the_episode():
    from envs.kitchen.tasks import OBSERVATION_SIZE, TASK_GOAL, TASK_MASK
    from experiments.analysis.side_tasks import side_tasks

    def satisfy(obs, task):  # put the sub-task's joints at its goal
        joints = np.flatnonzero(TASK_MASK[task])
        obs[..., joints] = TASK_GOAL[task, joints]

    observations = np.full((2, 3, OBSERVATION_SIZE + 4), 50.0, np.float32)  # every sub-task far from its goal
    satisfy(observations[0, 1:], 0)  # episode 0 (goal kettle): the microwave on the way, then the kettle
    satisfy(observations[0, 2:], 1)
    satisfy(observations[1], 3)  # episode 1 (goal microwave): the slide cabinet already done at reset,
    satisfy(observations[1, 2:], 2)  # the light switch only after the episode ended
    valid = np.array([[True, True, True], [True, True, False]])
    np.testing.assert_array_equal(side_tasks(observations, valid, np.array([1, 0])), [1, 0])


def test_code_grouping_separates_tight_goal_groups_from_split_ones():
    from experiments.analysis.code_grouping import grouping

    goals = np.array([0, 0, 1, 1, 0, 1])
    is_train = np.array([True, True, True, True, False, False])
    tight = np.array([[0.0, 0], [0.1, 0], [5, 5], [5, 5.1], [0, 0.1], [5.1, 5]])
    split = np.array([[0.0, 0], [5, 5], [0, 5], [5, 0], [0, 0.1], [5.1, 5]])  # each goal's two codes far apart
    good, bad = grouping(tight, goals, is_train), grouping(split, goals, is_train)
    assert good["silhouette"] > 0.9 and bad["silhouette"] < 0
    assert good["within_over_between"] < 0.05 and bad["within_over_between"] > 1
    assert good["distinct_codes_per_goal"] == [2, 2] and good["test_nearest_goal"] == 1.0


def test_early_curves_compares_at_shared_steps_up_to_the_budget(tmp_path, capsys):
    from experiments.analysis.early_curves import main, run_command

    def write(folder, steps, per_seed):
        folder.mkdir()
        rows = [{"train/env_steps": 10, "train/success": 0.0}]  # a chunk without evaluation is skipped
        for step, success in zip(steps, per_seed):
            goals = [success[0], None]
            rows.append(
                {"train/env_steps": step, "eval/train/success_per_seed": success, "eval/train/success_per_goal": goals}
            )
        (folder / "ifp_metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows))

    write(tmp_path / "long", [100, 200, 300], [[0.1, 0.3], [0.5, 0.7], [0.9, 0.9]])
    write(tmp_path / "short", [100, 200], [[0.0], [0.25]])
    assert main(["--until", "250", f"long={tmp_path / 'long'}", f"short={tmp_path / 'short'}"]) == 0
    out = capsys.readouterr().out
    assert "| method | seeds | 100 | 200 | mean over these | last, per goal |" in out
    assert "| long | 2 | 20.0 (10/30) | 60.0 (50/70) | 40.0 (30/50) | 50/- |" in out  # 300 is past --until
    assert "| short | 1 | 0.0 | 25.0 | 12.5 | 25/- |" in out
    # test instructions are not in the synthetic rows: the plot needs both splits, and says so
    with pytest.raises(ValueError, match="no evaluation on test instructions"):
        run_command(["--until", "250", "--plot", str(tmp_path / "c.png"), f"long={tmp_path / 'long'}"])
    both = tmp_path / "both"
    both.mkdir()
    evaluation = {f"eval/{s}/success_{k}": [0.5] for s in ("train", "test") for k in ("per_seed", "per_goal")}
    rows = [{"train/env_steps": n, **evaluation} for n in (100, 200)]
    (both / "ifp_metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows))
    assert main(["--until", "250", "--plot", str(tmp_path / "c.png"), f"both={both}"]) == 0
    assert (tmp_path / "c.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="no evaluation on train instructions at or before 50"):
        run_command(["--until", "50", f"long={tmp_path / 'long'}"])
    assert "LABEL=FOLDER" in _error(capsys, main, ["--until", "50", str(tmp_path / "long")])


def test_finetuned_bert_drift_measures_weight_change_and_grouping(tmp_path):
    from experiments.analysis.finetuned_bert_drift import goal_grouping, relative_change, run_command
    from talar_jax.agent import AgentError

    pretrained = {"a": np.ones((3, 4)), "b": {"c": -2 * np.ones(5)}}
    assert abs(relative_change(jax.tree.map(lambda x: 1.1 * x, pretrained), pretrained) - 0.1) < 1e-6
    goals = np.array([0, 0, 1, 1, 0, 1])
    is_train = np.array([True, True, True, True, False, False])
    tight = np.array([[0.0, 0], [0.1, 0], [5, 5], [5, 5.1], [0, 0.1], [5.1, 5]])
    assert goal_grouping(tight, goals, is_train) == pytest.approx(
        {"silhouette": 0.98, "test_nearest_goal": 1.0}, abs=0.02
    )
    folder = tmp_path / "bert-binary"
    (folder / "ifp").mkdir(parents=True)
    (folder / "ifp" / "stage.json").write_text("{}")
    (folder / "config.json").write_text(json.dumps({"method": "bert-binary", "env": "kitchen"}))
    with pytest.raises(AgentError, match="is a bert-binary run, not a finetuned-bert"):
        run_command([str(folder)])


def test_translator_robustness_agreement_and_the_swapped_translator():
    from experiments.analysis.translator_robustness import SwappedTranslator, agreement

    goal_codes = {0: np.array([1.0, 0.0]), 1: np.array([0.0, 1.0])}
    codes = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    assert agreement(codes, np.array([0, 1, 1]), goal_codes) == pytest.approx(2 / 3)
    assert agreement(codes[:1], np.array([5]), goal_codes) == 0.0  # a goal without a training code never agrees

    class Policy:
        def success_rate(self, *args, **kwargs):
            return ("success", args, kwargs)

    swapped = SwappedTranslator(Policy(), lambda features: 2 * features, goal_codes)
    np.testing.assert_array_equal(swapped.translate_features(np.ones(3)), [2.0, 2.0, 2.0])
    np.testing.assert_array_equal(swapped.goal_code(np.int64(1)), goal_codes[1])
    assert swapped.success_rate(1, key=2) == ("success", (1,), {"key": 2})  # the run's own policy


def test_encoder_neighbours_classifies_by_nearest_sentence_and_centroid(tmp_path, capsys):
    from experiments.analysis.encoder_neighbours import classify, kitchen_sentences, main

    names, train, held_out = kitchen_sentences()
    assert len(names) == 6 and {name for _, name in train} == {name for _, name in held_out} == set(names)

    def unit(rows):
        rows = np.asarray(rows, float)
        return rows / np.linalg.norm(rows, axis=1, keepdims=True)

    train_rows = unit([[1, 0, 0], [0.6, 0.8, 0], [0, 1, 0], [0, 0, 1]])
    train_goals = np.array([0, 0, 1, 2])
    # nearest training sentence: goal 0's second sentence (0.6, 0.8); nearest centroid: goal 1's
    nearest, centroid = classify(train_rows, train_goals, unit([[0.5, 0.9, 0], [0.1, 0, 1]]))
    np.testing.assert_array_equal(nearest, [0, 2])
    np.testing.assert_array_equal(centroid, [1, 2])
    assert main([str(tmp_path / "nowhere")]) == 2  # without sentence-transformers, or without the folder
    assert capsys.readouterr().err.startswith("error: ")
