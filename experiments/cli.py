"""What every command does with bad input: one ``error: ...`` line on stderr and exit status 2, before any work.

- ``parse_or_exit``: ``tyro.cli`` whose parse errors (a bad value, a typo'd option, a missing argument, a value a
  config's ``__post_init__`` rejects) become one ``error:`` line (a typo keeps tyro's "did you mean" hint on it),
  and whose help pages read as plain text (no double-backtick markup, no hard line breaks from the docstrings).
- ``ArgumentParser``: the same for the commands that parse with argparse.
- ``check_output_path``: an output path a command will write (``--out``, ``--video``, ``--json``) checked before any
  work: a file where a folder goes (or the reverse), a path under a file, a folder that cannot be written;
  ``write_output`` writes one once the work is done.
- ``hold_or_exit``: the run folder's lock (``experiments.lock``) for the command's life; a folder another command
  holds stops this one with one line naming that command.

The help text lives in ``experiments.help_text``, the condensing of tyro's errors in ``experiments.parse_errors``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import tyro

from experiments.help_text import PlainHelpFormatter, plain, plain_help, program
from experiments.parse_errors import parse_error_events, parse_error_message

T = TypeVar("T")

CLI_CONFIG = (tyro.conf.AvoidSubcommands,)
"""tyro settings of every command: optional nested configs (``--talar.*``, ``--ifp.*``) stay plain options."""


def fail(message: str) -> NoReturn:
    """One ``error: <message>`` line on stderr, then exit status 2."""
    print(f"error: {message}", file=sys.stderr, flush=True)
    raise SystemExit(2)


def valid_or_exit(check: Callable[..., T], *args: Any) -> T:
    """``check(*args)``; a ``ValueError`` it raises becomes one ``error: ...`` line and ``SystemExit(2)``."""
    try:
        return check(*args)
    except ValueError as error:
        fail(str(error))


def env_argument(argv: list[str] | None, default: str) -> str:
    """The ``--env`` of a command line whose other defaults are that env's recipe (``default`` when absent).

    tyro has no defaults that depend on another option's value, so the commands that take ``--env`` (compare,
    patterns, study) read it first with argparse, which leaves every other option, ``--help`` included, to tyro.
    """
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--env", default=default)
    known, _ = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    return known.env


def parse_or_exit(
    cls: type[T],
    argv: list[str] | None,
    *,
    default: T | None = None,
    description: str | None = None,
    config: tuple[Any, ...] = CLI_CONFIG,
) -> T:
    """``tyro.cli(cls, args=argv, default=default, description=description, config=config)`` with plain-text help
    pages; a command line it rejects prints one ``error: ...`` line (with tyro's "did you mean" hint for a typo'd
    option) and exits with status 2. ``--help`` prints the help page and exits with status 0 as before."""
    captured = io.StringIO()
    events: list[Any] = []
    try:
        with plain_help(), parse_error_events(events.append), contextlib.redirect_stderr(captured):
            parsed = tyro.cli(
                cls, args=argv, default=default, description=plain(description), config=config, prog=program()
            )
    except SystemExit as stop:
        if stop.code not in (0, None):
            fail(parse_error_message(events, captured.getvalue(), argv))
        sys.stderr.write(captured.getvalue())
        raise
    except BaseException:
        sys.stderr.write(captured.getvalue())
        raise
    sys.stderr.write(captured.getvalue())  # warnings and the like
    return parsed


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose errors are one ``error: ...`` line (not the usage and a second line) and
    exit status 2, and whose description reads as plain text (``PlainHelpFormatter``, whatever ``formatter_class``
    says); subcommand parsers made by ``add_subparsers`` are of this class too."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs["formatter_class"] = PlainHelpFormatter
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        hint = f" (see {self.prog} --help)" if self.add_help else ""
        fail(f"{message}{hint}")


def module_parser(module: str, description: str | None) -> ArgumentParser:
    """The ``ArgumentParser`` of ``python -m <module>``, whose help keeps ``description`` (its docstring) as written."""
    return ArgumentParser(
        prog=f"python -m {module}", description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )


# --- output paths ----------------------------------------------------------------------------------------------


def output_path_problem(path: str | Path, kind: str = "folder") -> str | None:
    """Why a command could not write ``path`` (``kind``: "folder" it creates or writes into, or "file" it writes),
    or None when it can: a file where a folder goes or the reverse, an existing path it may not write, or a path
    that cannot be created (the nearest existing folder above it is a file or not writable). Nothing is created."""
    if kind not in ("folder", "file"):
        raise ValueError(f"kind must be 'folder' or 'file', got {kind!r}")
    path = Path(path)
    if path.exists():
        if kind == "folder" and not path.is_dir():
            return f"{path} is a file, not a folder"
        if kind == "file" and path.is_dir():
            return f"{path} is a folder, not a file"
        if not os.access(path, os.W_OK | (os.X_OK if kind == "folder" else 0)):
            return f"{path} is not writable"
        if kind == "folder":
            return None
    above = path.parent if str(path.parent) else Path(".")
    while not above.exists() and above != above.parent:
        if above.is_symlink():
            return f"{path} cannot be created: {above} is a broken link"
        above = above.parent
    if not above.is_dir():
        return f"{path} cannot be created: {above} is a file"
    if not os.access(above, os.W_OK | os.X_OK):
        return f"{path} cannot be {'written' if path.exists() else 'created'}: {above} is not writable"
    return None


def check_output_path(path: str | Path | None, option: str, kind: str = "folder") -> None:
    """Raises one ``ValueError`` naming ``option`` when ``path`` cannot be written (``output_path_problem``); None
    (an option left out) passes."""
    if path is None:
        return
    problem = output_path_problem(path, kind)
    if problem is not None:
        raise ValueError(f"{option}: {problem}")


def check_outputs_or_exit(*outputs: tuple[str | Path | None, str, str]) -> None:
    """``check_output_path`` of each ``(path, option, kind)``; the first problem prints one ``error:`` line and
    exits with status 2, before any work."""
    for path, option, kind in outputs:
        valid_or_exit(check_output_path, path, option, kind)


def write_output(path: str | Path | None, text: str) -> None:
    """Writes ``text`` to ``path`` (an output option), making the folders above it; None (left out) writes nothing."""
    if path is None:
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


# --- run-folder lock -------------------------------------------------------------------------------------------


@contextlib.contextmanager
def hold_or_exit(folder: str | Path) -> Iterator[Path]:
    """Holds ``folder``'s lock (``experiments.lock.hold``) for the ``with`` block; a folder another command holds,
    now or later in the block (a run folder the command writes besides its own), prints one ``error:`` line naming
    that command and exits with status 2."""
    from experiments.lock import FolderInUseError, hold

    try:
        with hold(folder) as held:
            yield held
    except FolderInUseError as error:
        fail(str(error))
