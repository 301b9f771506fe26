"""The ``sixaxis`` CLI as the tests run it (typer's CliRunner on the real app), and what a clean
refusal looks like."""

from __future__ import annotations

from typer.testing import CliRunner

from experiments.cli import app

runner = CliRunner()


def lab(*args: object):
    """``sixaxis lab ARGS...``, in process."""
    return runner.invoke(app, ["lab", *map(str, args)])


def one_error_line(res, *words: str) -> str:
    """The result is a clean refusal: exit code 2, one line ``error: ...`` on stderr naming
    ``words``, no traceback."""
    assert res.exit_code == 2, (res.exit_code, res.output, res.exception)
    err = res.stderr
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "Traceback" not in res.output
    for w in words:
        assert w in err, (w, err)
    return err
