"""Paper Fig. 11: t-SNE of every representation on training and test instructions, from finished runs.

``python -m experiments.tsne RUN_DIR [RUN_DIR ...] [--out FIGURE.png] [--seed 0]``

Each RUN_DIR is a finished run of one env (a run root such as ``runs/clevr`` or a method folder such as
``runs/compare-clevr/bert-binary``). One row per run: the codes its seed gives every instruction of the env (the
translated TL for TALAR, the Handcrafted / GLA codes, the trained encoding layer of BERT-*), one t-SNE over both sets,
shown as a training and a test panel; beside the figure, ``<out>.json`` and the printout give each run's share of test
instructions whose nearest training codes name their goal. The figure goes to ``--out``, by default
``tsne-seed<K>.png`` in the first RUN_DIR (beside the runs it draws, apart from the ``tsne.png`` a run or a comparison
writes itself). ``experiments.compare`` writes the same figure for its methods.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from experiments.cli import POSITIONAL, check_outputs, command, parse
from experiments.methods import method_label
from experiments.recipes import get_recipe
from experiments.reports import trained_codes
from talar_jax import runtime
from talar_jax.agent import AgentError, find_method_folder
from talar_jax.checkpoint import write_json_atomic
from talar_jax.language import build_cache, load_encoder
from talar_jax.report import plot_tsne_grid


@dataclasses.dataclass(frozen=True)
class TsneArgs:
    run_dirs: tuple[Path, ...] = dataclasses.field(metadata=POSITIONAL)
    """Finished run folders of one env (run roots or method folders)."""
    out: Path | None = None
    """The figure to write, with its record beside it (<out>.json); default: tsne-seed<K>.png in the first
    RUN_DIR."""
    seed: int = 0
    """Which seed's codes to project."""

    def figure(self) -> Path:
        """The figure's path: ``--out``, or ``tsne-seed<K>.png`` in the first run folder."""
        if self.out is not None:
            return self.out
        return (self.run_dirs[0] if self.run_dirs else Path(".")) / f"tsne-seed{self.seed}.png"


def nearest_training_goal_accuracy(codes: np.ndarray, goal_ids: np.ndarray, is_train: np.ndarray) -> float:
    """Fraction of test instructions whose nearest training instructions (Euclidean, in code space) name their goal:
    the goals most common among the training codes at the smallest distance, ties between goals counted fractionally.
    1.0 when every test phrasing lands on its goal's training codes (what Fig. 11's clusters show by eye)."""
    codes = np.asarray(codes, np.float64)
    train, test = codes[is_train], codes[~is_train]
    train_goals, test_goals = goal_ids[is_train], goal_ids[~is_train]
    num_goals = int(goal_ids.max()) + 1
    distances = np.linalg.norm(test[:, None, :] - train[None, :, :], axis=-1)
    nearest = distances <= distances.min(axis=1, keepdims=True) + 1e-6
    score = 0.0
    for row, goal in enumerate(test_goals):
        votes = np.bincount(train_goals[nearest[row]], minlength=num_goals)
        winners = np.flatnonzero(votes == votes.max())
        score += float(goal in winners) / len(winners)
    return score / len(test_goals)


def goal_grouping(codes: np.ndarray, goals: np.ndarray, is_train: np.ndarray) -> dict:
    """How tightly codes group by goal: over the training rows the silhouette by goal (scikit-learn, Euclidean; 1 =
    each goal a tight, separate group), the mean distance between two instructions of one goal over the mean distance
    between instructions of different goals, the number of distinct (rounded) codes per goal; and the test rows'
    ``nearest_training_goal_accuracy``."""
    from scipy.spatial.distance import cdist
    from sklearn.metrics import silhouette_score

    train, train_goals = codes[is_train], goals[is_train]
    distances = cdist(train, train)
    same = train_goals[:, None] == train_goals[None, :]
    within = distances[same & ~np.eye(len(train), dtype=bool)].mean()
    rounded = np.round(train, 3)
    return {
        "silhouette": float(silhouette_score(train, train_goals)),
        "within_over_between": float(within / distances[~same].mean()),
        "distinct_codes_per_goal": [len(np.unique(rounded[train_goals == g], axis=0)) for g in np.unique(train_goals)],
        "test_nearest_goal": float(nearest_training_goal_accuracy(codes, goals, is_train)),
    }


