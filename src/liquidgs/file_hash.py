"""The SHA-256 of a file's bytes: what the source records of derived files (train.run_folder.provenance)
and the optical flow's record of its frames (data.flow) compare. Beside errors and atomic, under
data/ and train/, so that both can import it."""

from __future__ import annotations

import hashlib
from pathlib import Path

_digests: dict[tuple[str, int, int], str] = {}
"""File hashes by (path, size, mtime): a report reads one checkpoint for several derived files."""


def file_sha256(path: Path) -> str:
    path = Path(path)
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _digests:
        digest = hashlib.sha256()
        with open(path, "rb") as file:
            for block in iter(lambda: file.read(1 << 20), b""):
                digest.update(block)
        _digests[key] = digest.hexdigest()
    return _digests[key]
