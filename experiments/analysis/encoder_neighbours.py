"""Does a sentence encoder put each kitchen development phrasing next to its own sub-task's training sentences?

    python -m experiments.analysis.encoder_neighbours ENCODER_FOLDER [ENCODER_FOLDER ...]

For every sentence-transformers folder given, embeds the kitchen's training instructions and our development
phrasings (``talar_jax/language/data/development.json``; never trained on) and classifies each development phrasing
by its nearest training sentence and by its nearest sub-task centroid (cosine). Prints both accuracies and every
miss. This asks whether an encoder *could* tell the burners apart by position words the training sentences never use
("front", "back", "lower"): a translator trained on training sentences only cannot know more than its encoder.

Runs outside the project's environment (from the checkout's root, in any Python with numpy): it needs
``sentence-transformers`` (and torch), which talar-jax does not depend on, and imports nothing else of the project;
results/unseen-phrasings.md gives the commands used for all-MiniLM-L6-v2 and all-mpnet-base-v2.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from experiments.cli import ArgumentParser, UsageError, command

DATA = Path(__file__).resolve().parents[2] / "talar_jax" / "language" / "data"


def kitchen_sentences() -> tuple[list[str], list[tuple[str, str]], list[tuple[str, str]]]:
    """Sub-task names, (training sentence, sub-task) and (development sentence, sub-task) pairs."""
    subtasks = json.loads((DATA / "instructions.json").read_text())["kitchen"]["subtasks"]
    development = json.loads((DATA / "development.json").read_text())["kitchen"]
    names = list(subtasks)
    train = [(sentence, name) for name in names for sentence in subtasks[name]["train"]]
    held_out = [(sentence, name) for name in names for sentence in development[name]]
    return names, train, held_out


def classify(train: np.ndarray, train_goals: np.ndarray, held_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-training-sentence and nearest-centroid goal of each held-out embedding (rows L2-normalised)."""
    nearest = train_goals[(held_out @ train.T).argmax(1)]
    centroids = np.stack([train[train_goals == goal].mean(0) for goal in range(train_goals.max() + 1)])
    centroids /= np.linalg.norm(centroids, axis=1, keepdims=True)
    return nearest, (held_out @ centroids.T).argmax(1)


def run_command(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(prog="python -m experiments.analysis.encoder_neighbours", description=__doc__)
    parser.add_argument("encoders", nargs="+", metavar="ENCODER_FOLDER", help="a sentence-transformers model folder")
    folders = parser.parse_args(argv).encoders
    try:
        from sentence_transformers import SentenceTransformer
    except ImportError:
        raise UsageError("this probe needs sentence-transformers (pip install sentence-transformers)") from None
    missing = [folder for folder in folders if not Path(folder).is_dir()]
    if missing:
        raise UsageError(f"no such encoder folder: {missing[0]}")
    names, train, held_out = kitchen_sentences()
    train_goals = np.array([names.index(name) for _, name in train])
    goals = np.array([names.index(name) for _, name in held_out])
    for folder in folders:
        model = SentenceTransformer(folder, device="cpu")
        embed = lambda pairs: model.encode([s for s, _ in pairs], normalize_embeddings=True)  # noqa: E731
        for label, guess in zip(
            ("nearest sentence", "nearest centroid"), classify(embed(train), train_goals, embed(held_out))
        ):
            print(f"{folder} {label}: {int((guess == goals).sum())}/{len(goals)} development phrasings")
            for index in np.flatnonzero(guess != goals):
                print(f"  miss: {held_out[index][0]!r} ({held_out[index][1]}) -> {names[guess[index]]}")


main = command(run_command)

if __name__ == "__main__":
    raise SystemExit(main())
