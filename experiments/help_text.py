"""Help pages in plain text: what tyro and argparse show of the docstrings, without their markup.

tyro takes a command's help text from its docstrings (the module's, the config classes', each field's), which are
written for a reader of the source: double-backtick markup and hard line breaks. ``plain`` turns such text into
paragraphs; ``plain_help`` applies it to what tyro reads while a parser is built; ``PlainHelpFormatter`` does the same
for argparse.
"""

from __future__ import annotations

import argparse
import contextlib
import re
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path
from typing import Any


def plain(text: str | None) -> str | None:
    """Docstring text as a help page shows it: ``code`` markup dropped and hard-wrapped lines joined into paragraphs.
    Blank lines still separate paragraphs, a list item (a line starting ``- `` or ``* ``) starts a line of its own,
    and a line indented by four spaces or more (a command shown as an example) keeps its own line and indentation."""
    if text is None:
        return None
    text = re.sub(r"``(.+?)``", r"\1", text, flags=re.S)
    first, _, rest = text.strip("\n").partition("\n")
    text = first.strip() + ("\n" + textwrap.dedent(rest) if rest else "")
    paragraphs = []
    for block in re.split(r"\n[ \t]*\n", text.strip("\n")):
        lines: list[str] = []
        for raw in block.splitlines():
            line = raw.strip()
            verbatim = raw.startswith(("    ", "\t"))  # a list item's continuation is indented less
            if verbatim:
                lines.append(raw.rstrip())
            elif lines and not lines[-1][:1].isspace() and not re.match(r"[-*] ", line):
                lines[-1] = f"{lines[-1]} {line}"
            else:
                lines.append(line)
        paragraphs.append("\n".join(lines))
    text = paragraphs[0] if paragraphs else ""
    for paragraph in paragraphs[1:]:  # a list or an example right after its lead-in keeps to the next line
        text += ("\n" if re.match(r"[-*] |\s", paragraph) else "\n\n") + paragraph
    return text


class PlainHelpFormatter(argparse.HelpFormatter):
    """argparse help with ``plain`` descriptions: each paragraph and list item wrapped on its own, example commands
    (indented lines) kept as they are."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        out = []
        for paragraph in (plain(text) or "").split("\n\n"):
            for line in paragraph.split("\n"):
                if line[:1].isspace():
                    out.append(indent + line)
                else:
                    hang = "  " if re.match(r"[-*] ", line) else ""
                    out.append(textwrap.fill(line, width, initial_indent=indent, subsequent_indent=indent + hang))
            out.append("")
        return "\n".join(out).rstrip()


@contextlib.contextmanager
def plain_help() -> Iterator[None]:
    """While tyro builds a parser, the field and class docstrings it shows pass through ``plain``. (tyro reads them
    itself; where its docstring functions move, help pages keep the raw text, which the tests catch.)"""
    try:
        from tyro import _docstrings
    except ImportError:  # pragma: no cover
        yield
        return
    originals = {name: getattr(_docstrings, name, None) for name in ("get_field_docstring", "get_callable_description")}
    if None in originals.values():  # pragma: no cover
        yield
        return

    def field_docstring(*args: Any, **kwargs: Any) -> str | None:
        return plain(originals["get_field_docstring"](*args, **kwargs))

    def callable_description(*args: Any, **kwargs: Any) -> str:
        return plain(originals["get_callable_description"](*args, **kwargs)) or ""

    _docstrings.get_field_docstring = field_docstring
    _docstrings.get_callable_description = callable_description
    try:
        yield
    finally:
        for name, original in originals.items():
            setattr(_docstrings, name, original)


def program() -> str:
    """The running command as its user typed it: ``python -m experiments.clevr``, or a console script's name
    (``talar-clevr``)."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is not None and spec.name and spec.name != "__main__":
        return f"python -m {spec.name.removesuffix('.__main__')}"
    return Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "python"
