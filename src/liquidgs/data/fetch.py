"""One file fetched over HTTP(S) with its size and SHA-256, for the dataset archives
(data.download) and the real-clip benchmark's videos (data.clips)."""

from __future__ import annotations

import dataclasses
import hashlib
import http.client
import time
import typing
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable
from pathlib import Path

from liquidgs.errors import ConfigError
from liquidgs.settings import describe, matches

CHUNK = 1 << 20
TIMEOUT_S = 60
"""Seconds a connection may stay silent before the download is abandoned."""
DEADLINE_S = 4 * 3600
"""Seconds a whole download may take (the largest archive, a few GB, at 1 MB/s is about an hour):
past it the download stops. Checked between reads, each of which waits at most TIMEOUT_S."""


def _connect(url: str):
    """The open response for `url`; one line naming the host when no connection can be made."""
    try:
        return urllib.request.urlopen(url, timeout=TIMEOUT_S)
    except urllib.error.HTTPError as err:
        raise ConfigError(f"{url}: the server answered {err.code} {err.reason}") from None
    except (urllib.error.URLError, http.client.HTTPException, OSError) as err:
        reason = getattr(err, "reason", None) or err
        raise ConfigError(f"{url}: could not reach {urllib.parse.urlsplit(url).netloc}: {reason}") from None


def fetch(url: str, expected: int | None, path: Path, report: Callable[[str], None]) -> tuple[int, str]:
    """The bytes at `url` into `path`; (size, sha256). One line for a server that cannot be reached, a
    server error, a broken download, one past DEADLINE_S, or a server that offers other than the
    `expected` bytes (None: not known)."""
    digest, size = hashlib.sha256(), 0
    deadline = time.monotonic() + DEADLINE_S
    try:
        with _connect(url) as response, path.open("wb") as out:
            announced = response.headers.get("Content-Length")
            announced = int(announced) if announced and announced.isdigit() else None
            if expected is not None and announced is not None and announced != expected:
                raise ConfigError(f"{url}: the server offers {announced:,} bytes, the file is "
                                  f"{expected:,} bytes: not the published file")  # fmt: skip
            report(f"downloading {url} ({f'{announced / 2**20:,.1f} MiB' if announced else 'size not given'})")
            while chunk := response.read1(CHUNK):  # what has arrived: a slow server meets the deadline
                out.write(chunk)
                digest.update(chunk)
                size += len(chunk)
                if time.monotonic() > deadline:
                    raise ConfigError(f"{url}: stopped after {size:,} bytes: a download may take at most "
                                      f"{DEADLINE_S:g} s (liquidgs.data.fetch.DEADLINE_S)")  # fmt: skip
    except (urllib.error.URLError, http.client.HTTPException, OSError) as err:
        reason = getattr(err, "reason", None) or err
        raise ConfigError(f"{url}: the download broke off after {size:,} bytes ({reason})") from None
    if announced is not None and size != announced:
        raise ConfigError(f"{url}: got {size:,} of the {announced:,} bytes the server announced: truncated")
    return size, digest.hexdigest()


def table_entry(variable: str, name: str, given, cls, base=None):
    """An entry of a download table (a dataclass `cls`) from the JSON object an environment variable
    gives for `name`: `base` (the built-in entry, if any) with those fields replaced, every field of
    its own type, one ConfigError naming the variable, the entry and the field otherwise."""
    if not isinstance(given, dict):
        raise ConfigError(f"{variable}: entry '{name}' must be a JSON object of fields, got {given!r}")
    hints = typing.get_type_hints(cls)
    for key, value in given.items():
        if key not in hints:
            raise ConfigError(f"{variable}: entry '{name}' has unknown field '{key}' (fields: {', '.join(hints)})")
        if not matches(value, hints[key]):
            raise ConfigError(
                f"{variable}: entry '{name}': field '{key}' must be {describe(hints[key])}, got {value!r}"
            )
    if base is not None:
        return dataclasses.replace(base, **given)
    required = [f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING and f.name not in given]
    if required:
        raise ConfigError(f"{variable}: entry '{name}' is not built in, so it needs field '{required[0]}'")
    return cls(**given)
