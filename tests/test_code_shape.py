"""Code shape: no function of the project over ``MAX_FUNCTION_LINES`` lines (tests apart), and no module of
``experiments/`` over ``MAX_MODULE_LINES`` lines; a longer one is split into pieces named for what they do."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("talar_jax", "envs", "experiments", "benchmarks", "examples")
MAX_FUNCTION_LINES = 60
MAX_MODULE_LINES = 300


def function_lengths(source: str) -> list[tuple[str, int, int]]:
    """(qualified name, ``def`` line, lines from ``def`` to the function's last line, docstring included) of every
    function and method in ``source``, nested ones included; decorators do not count."""
    lengths = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                name = f"{prefix}{child.name}"
                lengths.append((name, child.lineno, child.end_lineno - child.lineno + 1))
                visit(child, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return lengths


def project_files() -> list[Path]:
    return sorted(path for package in PACKAGES for path in (ROOT / package).rglob("*.py"))


def test_function_lengths_count_from_def_to_the_last_line():
    source = '''
import functools


@functools.cache
def short(x):
    """Doc."""
    return x


class Holder:
    def method(self):
        def inner():
            return 1

        return inner()


async def waits():
    pass
'''
    long_body = "".join(f"    x{i} = {i}\n" for i in range(60))
    lengths = function_lengths(source + "\n\ndef long():\n" + long_body)
    assert lengths == [
        ("short", 6, 3),
        ("Holder.method", 12, 5),
        ("Holder.method.inner", 13, 2),
        ("waits", 19, 2),
        ("long", 23, 61),
    ]
    assert [name for name, _, lines in lengths if lines > MAX_FUNCTION_LINES] == ["long"]


def test_no_function_is_over_the_limit():
    offenders = [
        f"{path.relative_to(ROOT)}:{line} {name} ({lines} lines)"
        for path in project_files()
        for name, line, lines in function_lengths(path.read_text())
        if lines > MAX_FUNCTION_LINES
    ]
    assert not offenders, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(offenders)


def test_no_experiments_module_is_over_the_limit():
    offenders = [
        f"{path.relative_to(ROOT)} ({lines} lines)"
        for path in sorted((ROOT / "experiments").rglob("*.py"))
        if (lines := len(path.read_text().splitlines())) > MAX_MODULE_LINES
    ]
    assert not offenders, f"experiments/ modules over {MAX_MODULE_LINES} lines:\n" + "\n".join(offenders)
