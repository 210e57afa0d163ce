"""Helpers shared by the test modules."""


def one_line_error(capsys, main, argv) -> str:
    """The one ``error: ...`` line that a command's ``main(argv)`` writes to stderr as it returns status 2."""
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]
