"""How tightly a finished run's instruction codes group by goal, per seed (used for Fig. 12's aligned baselines).

    python -m experiments.analysis.code_grouping RUN_DIR

For every seed, over the codes of the training instructions (``experiments.reports.trained_codes``: the translated
TL, or the trained encoding layer of BERT-* and aligned BERT-*): the silhouette score by goal (scikit-learn; 1 = each
goal a tight, separate group), the mean distance between two instructions of one goal over the mean distance between
instructions of different goals, the number of distinct (rounded) codes per goal, and the share of test instructions
whose nearest training code names their goal (``experiments.tsne``). Distances make it meaningful for continuous codes
too, where counting distinct codes is not.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.cli import ArgumentParser, command
from experiments.reports import load_agent, trained_codes
from experiments.tsne import goal_grouping as grouping
from talar_jax import runtime
from talar_jax.agent import AgentError, find_method_folder


def run_command(argv: list[str] | None = None) -> None:
    runtime.start()
    parser = ArgumentParser(prog="python -m experiments.analysis.code_grouping", description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", help="a finished run folder (a run root such as runs/clevr, or its method folder)")
    args = parser.parse_args(argv)
    folder = find_method_folder(args.run_dir, prefer="talar")
    agent = load_agent(args.run_dir, seed=0)
    goals, is_train = agent.cache.goal_ids, agent.cache.is_train
    for seed in range(int(agent.config["seeds"])):
        row = grouping(np.asarray(trained_codes(Path(folder), seed), dtype=np.float64), goals, is_train)
        print(
            f"seed {seed}: silhouette {row['silhouette']:.2f}, "
            f"within/between distance {row['within_over_between']:.2f}, "
            f"distinct codes per goal {row['distinct_codes_per_goal']}, test next to their goal "
            f"{100 * row['test_nearest_goal']:.1f} %"
        )


main = command(run_command, bad_input=(AgentError,))

if __name__ == "__main__":
    raise SystemExit(main())
