"""What the complete kitchen costs: env steps/s of the kitchen model before the hinge doors swung (commit 3ffadf1),
now (swinging doors, 6 more contact pairs), and now with ``arm_collisions`` (16 more pairs), timed in one run.

    python -m benchmarks.kitchen_model_cost [--quick]

The "before" rows run in a subprocess on a ``git worktree`` of the earlier commit (same machine, same benchmark
function ``benchmarks.env_sps.time_backend``); rows are interleaved over ``--repeats`` rounds (MJX, which
compiles for minutes, in the first round only) and the table gives the median steps/s and each variant's ratio to
the doors-static model. Writes ``benchmarks/results/kitchen_model_cost.json``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.env_sps import BENCH_CONFIGS, RESULTS_DIR, time_backend
from experiments.cli import ArgumentParser, exit_status
from talar_jax import runtime

BEFORE_COMMIT = "3ffadf1"
VARIANTS = {
    "doors static (before)": None,
    "doors swing (now)": {},
    "doors swing + arm_collisions": {"arm_collisions": True},
}
_SNIPPET = (
    "import json, sys; from benchmarks.env_sps import BENCH_CONFIGS, time_backend; "
    "print(json.dumps(time_backend('kitchen', sys.argv[1], int(sys.argv[2]), BENCH_CONFIGS['kitchen'], "
    "float(sys.argv[3]))))"
)


def _time_before(worktree: Path, physics: str, batch: int, seconds: float) -> float:
    out = subprocess.run(
        [sys.executable, "-c", _SNIPPET, physics, str(batch), str(seconds)],
        cwd=worktree,
        capture_output=True,
        text=True,
        check=True,
        env={"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=false", "PATH": "/usr/bin:/bin"},
    )
    return json.loads(out.stdout.strip().splitlines()[-1])["steps_per_s"]


def main() -> None:
    runtime.configure(compile_cache=False)  # compile time is part of what benchmarks report
    parser = ArgumentParser(prog="python -m benchmarks.kitchen_model_cost", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="one round, short timing windows")
    parser.add_argument(
        "--repeats", type=int, default=3, help="timing rounds of the C rows; the median counts (default: 3)"
    )
    args = parser.parse_args()
    rows = [("c", 64), ("mjx", 64)] if not args.quick else [("c", 64)]
    repeats, seconds = (1, 1.0) if args.quick else (args.repeats, 3.0)
    config = BENCH_CONFIGS["kitchen"]
    samples: dict[tuple[str, str, int], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        worktree = Path(tmp) / "before"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(worktree), BEFORE_COMMIT], check=True, capture_output=True
        )
        try:
            for round_ in range(repeats):
                for physics, batch in rows if round_ == 0 else [row for row in rows if row[0] == "c"]:
                    for name, options in VARIANTS.items():
                        if options is None:
                            sps = _time_before(worktree, physics, batch, seconds)
                        else:
                            sps = time_backend("kitchen", physics, batch, config, seconds, options)["steps_per_s"]
                        samples.setdefault((name, physics, batch), []).append(sps)
                        print(
                            f"  round {round_ + 1}: {name:<30} {physics:>4} batch {batch}: {sps:8.0f} steps/s",
                            flush=True,
                        )
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(worktree)], check=False, capture_output=True)
    results = []
    for physics, batch in rows:
        base = float(np.median(samples[("doors static (before)", physics, batch)]))
        for name in VARIANTS:
            median = float(np.median(samples[(name, physics, batch)]))
            results.append(
                {
                    "variant": name,
                    "physics": physics,
                    "batch": batch,
                    "steps_per_s": median,
                    "ratio_to_before": median / base,
                    "samples": samples[(name, physics, batch)],
                }
            )
    print(f"\nkitchen env steps/s (median of {repeats}; random actions, training wrappers)")
    print(f"{'variant':<32}{'physics':>8}{'batch':>7}{'steps/s':>10}{'x before':>10}")
    for row in results:
        print(
            f"{row['variant']:<32}{row['physics']:>8}{row['batch']:>7}{row['steps_per_s']:>10.0f}{row['ratio_to_before']:>10.2f}"
        )
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"kitchen_model_cost{'_quick' if args.quick else ''}.json"
    path.write_text(json.dumps({"before_commit": BEFORE_COMMIT, "rows": results}, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(exit_status(main))
