"""Figures and tables of a run: learning curves like the paper's Fig. 4, t-SNE like Fig. 5a, a results table."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

LANGUAGE_RECORD = "language.json"
"""A run folder's record of the text encoder and language cache it trained with (written by the pipeline, read by
the agent)."""

REPORT_FILES = ("config.json", "results.md", "summary.json", "curves.png", "tsne.png", "deployment.png")
"""A run folder's report files (tsne.png and deployment.png only where the method has codes to show)."""
RECORD_FILES = (*REPORT_FILES, LANGUAGE_RECORD)
"""The method folder's files a results/ record keeps and puts back (``experiments.records record`` / ``restore``)."""


@dataclass(frozen=True)
class LearningCurve:
    """Success rate over env steps for one method, all seeds.

    Attributes:
        env_steps: (T,) env steps at each evaluation.
        success: split name ("train", "test") -> (num_seeds, T) success rates in [0, 1].
    """

    env_steps: np.ndarray
    success: Mapping[str, np.ndarray]


@dataclass(frozen=True)
class GoalCurves:
    """Success per goal over env steps, pooled over seeds (one method, one instruction split).

    Attributes:
        env_steps: (T,) env steps at each evaluation.
        success: (T, num_goals) success rates in [0, 1]; NaN where a goal had no episode.
        names: (num_goals,) goal names.
        split: the instruction split evaluated.
    """

    env_steps: np.ndarray
    success: np.ndarray
    names: Sequence[str]
    split: str = "train"


def plot_learning_curves(
    curves: Mapping[str, LearningCurve], path: str | Path, title: str = "", per_goal: GoalCurves | None = None
) -> Path:
    """One panel per instruction split; mean +- std over seeds per method (Fig. 4 style). Writes a PNG.

    With ``per_goal`` a last panel draws one line per goal (e.g. kitchen's six sub-tasks), so a stalled goal shows.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    splits = sorted({split for curve in curves.values() for split in curve.success}, key=["train", "test"].index)
    panels = len(splits) + (per_goal is not None)
    fig, axes = plt.subplots(1, panels, figsize=(5 * panels, 3.6), squeeze=False)
    if per_goal is not None:
        ax = axes[0][-1]
        for goal, name in enumerate(per_goal.names):
            ax.plot(
                per_goal.env_steps,
                np.asarray(per_goal.success, float)[:, goal] * 100,
                label=name,
                **_points(per_goal.env_steps),
            )
        ax.set_title(f"per goal, pooled over seeds ({per_goal.split} instructions)")
        ax.set_xlabel("env steps")
        ax.set_ylabel("success rate (%)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax, split in zip(axes[0], splits, strict=False):
        for method, curve in curves.items():
            if split not in curve.success:
                continue
            rates = np.asarray(curve.success[split], float) * 100
            mean, std = rates.mean(0), rates.std(0)
            (line,) = ax.plot(curve.env_steps, mean, label=method, **_points(curve.env_steps))
            ax.fill_between(curve.env_steps, mean - std, mean + std, color=line.get_color(), alpha=0.2)
        ax.set_title(f"{title} ({split} instructions)".strip())
        ax.set_xlabel("env steps")
        ax.set_ylabel("success rate (%)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return _save(fig, path, dpi=120)


def _points(env_steps) -> dict:
    """Markers on a curve of few evaluations: a line through one point draws nothing, and a short run's curves (a
    ``--quick`` run evaluates once or twice) would look empty."""
    return {"marker": "o", "markersize": 4} if len(env_steps) <= 20 else {}


def _save(fig, path: str | Path, dpi: int) -> Path:
    """Lays out, writes and closes a figure; returns its path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def tsne_points(vectors: np.ndarray) -> np.ndarray:
    """(N, 2) t-SNE projection of (N, F) vectors, seeded.

    A small jitter separates identical points (the paper does the same), so identical TL stays visible. The inputs
    get a 1e-3 jitter too: sklearn's t-SNE divides by the data's variance and crashes (segfault in Barnes-Hut) when
    every vector is identical, e.g. a collapsed task language.
    """
    from sklearn.manifold import TSNE

    rng = np.random.default_rng(0)
    vectors = np.asarray(vectors, np.float64)
    vectors = vectors + rng.normal(scale=1e-3, size=vectors.shape)
    perplexity = float(min(30.0, max(2.0, (len(vectors) - 1) / 3)))
    # Exact gradients below 500 points: sklearn's Barnes-Hut took 23 s for 40 points on a busy 2-core machine (its
    # OpenMP threads spin), the exact method 0.24 s; above, Barnes-Hut is the cheaper one (1440 points: 43 vs 53 s).
    method = "exact" if len(vectors) < 500 else "barnes_hut"
    tsne = TSNE(n_components=2, perplexity=perplexity, init="pca", random_state=0, method=method)
    points = tsne.fit_transform(vectors)
    return points + rng.normal(scale=0.01 * points.std(), size=points.shape)


