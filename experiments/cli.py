"""What every command does with bad input: one ``error: ...`` line on stderr and exit status 2, before any work."""

from __future__ import annotations

import argparse
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


def env_argument(argv: list[str] | None, default: str) -> str:
    """The ``--env`` of a command line whose other defaults are that env's recipe (``default`` when absent).

    tyro has no defaults that depend on another option's value, so the commands that take ``--env`` (compare,
    patterns, study) read it first with argparse, which leaves every other option, ``--help`` included, to tyro.
    """
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--env", default=default)
    known, _ = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    return known.env


CLI_CONFIG = (tyro.conf.AvoidSubcommands,)
"""tyro settings of every command: optional nested configs (``--talar.*``, ``--ifp.*``) stay plain options."""
