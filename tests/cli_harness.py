"""Running the CLI in-process with every entry point that would compile stubbed out, so a
test sees whether bad input is refused up front (tests/test_cli.py, test_cli_fuzz.py)."""

from __future__ import annotations

import contextlib
import io
from unittest import mock

import jaxform.design.problem
import jaxform.driver
import jaxform.materialpoint
import jaxform.xla_options
from jaxform.cli import main


class Reached(AssertionError):
    """An entry point that compiles was called: the input was not refused up front."""


def _stop(*args, **kwargs):
    raise Reached("bad input reached the simulation / compilation")


@contextlib.contextmanager
def no_compilation():
    """Every path from the CLI into a compiled program raises Reached."""
    with (
        mock.patch.object(jaxform.driver, "simulate", _stop),
        mock.patch.object(jaxform.design.problem, "remeshed_schedule", _stop),
        mock.patch.object(jaxform.materialpoint, "uniaxial_compression", _stop),
        mock.patch.object(jaxform.xla_options, "jit", _stop),
    ):
        yield


def run_cli(argv: list[str]) -> tuple[int, list[str]]:
    """(exit status, non-empty stderr lines) of the CLI run in-process; Reached and any
    other exception propagate (a traceback fails the test)."""
    err = io.StringIO()
    with (
        no_compilation(),
        contextlib.redirect_stderr(err),
        contextlib.redirect_stdout(io.StringIO()),
    ):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    return code, [ln for ln in err.getvalue().splitlines() if ln.strip()]


def assert_refused(argv: list[str], needle: str) -> str:
    """Exit 2 with one stderr line that names ``needle``; returns the line."""
    code, lines = run_cli(argv)
    assert code == 2, (argv, code, lines)
    assert len(lines) == 1, (argv, lines)
    assert needle in lines[0], (argv, needle, lines[0])
    assert "Traceback" not in lines[0]
    return lines[0]
