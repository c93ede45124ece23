"""User-facing errors: one clear line, naming the file and field at fault."""

from __future__ import annotations

from pathlib import Path


class LiquidGSError(Exception):
    """An error the CLI reports as one line and a non-zero exit, without a traceback."""


class ConfigError(LiquidGSError, ValueError):
    """A bad setting (unknown name, out-of-range value)."""


class DataError(LiquidGSError):
    """Bad input data. The message names the file and, where there is one, the field."""

    def __init__(self, path: str | Path, message: str, field: str | None = None):
        self.path = Path(path)
        self.field = field
        where = f"{self.path}" + (f": field '{field}'" if field else "")
        super().__init__(f"{where}: {message}")


def one_line(text: str) -> str:
    """Messages from other libraries (torch, yaml) can span lines; the CLI prints one."""
    return " ".join(text.split())
