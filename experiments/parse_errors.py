"""tyro's parse errors as one line: what ``experiments.cli.parse_or_exit`` prints instead of tyro's error box.

tyro reports a rejected command line with an event (its ``on_parse_error`` hook, which these functions only record)
and a box it prints on stderr. The line comes from the event where this module knows its kind (an unrecognised
option, with the box's "did you mean" options; a value that does not parse; a value a config's ``__post_init__``
rejects, named by the option the command line used; an invalid choice; a missing argument), else from the box's
first paragraph, framed or plain.
"""

from __future__ import annotations

import contextlib
import re
import sys
from collections.abc import Callable, Iterator
from typing import Any

_BOX = re.compile(r"[\u2500-\u257f]")
"""Box-drawing characters of tyro's error boxes."""


def _box_lines(text: str) -> list[str]:
    """The text lines of tyro's rendered error, framed (a box of line-drawing characters) or plain (where the
    output cannot show them): frame characters, colour codes and blank lines dropped, the indentation inside the
    frame kept; a divider becomes ``---`` and the title ``# <title>``."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", text)
    framed = "\u2502" in text
    lines: list[str] = []
    for raw in text.splitlines():
        stripped = raw.strip()
        if not stripped:
            continue
        if framed and stripped.startswith(("\u256d", "\u2570")):  # top (with the title) and bottom of the frame
            title = _BOX.sub("", stripped).strip()
            if title:
                lines.append(f"# {title}")
            continue
        inner = stripped.strip("\u2502").rstrip() if framed else raw.rstrip()
        if framed and inner.startswith(" "):
            inner = inner[1:]  # the frame's padding
        if not _BOX.sub("", inner).strip(" -"):
            if lines and len(lines) == 1 and not framed:  # plain: the first line, above the first divider, is the title
                lines[0] = f"# {lines[0].strip()}"
            lines.append("---")
        else:
            lines.append(inner)
    return lines


def _suggestions(text: str) -> list[str]:
    """The options tyro's "Perhaps you meant" block names (its lines indented four spaces more than its head)."""
    found: list[str] = []
    head: int | None = None
    for line in _box_lines(text):
        indent = len(line) - len(line.lstrip())
        if line.strip().startswith(("Perhaps you meant", "Arguments similar to")):
            head = indent
        elif line == "---" or line.startswith("# "):
            head = None
        elif head is not None and indent == head + 4 and line.strip().startswith("-"):
            option = line.strip().split(" ")[0].rstrip(",")
            if option not in found:
                found.append(option)
    return found


def _fallback_message(text: str) -> str:
    """The first paragraph of tyro's error as one line (an error this module has no event for)."""
    lines = [line for line in _box_lines(text) if not line.startswith("# ")]
    while lines and lines[0] == "---":
        lines.pop(0)
    head = []
    for line in lines:
        if line == "---":
            break
        head.append(line.strip())
    message = " ".join(head) or "could not parse the command line"
    return message[0].lower() + message[1:] if message[:1].isupper() and message[1:2].islower() else message


def _argument_name(argument: Any) -> str:
    """``--seeds`` for an option, the metavar (``RUN_DIR``) for a positional argument."""
    lowered = argument.lowered
    if argument.is_positional():
        metavar = lowered.metavar
        if metavar and not metavar.startswith("{"):
            return str(metavar)
        return argument.field.intern_name.upper()
    return "/".join(lowered.name_or_flags)


def _plain_value_error(message: str, metavar: str | None = None) -> str:
    """A Python conversion error in the reader's words (``metavar``: what the option takes, e.g. ``INT``)."""
    if metavar:
        metavar = re.sub(r"^\{None\}\|", "", metavar)
        while len(metavar) > 2 and metavar[0] + metavar[-1] in ("[]", "{}"):
            metavar = metavar[1:-1]
    for pattern, words in (
        (r"invalid literal for int\(\) with base 10: (.*)", "not an integer: {}"),
        (r"could not convert string to float: (.*)", "not a number: {}"),
        (r"Could not find valid parse for arguments: \[(.*)\]", "cannot read {}"),
        (r"no type matching .* could be instantiated from \[(.*?)\]\..*", "cannot read {}"),
    ):
        match = re.fullmatch(pattern, message.strip(), flags=re.S)
        if match:
            expected = f" (expected {metavar})" if metavar and words.startswith("cannot") else ""
            return words.format(match.group(1)) + expected
    return message


