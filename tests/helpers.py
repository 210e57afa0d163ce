"""Helpers shared by the test modules."""

import pytest


def one_line_error(capsys, main, argv) -> str:
    """The one ``error: ...`` line that ``main(argv)`` writes to stderr before exiting with status 2."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]
