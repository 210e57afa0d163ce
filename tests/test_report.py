"""Run reports: learning-curve and t-SNE figures are written, the results table shows mean ± std."""

from pathlib import Path

import numpy as np
import pytest

from talar_jax.report import LearningCurve, plot_learning_curves, plot_tsne, plot_tsne_grid, results_table, tsne_points


def test_learning_curve_and_tsne_figures(tmp_path):
    steps = np.arange(5) * 1000
    curve = LearningCurve(steps, {"train": np.array([[0, 0.2, 0.5, 0.8, 1.0]] * 3), "test": np.zeros((3, 5))})
    path = plot_learning_curves({"TALAR": curve}, tmp_path / "curves.png", title="clevr")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    vectors = np.repeat(np.eye(4), 10, axis=0)
    path = plot_tsne(vectors, np.repeat(np.arange(4), 10), tmp_path / "tsne.png", label_names=list("abcd"))
    assert path.stat().st_size > 1000
    # A collapsed encoding (every vector identical) must still plot (it crashed sklearn's t-SNE before).
    path = plot_tsne(np.ones((40, 14)), np.repeat(np.arange(4), 10), tmp_path / "collapsed.png")
    assert path.stat().st_size > 1000


def test_a_curve_of_one_evaluation_is_drawn_with_markers(tmp_path, monkeypatch):
    """A --quick run evaluates once: a line through one point draws nothing, so few points get markers."""
    from talar_jax import report

    figures = []
    monkeypatch.setattr(report, "_save", lambda fig, path, dpi: figures.append(fig) or Path(path))
    one = LearningCurve(np.array([1000]), {"train": np.array([[0.5], [0.7]])})
    goals = report.GoalCurves(np.array([1000]), np.array([[0.5, 1.0]]), ["a", "b"])
    plot_learning_curves({"TALAR": one}, tmp_path / "one.png", per_goal=goals)
    long = LearningCurve(np.arange(100), {"train": np.zeros((2, 100))})
    plot_learning_curves({"TALAR": long}, tmp_path / "long.png")
    one_fig, long_fig = figures
    lines = [line for ax in one_fig.axes for line in ax.get_lines()]
    assert len(lines) == 3 and all(line.get_marker() == "o" for line in lines)
    assert [line.get_marker() for line in long_fig.axes[0].get_lines()] == ["None"]


def test_tsne_grid_rows_share_one_projection_per_representation(tmp_path):
    labels = np.tile(np.repeat(np.arange(4), 5), 2)
    is_train = np.arange(40) < 20
    clustered = np.repeat(np.eye(4), 5, axis=0)[np.tile(np.arange(20), 2)]
    scattered = np.random.default_rng(0).normal(size=(40, 6))
    path = plot_tsne_grid(
        {"TL": clustered, "BERT-binary": scattered}, labels, is_train, tmp_path / "fig11.png", label_names=list("abcd")
    )
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Goal clusters stay apart in the projection.
    points = tsne_points(clustered)
    centres = np.stack([points[labels == g].mean(0) for g in range(4)])
    spread = max(np.linalg.norm(points[labels == g] - centres[g], axis=1).max() for g in range(4))
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1)[~np.eye(4, dtype=bool)]
    assert gaps.min() > 3 * spread
    with pytest.raises(ValueError, match="at least one representation"):
        plot_tsne_grid({}, labels, is_train, tmp_path / "none.png")


def test_results_table_mean_and_std():
    table = results_table({"TALAR": {"train": np.array([1.0, 0.9]), "test": np.array([0.5])}}, title="x")
    assert "| TALAR | 95.0 ± 5.0 (n=2) | 50.0 ± 0.0 (n=1) |" in table
    assert table.splitlines()[2].startswith("| method | train instructions (%) | test instructions (%)")


def test_per_seed_goal_table_shows_the_lowest_seed_of_each_goal():
    from experiments.reports import per_seed_goal_table

    table = per_seed_goal_table([[1.0, 0.5, None], [0.9, 1.0, 1.0]], ["a", "b", "c"])
    lines = table.strip().splitlines()
    assert lines[0] == "| seed | a | b | c |"
    assert lines[2] == "| 0 | 100 | 50 | - |"
    assert lines[-1] == "| lowest | 90 | 50 | 100 |"
