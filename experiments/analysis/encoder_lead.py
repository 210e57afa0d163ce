"""TALAR's lead over the natural-language baselines against how much the text encoder already groups phrasings by goal.

    python -m experiments.analysis.encoder_lead [--env clevr] [--root runs/paper] [--out results/encoder-lead]

For the default encoder (all-MiniLM-L6-v2) and each of ``ENCODER_VARIANTS`` (the same network read out in ways it was
not trained for, and with random weights), on one env (CLEVR by default):

- its **agreement**: the share of test instructions whose nearest training instruction (cosine between the encoder's
  sentence embeddings, which is what the BERT baselines read) names the same goal;
- from the finished comparisons under ``--root`` (``experiments.paper`` makes them: ``compare-ENV`` for the default
  encoder and One-hot, which reads no encoder; ``encoders-ENV/NAME`` for the others), each method's final success
  on test instructions and TALAR's lead over the best baseline, in points.

Writes ``encoder_lead.json``, ``encoder_lead.md`` and ``encoder_lead.png`` (lead against agreement, the paper's +13.4
marked) into ``--out``. An encoder whose runs have not finished is listed with its agreement alone.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from experiments.cli import ArgumentParser, command
from experiments.recipes import get_recipe, recipe_names
from experiments.tsne import nearest_training_goal_accuracy
from talar_jax import runtime
from talar_jax.language import load_encoder, load_instructions
from talar_jax.language.encoder import DEFAULT_ENCODER_NAME, ENCODER_VARIANTS

BASELINES: tuple[str, ...] = ("bert-binary", "bert-continuous", "onehot")


def paper_lead(env: str) -> float:
    """The paper's TALAR lead over its best baseline on the env's test instructions (Fig. 4), in points."""
    return get_recipe(env).paper_margin


def agreement(encoder_name: str | None, env: str = "clevr") -> float:
    """Share of the env's test instructions whose nearest training instruction, by the encoder's sentence embedding,
    names their goal (ties between goals counted fractionally)."""
    instructions = load_instructions(env, "all")
    embeddings = load_encoder(encoder_name).encode(list(instructions.sentences))
    return nearest_training_goal_accuracy(embeddings, instructions.goal_ids, instructions.is_train)


def final_test_success(folder: Path) -> float | None:
    """Mean over seeds of a finished method run's final success on test instructions, in %; None if not finished."""
    summary = folder / "summary.json"
    if not summary.is_file():
        return None
    return 100 * float(np.mean(json.loads(summary.read_text())["final_success"]["test"]))


def encoder_row(name: str, folder: Path, onehot: float | None, env: str = "clevr") -> dict:
    """One encoder's agreement, methods' success and TALAR's lead (None where a run has not finished)."""
    success = {method: final_test_success(folder / method) for method in ("talar", *BASELINES[:2])}
    success["onehot"] = onehot
    baselines = [success[m] for m in BASELINES if success[m] is not None]
    finished = success["talar"] is not None and len(baselines) == len(BASELINES)
    return {
        "encoder": name,
        "agreement": agreement(None if name == DEFAULT_ENCODER_NAME else name, env),
        "success_test": success,
        "lead": success["talar"] - max(baselines) if finished else None,
        "runs": str(folder),
    }


def lead_table(rows: list[dict], env: str = "clevr") -> str:
    """Markdown: one row per encoder, agreement, each method's test success and TALAR's lead."""
    header = "| encoder | agreement (%) | TALAR | BERT-binary | BERT-continuous | One-hot | TALAR's lead (points) |"
    lines = [header, "|---|---|---|---|---|---|---|"]
    cell = lambda value, fmt: "not finished" if value is None else format(value, fmt)  # noqa: E731
    for row in rows:
        rates = [cell(row["success_test"][m], ".1f") for m in ("talar", *BASELINES)]
        lead = cell(row["lead"], "+.1f")
        lines.append(f"| {row['encoder']} | {100 * row['agreement']:.1f} | {' | '.join(rates)} | {lead} |")
    return "\n".join(lines) + f"\n\nThe paper's lead on {env}: +{paper_lead(env)} points.\n"


def plot_lead(rows: list[dict], path: Path, env: str = "clevr") -> Path:
    """Lead against agreement, one labelled point per finished encoder, the paper's lead as a dashed line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for row in rows:
        if row["lead"] is not None:
            ax.scatter(100 * row["agreement"], row["lead"], color="C0")
            ax.annotate(row["encoder"], (100 * row["agreement"], row["lead"]), fontsize=8, xytext=(4, 4),
                        textcoords="offset points")  # fmt: skip
    ax.axhline(paper_lead(env), color="C3", linestyle="--", label=f"the paper's lead (+{paper_lead(env)})")
    ax.axhline(0, color="grey", linewidth=0.8)
    ax.set_xlabel("test phrasings next to their goal's training phrasing (%)")
    ax.set_ylabel("TALAR's lead over the best baseline (points)")
    ax.set_title(f"{env}, test instructions")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def run_command(argv: list[str] | None = None) -> None:
    runtime.start()
    parser = ArgumentParser(prog="python -m experiments.analysis.encoder_lead", description=__doc__.splitlines()[0])
    parser.add_argument("--env", choices=recipe_names(), default="clevr", help="the env (default: clevr)")
    parser.add_argument("--root", type=Path, default=Path("runs/paper"), help="experiments.paper's root folder")
    parser.add_argument("--out", type=Path, default=Path("results/encoder-lead"), help="where the outputs go")
    args = parser.parse_args(argv)
    env = args.env
    onehot = final_test_success(args.root / f"compare-{env}" / "onehot")
    folders = {DEFAULT_ENCODER_NAME: args.root / f"compare-{env}"}
    folders.update({name: args.root / f"encoders-{env}" / name for name in ENCODER_VARIANTS})
    rows = [encoder_row(name, folder, onehot, env) for name, folder in folders.items()]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "encoder_lead.json").write_text(json.dumps(rows, indent=1) + "\n")
    table = lead_table(rows, env)
    (args.out / "encoder_lead.md").write_text(table)
    plot_lead(rows, args.out / "encoder_lead.png", env)
    print(table)


main = command(run_command)

if __name__ == "__main__":
    raise SystemExit(main())