def _scatter_goals(ax, points: np.ndarray, labels: np.ndarray, label_names: Sequence[str] | None, legend: bool):
    """One marker / colour per goal, as Fig. 5; the goal of a label keeps its style across panels."""
    import matplotlib.pyplot as plt

    markers = "o^sDvP*Xh<>p"
    cmap = plt.get_cmap("tab20")
    for label in np.unique(labels):
        mask = labels == label
        name = label_names[int(label)] if label_names is not None else str(label)
        i = int(label)
        ax.scatter(*points[mask].T, s=14, marker=markers[i % len(markers)], color=cmap(i % 20), label=name)
    if legend and len(np.unique(labels)) <= 12:
        ax.legend(fontsize=7, loc="best")
    ax.set_xticks([])
    ax.set_yticks([])


def plot_tsne(
    vectors: np.ndarray, labels: np.ndarray, path: str | Path, title: str = "", label_names: Sequence[str] | None = None
) -> Path:
    """t-SNE projection of instruction encodings, one marker/colour per goal (Fig. 5 style). Writes a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = tsne_points(vectors)
    fig, ax = plt.subplots(figsize=(5.5, 5))
    _scatter_goals(ax, points, np.asarray(labels), label_names, legend=True)
    ax.set_title(title)
    return _save(fig, path, dpi=120)


def plot_tsne_grid(
    encodings: Mapping[str, np.ndarray],
    labels: np.ndarray,
    is_train: np.ndarray,
    path: str | Path,
    title: str = "",
    label_names: Sequence[str] | None = None,
) -> Path:
    """Paper Fig. 11: one row per representation, columns training / test instructions. Each row is one t-SNE of
    that representation's codes of every instruction (both sets, so the two panels share axes: a test phrasing that
    lands in its goal's training cluster shows there). Writes a PNG.

    Args:
        encodings: representation name -> (S, size) codes of every instruction.
        labels: (S,) goal of each instruction.
        is_train: (S,) True for training instructions.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not encodings:
        raise ValueError("plot_tsne_grid needs at least one representation")
    labels, is_train = np.asarray(labels), np.asarray(is_train, bool)
    fig, axes = plt.subplots(len(encodings), 2, figsize=(8, 3.6 * len(encodings)), squeeze=False)
    for row, (name, vectors) in enumerate(encodings.items()):
        points = tsne_points(vectors)
        for col, (split, mask) in enumerate((("training", is_train), ("test", ~is_train))):
            ax = axes[row, col]
            _scatter_goals(ax, points[mask], labels[mask], label_names, legend=row == 0 and col == 0)
            if row == 0:
                ax.set_title(f"{split} instructions", fontsize=10)
            if col == 0:  # the representation names its row (long names overlapped as panel titles)
                ax.set_ylabel(name, fontsize=9)
    if title:
        fig.suptitle(title)
    return _save(fig, path, dpi=110)


def counted(number: int, noun: str) -> str:
    """``number`` and ``noun``, plural unless one: "1 seed", "5 seeds"."""
    return f"{number:,} {noun}{'' if number == 1 else 's'}"


def percent_cell(rates: Sequence[float] | np.ndarray) -> str:
    """``mean ± std`` in % of success rates in [0, 1] (one per seed), as every results table shows them."""
    percent = 100 * np.asarray(rates, float)
    return f"{percent.mean():.1f} ± {percent.std():.1f}"


def results_table(final: Mapping[str, Mapping[str, np.ndarray]], title: str = "") -> str:
    """Markdown table of final success rates: method -> split -> (num_seeds,) rates in [0, 1]."""
    splits = sorted({s for per_split in final.values() for s in per_split}, key=["train", "test"].index)
    lines = [f"### {title}", ""] if title else []
    lines += ["| method | " + " | ".join(f"{s} instructions (%)" for s in splits) + " |"]
    lines += ["|---|" + "---|" * len(splits)]
    for method, per_split in final.items():
        cells = []
        for split in splits:
            rates = np.asarray(per_split.get(split, []), float)
            cells.append(f"{percent_cell(rates)} (n={rates.size})" if rates.size else "-")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot_deployment_strip(rows: Sequence[tuple[str, Sequence[np.ndarray]]], path: str | Path, title: str = "") -> Path:
    """Paper Fig. 17/18 style: one row of frames per instruction (its sentence as the row's title), a PNG.

    Args:
        rows: (label, frames) per row; frames are (H, W, 3) uint8 images, the same count in every row.
        path: output file.
        title: figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = max(len(frames) for _, frames in rows)
    height, width = rows[0][1][0].shape[:2]
    panel = 2.4  # inches per frame's width
    figure, axes = plt.subplots(
        len(rows), columns, figsize=(panel * columns, (panel * height / width + 0.3) * len(rows) + 0.4), squeeze=False
    )
    figure.subplots_adjust(
        left=0.01, right=0.99, bottom=0.01, top=1 - 0.5 / figure.get_figheight(), wspace=0.03, hspace=0.25
    )
    for r, (label, frames) in enumerate(rows):
        for c in range(columns):
            axis = axes[r, c]
            axis.axis("off")
            if c < len(frames):
                axis.imshow(frames[c])
        axes[r, 0].text(0.0, 1.04, label, transform=axes[r, 0].transAxes, fontsize=8, va="bottom", clip_on=False)
    if title:
        figure.suptitle(title, fontsize=10)
    path = Path(path)
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path
