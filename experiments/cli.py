"""What every command does with bad input: one ``error: ...`` line on stderr and exit status 2, before any work."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, TypeVar

import tyro

T = TypeVar("T")


def valid_or_exit(check: Callable[..., T], *args: Any) -> T:
    """``check(*args)``; a ``ValueError`` it raises becomes one ``error: ...`` line and ``SystemExit(2)``."""
    try:
        return check(*args)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from None


CLI_CONFIG = (tyro.conf.AvoidSubcommands,)
"""tyro settings of every command: optional nested configs (``--talar.*``, ``--ifp.*``) stay plain options."""
