"""Where a result came from: the command line and the checkout's commit, recorded in every summary.json."""

from __future__ import annotations

import functools
import shlex
import subprocess
import sys
from pathlib import Path


def git_commit(folder: str | Path | None = None) -> str | None:
    """The commit checked out in ``folder`` (default: this package's checkout), with ``-dirty`` when tracked files
    differ from it; None outside a git checkout."""
    cwd = Path(folder) if folder is not None else Path(__file__).resolve().parent
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True, check=True)
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=cwd,
            capture_output=True,
            text=True,
            check=True,
        )
    except (OSError, subprocess.CalledProcessError):
        return None
    return commit.stdout.strip() + ("-dirty" if status.stdout.strip() else "")


@functools.cache
def process_commit() -> str | None:
    """This package's checkout's commit (``git_commit()``), read on the first call and kept for the process: a command
    asks when it starts (``talar_jax.runtime.start``), so a long run whose checkout moves on while it trains (a commit,
    an edit) still names the code it started with."""
    return git_commit()


def provenance() -> dict[str, str | None]:
    """``{"command": ..., "commit": ...}`` of the running process; the commit is ``process_commit()``: the one checked
    out when the process started, not the one at the time of the call."""
    return {"command": "python " + shlex.join(sys.argv), "commit": process_commit()}
