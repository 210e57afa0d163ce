"""The ``talar-*`` console commands (``[project.scripts]`` in pyproject.toml, installed by ``pip install -e .``).

Each runs one module's ``main()`` on the command line's arguments, as ``python -m experiments.<name>`` does, and exits
with status 0 when it returns (``talar-paper``: the status its ``main()`` returns). The wrappers exist because a
console script exits with what its function returns, and a command's ``main()`` returns what a caller in Python wants
(a run's summary, a figure's path), which would otherwise be printed as an error with status 1. The module is
imported when the command runs.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

COMMANDS: dict[str, str] = {
    "talar-clevr": "experiments.clevr",
    "talar-kitchen": "experiments.kitchen",
    "talar-compare": "experiments.compare",
    "talar-patterns": "experiments.patterns",
    "talar-oracle": "experiments.oracle",
    "talar-instruct": "experiments.instruct",
    "talar-generalize": "experiments.generalize",
    "talar-tsne": "experiments.tsne",
    "talar-hrl": "experiments.hrl",
    "talar-study": "experiments.study",
    "talar-paper": "experiments.paper",
    "talar-records": "experiments.records",
}
"""Console command -> the module whose ``main(argv=None)`` it runs."""


def run(module: str, argv: list[str] | None = None) -> int:
    """``module.main(argv)``; its result when that is an exit status (an int), else 0."""
    result = importlib.import_module(module).main(argv)
    return result if isinstance(result, int) and not isinstance(result, bool) else 0


def _command(name: str) -> Callable[[], int]:
    module = COMMANDS[name]

    def command() -> int:
        return run(module)

    command.__name__ = name.removeprefix("talar-")
    command.__doc__ = f"``{name}``: ``python -m {module}``."
    return command


clevr = _command("talar-clevr")
kitchen = _command("talar-kitchen")
compare = _command("talar-compare")
patterns = _command("talar-patterns")
oracle = _command("talar-oracle")
instruct = _command("talar-instruct")
generalize = _command("talar-generalize")
tsne = _command("talar-tsne")
hrl = _command("talar-hrl")
study = _command("talar-study")
paper = _command("talar-paper")
records = _command("talar-records")
