"""Where an example's result came from: the command line (shell-quoted) and the checkout's commit."""

from __future__ import annotations

import shlex
import subprocess
import sys


def git_commit() -> str | None:
    """The checkout's commit (None outside a git checkout)."""
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return out.stdout.strip()


def provenance() -> dict[str, str | None]:
    """``{"command": ..., "commit": ...}`` of the running example."""
    return {"command": "python " + shlex.join(sys.argv), "commit": git_commit()}
