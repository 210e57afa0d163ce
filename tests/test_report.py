"""Run reports: learning-curve and t-SNE figures are written, the results table shows mean ± std."""

import numpy as np

from talar_jax.report import LearningCurve, plot_learning_curves, plot_tsne, results_table


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


def test_results_table_mean_and_std():
    table = results_table({"TALAR": {"train": np.array([1.0, 0.9]), "test": np.array([0.5])}}, title="x")
    assert "| TALAR | 95.0 ± 5.0 (n=2) | 50.0 ± 0.0 (n=1) |" in table
    assert table.splitlines()[2].startswith("| method | train instructions (%) | test instructions (%)")