def write_tsne_grid(folders: Sequence[Path], path: Path, seed: int = 0) -> tuple[Path, list[str]]:
    """Fig. 11 for the runs in ``folders`` (method folders of one env) at ``path``; returns the path and the labels of
    runs left out (methods without a sentence encoding, e.g. One-hot). Raises ``AgentError`` for a folder that is
    not a finished run, runs of different envs, or when no run has codes."""
    configs = {folder: json.loads((folder / "config.json").read_text()) for folder in folders}
    env_names = {config["env"] for config in configs.values()}
    if len(env_names) != 1:
        raise AgentError(f"the runs are of different envs ({', '.join(sorted(env_names))}); give runs of one env")
    env = env_names.pop()
    encodings, skipped = {}, []
    for folder, config in configs.items():
        if not 0 <= seed < int(config["seeds"]):
            raise AgentError(f"--seed must lie in 0..{int(config['seeds']) - 1} for {folder}, got {seed}")
        label = method_label(config["method"])
        codes = trained_codes(folder, seed)
        if codes is None:
            skipped.append(label)
        else:
            encodings[label if label not in encodings else f"{label} ({folder})"] = codes
    if not encodings:
        raise AgentError(f"none of the runs has instruction codes to project (left out: {', '.join(skipped)})")
    encoder = next(iter(configs.values())).get("encoder")
    cache = build_cache(env, load_encoder(encoder), progress=False)
    accuracy = {
        label: nearest_training_goal_accuracy(codes, cache.goal_ids, cache.is_train)
        for label, codes in encodings.items()
    }
    for label, value in accuracy.items():
        print(f"{label}: test instructions whose nearest training codes name their goal {100 * value:.1f} %")
    write_json_atomic(
        path.with_suffix(".json"),
        {"env": env, "seed": seed, "folders": [str(f) for f in folders], "nearest_training_goal": accuracy},
    )
    plot_tsne_grid(
        {f"{label} (NN goal {100 * accuracy[label]:.0f} %)": v for label, v in encodings.items()},
        cache.goal_ids,
        cache.is_train,
        path,
        title=f"{env}: instruction codes, seed {seed}",
        label_names=get_recipe(env).goal_names(),
    )
    return path, skipped


def tsne(args: TsneArgs) -> Path:
    if not args.run_dirs:
        raise AgentError("give at least one run folder")
    folders = [find_method_folder(run_dir, prefer="talar") for run_dir in args.run_dirs]
    for folder in folders:
        if not (folder / "ifp" / "stage.json").is_file():
            raise AgentError(f"the run in {folder} is not finished (its ifp stage has no stage.json)")
    args.figure().parent.mkdir(parents=True, exist_ok=True)
    path, skipped = write_tsne_grid(folders, args.figure(), args.seed)
    print(f"wrote {path}" + (f" (left out, no sentence encoding: {', '.join(skipped)})" if skipped else ""))
    return path


def run_command(argv: list[str] | None = None) -> Path:
    """``python -m experiments.tsne`` for Python callers: the figure's path. A bad option or output path raises
    ``experiments.cli.UsageError`` before any run is read."""
    runtime.start()
    args = parse(TsneArgs, argv, description=__doc__)
    figure = args.figure()
    check_outputs((figure, "--out", "file"), (figure.with_suffix(".json"), "--out", "file"))
    return tsne(args)


main = command(run_command, bad_input=(AgentError,))

if __name__ == "__main__":
    raise SystemExit(main())
