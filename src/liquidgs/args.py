"""Command-line parsing whose usage errors are one line (a ConfigError), not a help panel.

tyro and argparse print a usage error as a multi-line panel and exit 2; the `liquidgs`
commands report every bad input the same way instead: one line, exit 2.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from typing import TypeVar

import tyro

from liquidgs.errors import ConfigError

T = TypeVar("T")

_BOX = " │╭╮╰╯─"
_STOP = ("For full helptext", "Argument helptext", "usage:")


def usage_error_line(text: str) -> str:
    """The message of a tyro panel ('Title: message') or of an argparse 'prog: error: message'."""
    lines = [line.strip(_BOX) for line in text.splitlines()]
    lines = [line for line in lines if line and not set(line) <= set("-─ ")]
    for line in lines:
        if ": error: " in line:
            return line.split(": error: ", 1)[1]
    if not lines:
        return "invalid arguments"
    title, body = lines[0], []
    for line in lines[1:]:
        if line.startswith(_STOP):
            break
        body.append(line)
    message = " ".join(body)
    return message if message.startswith(title) or not message else f"{title}: {message}"


def one_line_usage_errors(parse: Callable[[], T]) -> T:
    """Run a parser; a usage error becomes a ConfigError, --help prints as usual."""
    captured = io.StringIO()
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100000"  # the panel prints each message on one line, unwrapped
    try:
        with redirect_stdout(captured), redirect_stderr(captured):
            return parse()
    except SystemExit as exit_:
        if exit_.code in (0, None):
            failed = False
        else:
            failed = True
            message = usage_error_line(captured.getvalue())
    finally:
        if columns is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = columns
    if failed:
        raise ConfigError(message)
    return parse()  # --help: parse again without capturing, so it prints at the terminal's width and exits


def parse_args(spec: Callable[..., T], argv: list[str], prog: str, description: str | None = None, **kwargs) -> T:
    """tyro.cli with one-line usage errors."""
    return one_line_usage_errors(lambda: tyro.cli(spec, args=argv, prog=prog, description=description, **kwargs))
