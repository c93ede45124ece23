"""`liquidgs data download`: against a server on 127.0.0.1 serving archives made here (never the network)."""

from __future__ import annotations

import hashlib
import http.server
import io
import json
import threading
import zipfile
from pathlib import Path

import pytest

from liquidgs.cli import main as cli
from liquidgs.data import generate_synthetic
from liquidgs.data.download import ARCHIVES_ENV, download
from tiny_runs import one_line_error


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory) -> Path:
    """A tiny built-in scene in both layouts (dnerf/ and nerfies/)."""
    return Path(generate_synthetic("spinner", tmp_path_factory.mktemp("download") / "s", size=16, frames=8))


def zip_of(folders: dict[str, Path], broken: dict[str, bytes] | None = None) -> bytes:
    """A zip holding each folder under its archive name, and files replaced by `broken`."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, folder in folders.items():
            for path in sorted(folder.rglob("*")):
                if path.is_file():
                    member = f"{name}/{path.relative_to(folder).as_posix()}"
                    archive.writestr(member, (broken or {}).get(member, path.read_bytes()))
    return buffer.getvalue()


class Archives:
    """What the server holds: path -> (body, bytes it announces); every request counted."""

    def __init__(self):
        self.files: dict[str, tuple[bytes, int]] = {}
        self.requests = 0


@pytest.fixture(scope="module")
def server():
    archives = Archives()

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server's name
            archives.requests += 1
            if self.path not in archives.files:
                self.send_error(404, "Not Found")
                return
            body, announced = archives.files[self.path]
            self.send_response(200)
            self.send_header("Content-Type", "application/zip")
            self.send_header("Content-Length", str(announced))
            self.end_headers()
            self.wfile.write(body)  # fewer bytes than announced: a download cut off

        def log_message(self, *args):
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield archives, f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    thread.join()


def serve(server, monkeypatch, name: str, body: bytes, announced: int | None = None, dataset: str = "dnerf",
          **table) -> str:  # fmt: skip
    archives, base = server
    archives.files[f"/{name}"] = (body, len(body) if announced is None else announced)
    monkeypatch.setenv(ARCHIVES_ENV, json.dumps({dataset: {"url": f"{base}/{name}", **table}}))
    return f"{base}/{name}"


def left_beside(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir())


@pytest.mark.parametrize(
    ("dataset", "layout", "folder"),
    [("dnerf", "dnerf", "data/spinner"), ("nerfds", "nerfies", "spinner_novel_view")],
)
def test_download_checks_unpacks_and_checks_every_scene(synthetic, server, monkeypatch, tmp_path, capsys,
                                                        dataset, layout, folder):  # fmt: skip
    body = zip_of({folder: synthetic / layout})
    sha256 = hashlib.sha256(body).hexdigest()
    serve(server, monkeypatch, f"{dataset}.zip", body, dataset=dataset, size=len(body), sha256=sha256)
    assert cli(["data", "download", dataset, str(tmp_path / dataset)]) == 0
    out, err = capsys.readouterr()
    assert f"{dataset}: 1 scenes in {tmp_path / dataset}: spinner" in out  # NeRF-DS's _novel_view cut
    assert f"archive: {len(body):,} bytes, SHA-256 {sha256} (size as published, SHA-256 as published" in out
    assert "checked spinner: " in err
    scene = tmp_path / dataset / "spinner"
    assert (scene / ("transforms_train.json" if dataset == "dnerf" else "dataset.json")).is_file()
    assert left_beside(tmp_path) == [dataset]  # no temporary file or folder left


def test_without_a_published_checksum_the_size_and_crcs_are_checked_and_said(synthetic, server, monkeypatch, tmp_path):
    body = zip_of({"data/spinner": synthetic / "dnerf"})
    serve(server, monkeypatch, "plain.zip", body)
    result = download("dnerf", tmp_path / "d", report=lambda line: None)
    assert result.checks == "size as the server announced, no published checksum, every member's CRC"


@pytest.mark.parametrize(
    ("case", "words"),
    [
        ("sha256", "SHA-256 "),
        ("size", "the server offers"),
        ("truncated", "bytes the server announced: truncated"),
        ("missing", "the server answered 404 Not Found"),
        ("corrupt", "is corrupt (CRC mismatch)"),
        ("bad scene", "transforms_train.json"),
        ("no scene", "no scene in the archive (no folder holds transforms_train.json)"),
    ],
)
def test_a_failed_download_is_one_line_and_leaves_nothing(synthetic, server, monkeypatch, tmp_path, capsys, case,
                                                          words):  # fmt: skip
    body = zip_of({"data/spinner": synthetic / "dnerf"})
    table, announced = {}, None
    if case == "sha256":
        table = {"sha256": "0" * 64}
    elif case == "size":
        table = {"size": len(body) + 1}
    elif case == "truncated":
        body, announced = body[: len(body) // 2], len(body)
    elif case == "corrupt":  # a member's bytes changed after its CRC was written
        offset = body.index(b"transforms_train.json") + len("transforms_train.json") + 2
        body = body[:offset] + bytes([body[offset] ^ 0xFF]) + body[offset + 1 :]
    elif case == "bad scene":
        body = zip_of({"data/spinner": synthetic / "dnerf"}, {"data/spinner/transforms_train.json": b"{"})
    elif case == "no scene":
        body = zip_of({"data/notes": synthetic / "dnerf" / "train"})
    name = "absent.zip" if case == "missing" else f"{case.replace(' ', '-')}.zip"
    url = serve(server, monkeypatch, name, body, announced, **table)
    if case == "missing":
        server[0].files.pop("/absent.zip")
    assert cli(["data", "download", "dnerf", str(tmp_path / "dnerf")]) == 2
    line = one_line_error(capsys)
    assert words in line, line
    assert url in line or case == "bad scene"
    assert left_beside(tmp_path) == []  # nothing that looks like a dataset, no temporary file


def test_an_existing_folder_is_refused_before_anything_is_fetched(server, monkeypatch, tmp_path, capsys):
    serve(server, monkeypatch, "never.zip", b"")
    (tmp_path / "dnerf").mkdir()
    before = server[0].requests
    assert cli(["data", "download", "dnerf", str(tmp_path / "dnerf")]) == 2
    assert "already exists" in one_line_error(capsys) and server[0].requests == before


def test_an_unknown_dataset_is_one_line(tmp_path, capsys):
    assert cli(["data", "download", "hypernerf", str(tmp_path / "h")]) == 2
    assert "unknown dataset 'hypernerf' (choose from dnerf, nerfds)" in one_line_error(capsys)
    assert left_beside(tmp_path) == []


def test_ctrl_c_while_unpacking_leaves_nothing(synthetic, server, monkeypatch, tmp_path):
    serve(server, monkeypatch, "interrupted.zip", zip_of({"data/spinner": synthetic / "dnerf"}))

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(zipfile.ZipFile, "extractall", interrupted)
    with pytest.raises(KeyboardInterrupt):
        download("dnerf", tmp_path / "dnerf", report=lambda line: None)
    assert left_beside(tmp_path) == []