def _config_option(message: str, prefix: str | None, argv: list[str]) -> str:
    """``PPOConfig.total_env_steps must be ...`` of the nested config ``ifp`` as ``--ifp.total-env-steps must be
    ...``: the option as the command line spelled it when it did (a nested config's options may drop a prefix
    of its path), else ``--<prefix>.<field>``."""
    if not prefix:
        return message
    prefix = prefix.replace("_", "-")

    def option(field: str) -> str:
        field = field.replace("_", "-")
        for token in argv:
            name = token.split("=", 1)[0].replace("_", "-")
            if name.startswith("--") and name.endswith(f".{field}") and f"{prefix}.{field}".endswith(name[2:]):
                return name
        return f"--{prefix}.{field}"

    renamed = re.sub(r"\b[A-Z]\w*Config\.(\w+)", lambda match: option(match.group(1)), message, count=1)
    if renamed != message:
        return renamed
    groups = [token.split("=", 1)[0].rsplit(".", 1)[0] for token in argv if token.startswith("--") and "." in token]
    spelled = [group for group in groups if f".{prefix}".endswith(f".{group[2:].replace('_', '-')}")]
    return f"{spelled[0] if spelled else '--' + prefix}: {message}"


def _event_message(event: Any, text: str, argv: list[str]) -> str | None:
    """One line for a tyro parse-error event (None for an event of a kind this function does not know)."""
    from tyro import _errors

    if isinstance(event, _errors.UnrecognizedArgs):
        tokens = list(event.tokens)
        options = [token for token in tokens if token.startswith("-")]
        what = "unrecognized option" if options else "unexpected argument"
        message = f"{what}{'s' if len(options or tokens) > 1 else ''}: {' '.join(tokens)}"
        hints = _suggestions(text)
        if hints:
            message += f" (did you mean {' or '.join(hints[:3])}?)"
        return message
    if isinstance(event, _errors.InstantiationFailure):
        if event.argument is not None:
            metavar = event.argument.lowered.metavar
            return f"{_argument_name(event.argument)}: {_plain_value_error(event.message, metavar)}"
        prefix = re.search(r"Error parsing ([\w.]+):", re.sub(r"\s+", " ", " ".join(_box_lines(text))))
        name = prefix.group(1) if prefix else None
        return _config_option(event.message, name if name and not name[:1].isupper() else None, argv)
    if isinstance(event, _errors.InvalidChoice):
        choices = ", ".join(event.choices)
        return f"{_argument_name(event.argument)}: invalid choice {event.value!r}; choose one of {choices}"
    if isinstance(event, _errors.MissingArgs):
        parts = []
        for context in event.missing_arguments:
            choices = context.arg.lowered.choices
            name = _argument_name(context.arg)
            parts.append(f"{name} (one of {', '.join(map(str, choices))})" if choices else name)
        return f"missing {', '.join(parts)}"
    if isinstance(event, _errors.BadValue):
        name = _argument_name(event.argument)
        if event.offending_value is not None:
            return f"{name} takes no value, got {event.offending_value!r}"
        return f"{name} needs a value"
    if isinstance(event, _errors.MutexConflict):
        return f"{event.first_token} and {event.second_token} cannot be given together"
    if isinstance(event, _errors.MissingSubcommand):
        return f"missing a subcommand (one of {', '.join(event.subcommand_spec.parser_from_name)})"
    return None


@contextlib.contextmanager
def parse_error_events(record: Callable[[Any], None]) -> Iterator[None]:
    """Records tyro's parse-error events (its ``on_parse_error`` hook; nothing where this tyro has none). The hook
    only records: tyro still prints its box (captured by ``parse_or_exit``) and exits."""
    try:
        from tyro import _errors

        hook = _errors.on_parse_error
    except (ImportError, AttributeError):  # pragma: no cover
        yield
        return
    with hook(record):
        yield


def parse_error_message(events: list[Any], text: str, argv: list[str] | None = None) -> str:
    """The one-line message of a failed parse of ``argv``: from tyro's first error event when there is one, else
    from the first paragraph of its printed box ``text``."""
    for event in events[:1]:
        try:
            message = _event_message(event, text, list(sys.argv[1:] if argv is None else argv))
        except (AttributeError, TypeError):  # an event whose fields moved: read the box instead
            message = None
        if message:
            return " ".join(message.split())
    return " ".join(_fallback_message(text).split())
