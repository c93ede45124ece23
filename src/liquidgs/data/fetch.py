"""One file fetched over HTTP(S) with its size and SHA-256, for the dataset archives
(data.download) and the real-clip benchmark's videos (data.clips)."""

from __future__ import annotations

import hashlib
import http.client
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path

from liquidgs.errors import ConfigError

CHUNK = 1 << 20
TIMEOUT_S = 60
"""Seconds a connection may stay silent before the download is abandoned."""


def fetch(url: str, expected: int | None, path: Path, report: Callable[[str], None]) -> tuple[int, str]:
    """The bytes at `url` into `path`; (size, sha256). One line for a server error, a broken download,
    or a server that offers other than the `expected` bytes (None: not known)."""
    digest, size = hashlib.sha256(), 0
    try:
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as response, path.open("wb") as out:
            announced = response.headers.get("Content-Length")
            announced = int(announced) if announced and announced.isdigit() else None
            if expected is not None and announced is not None and announced != expected:
                raise ConfigError(f"{url}: the server offers {announced:,} bytes, the file is "
                                  f"{expected:,} bytes: not the published file")  # fmt: skip
            report(f"downloading {url} ({f'{announced / 2**20:,.1f} MiB' if announced else 'size not given'})")
            while chunk := response.read(CHUNK):
                out.write(chunk)
                digest.update(chunk)
                size += len(chunk)
    except urllib.error.HTTPError as err:
        raise ConfigError(f"{url}: the server answered {err.code} {err.reason}") from None
    except (urllib.error.URLError, http.client.HTTPException, OSError) as err:
        reason = getattr(err, "reason", None) or err
        raise ConfigError(f"{url}: the download broke off after {size:,} bytes ({reason})") from None
    if announced is not None and size != announced:
        raise ConfigError(f"{url}: got {size:,} of the {announced:,} bytes the server announced: truncated")
    return size, digest.hexdigest()
