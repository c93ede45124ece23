"""User-facing errors: one clear line, naming the file and field at fault."""

from __future__ import annotations

import math
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


def check_number(setting: str, value, *, positive: bool = False) -> None:
    """ConfigError naming `setting` unless `value` is a finite number >= 0 (> 0 where `positive`);
    true and false are not numbers here, though Python counts them as 1 and 0."""
    is_number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not (is_number and math.isfinite(value) and (value > 0 if positive else value >= 0)):
        raise ConfigError(f"{setting} must be a finite number {'> 0' if positive else '>= 0'}, got {value!r}")


def check_integer(setting: str, value, minimum: int, maximum: int | None = None) -> None:
    """ConfigError naming `setting` unless `value` is an integer >= `minimum` (not true or false),
    and <= `maximum` where given (a size that multiplies cost)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{setting} must be an integer >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{setting} must be at most {maximum:,}, got {value:,}")


def one_line(text: str) -> str:
    """Messages from other libraries (torch, yaml) can span lines; the CLI prints one."""
    return " ".join(text.split())


def check_finite(source: str | Path, what: str, values) -> None:
    """LiquidGSError naming `source` and how many of `values` (tensors or arrays, or a mapping of
    them) are NaN or infinite: every writer of numbers (bake, export's PLY, splatv and web) calls it
    before anything is written, so a diverged run is refused rather than saved as a broken file."""
    import numpy as np
    import torch

    items = values.values() if isinstance(values, dict) else values
    bad = total = 0
    for value in items:
        array = value.detach() if isinstance(value, torch.Tensor) else torch.as_tensor(np.asarray(value))
        if array.is_floating_point():
            bad += int((~torch.isfinite(array)).sum())
        total += array.numel()
    if bad:
        raise LiquidGSError(f"{source}: {bad:,} of {total:,} values of {what} are NaN or infinite; nothing written")
