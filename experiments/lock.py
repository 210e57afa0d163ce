"""A run folder belongs to one command at a time: an OS file lock on ``<folder>/.lock``.

``hold(folder)`` takes an exclusive ``fcntl.flock`` on the folder's lock file for the ``with`` block and writes the
holder (pid, command line, start time) into it; the operating system releases the lock when the process ends in any
way (``kill -9`` included), so no stale lock is ever left to clean up. A second process asking for a held folder
gets ``FolderInUseError`` at once, naming the holder. Within one process the lock is re-entrant: a command that
holds its folder may call ``experiments.pipeline.run`` on it again and again (compare, patterns, study).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shlex
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from experiments.cli import UsageError, program

LOCK_FILE = ".lock"

_held: dict[str, list[int]] = {}
"""Resolved folder -> [file descriptor, depth] of the locks this process holds."""
_guard = threading.Lock()


class FolderInUseError(UsageError):
    """The run folder is held by another process (the message names the folder and that process). A command stops on
    it as on any bad input: one ``error:`` line, exit status 2, nothing written."""


def holder(folder: str | Path) -> dict[str, Any] | None:
    """What the lock file of ``folder`` says about its holder (pid, command, started), or None when it says
    nothing readable. Only meaningful while the lock is held: a released lock file is emptied."""
    try:
        text = (Path(folder) / LOCK_FILE).read_text()
        record = json.loads(text) if text.strip() else None
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def _describe(folder: Path) -> str:
    record = holder(folder) or {}
    pid = record.get("pid")
    who = f"process {pid}" if pid else "another process"
    command = record.get("command")
    running = f" ({command})" if command else ""
    return f"{folder} is in use by {who}{running}; wait for it to end or use another folder"


def _command_line() -> str:
    return " ".join([program(), *(shlex.quote(arg) for arg in sys.argv[1:])])


@contextlib.contextmanager
def hold(folder: str | Path) -> Iterator[Path]:
    """Holds ``folder``'s lock for the ``with`` block (creating the folder and its lock file when missing); raises
    ``FolderInUseError`` at once when another process holds it. Re-entrant within a process."""
    folder = Path(folder)
    key = str(folder.resolve())
    with _guard:
        if key in _held:
            _held[key][1] += 1
        else:
            folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise FolderInUseError(_describe(folder)) from None
            record = {"pid": os.getpid(), "command": _command_line(), "started": time.strftime("%Y-%m-%dT%H:%M:%S")}
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(record) + "\n").encode(), 0)
            _held[key] = [fd, 1]
    try:
        yield folder
    finally:
        with _guard:
            entry = _held[key]
            entry[1] -= 1
            if entry[1] == 0:
                del _held[key]
                with contextlib.suppress(OSError):
                    os.ftruncate(entry[0], 0)
                os.close(entry[0])  # releases the lock
