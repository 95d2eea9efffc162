"""Running the CLI in-process in tests: exit status, output, and the one-line error."""

from topodrake.apps.cli import main


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line(code, err, *words):
    """The one-line error of exit status 2, holding ``words``; returns the line."""
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("topodrake: error:"), err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]
