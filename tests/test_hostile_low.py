"""Hostile inputs of low weight: a negative number given as a flag's value, settings a run would
silently ignore, the dry run's estimate of static runs, a download that cannot connect or never ends.
Each is one line on stderr, exit 2, nothing written."""

from __future__ import annotations

import http.server
import json
import socket
import threading
import time
from pathlib import Path

import pytest

from liquidgs.cli import main as cli
from liquidgs.data import fetch as fetch_module
from liquidgs.data import generate_synthetic
from liquidgs.data.download import ARCHIVES_ENV
from liquidgs.settings import parse_flag_settings
from liquidgs.train.config import TrainConfig
from tiny_runs import one_line_error, tiny_flags


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> Path:
    """The spinner in both layouts: dnerf/ (motion terms off by default), nerfies/ (a capture: on)."""
    return generate_synthetic("spinner", tmp_path_factory.mktemp("low") / "spinner", size=16, frames=8)


def refused(capsys, argv: list[str], *untouched: Path) -> str:
    """The command's one error line, after checking its exit code and that `untouched` were not made."""
    assert cli(argv) == 2
    line = one_line_error(capsys)
    assert not any(path.exists() for path in untouched)
    return line


# ------------------------------------------------------------------ a negative number as a flag's value
def test_a_negative_number_in_exponent_form_is_the_flags_value():
    settings = parse_flag_settings(TrainConfig, ["--data", "d", "--cameras.rotation-lr", "-1e-3"], "liquidgs train")
    assert settings["cameras.rotation_lr"] == -1e-3


def test_a_negative_learning_rate_is_refused_by_the_configs_own_range_check(scenes, tmp_path, capsys):
    out = tmp_path / "run"
    line = refused(capsys, ["train", "--data", str(scenes / "dnerf"), "--out", str(out),
                            "--cameras.rotation-lr", "-1e-3"], out)  # fmt: skip
    assert line == "liquidgs train: error: cameras.rotation-lr must be a finite number > 0, got -0.001"


# ------------------------------------------------------------------ settings that would have no effect
@pytest.mark.parametrize(
    ("layout", "flags", "message"),
    [
        ("dnerf", ["--field", "static", "--field-options.mlp-width", "8"],
         "--field-options.mlp-width has no effect on field 'static' (it reads no field options)"),
        ("dnerf", ["--field", "mlp", "--field-options.cells", "3"],
         "--field-options.cells has no effect on field 'mlp' (it reads xyz_freqs, time_freqs, timenet_width, "
         "timenet_out, mlp_depth, mlp_width)"),
        ("nerfies", ["--field", "mlp", "--motion.apply", "off", "--motion.stillness", "0.5"],
         "--motion.stillness has no effect: --motion.apply is off, so no motion term is trained"),
        ("nerfies", ["--field", "static", "--motion.rigidity", "0.5"],
         "--motion.rigidity has no effect: the static field does not move Gaussians, so no motion term is trained"),
        ("dnerf", ["--field", "mlp", "--motion.stillness", "0.5"],
         "--motion.stillness has no effect: --motion.apply auto is off for dnerf data (on for captures), so no "
         "motion term is trained"),
    ],
    ids=["static-field-options", "another-fields-options", "motion-off", "static-motion", "motion-auto-on-dnerf"],
)  # fmt: skip
def test_a_setting_the_run_would_ignore_is_one_line_naming_it(scenes, tmp_path, capsys, layout, flags, message):
    out = tmp_path / "run"
    short = tiny_flags({"iterations": 20, "cameras.align_steps": 2})  # where it is not refused: a short run
    line = refused(capsys, ["train", "--data", str(scenes / layout), "--out", str(out), *short, *flags], out)
    assert line == f"liquidgs train: error: {message}"


def test_a_sequence_for_a_format_without_frames_is_one_line(tmp_path, capsys):
    out = tmp_path / "web"
    line = refused(capsys, ["export", "--run", str(tmp_path / "run"), "--format", "web", "--sequence", "5",
                            "--out", str(out)], out)  # fmt: skip
    assert line == ("liquidgs export: error: --sequence has no effect with --format web: it sets the frames of ply "
                    "and plyseq")


# ------------------------------------------------------------------ the dry run's estimate of static runs
def test_the_dry_run_never_estimates_static_runs_as_free(scenes, tmp_path, capsys):
    spec = tmp_path / "still.yml"
    spec.write_text(json.dumps({"name": "still", "preset": "tiny", "scenes": ["dnerf"], "fields": ["static"],
                                "seeds": [0, 1]}))  # fmt: skip
    args = ["experiment", "run", str(spec), "--data-root", str(scenes), "--out", str(tmp_path / "exp"), "--dry-run"]
    assert cli(args) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    assert line.startswith("GPU-time estimate for the 2 runs to train: unmeasured (2 runs unmeasured: a field "
                           "without FLOPs (static) still trains its Gaussians"), line  # fmt: skip
    assert "0.0 GPU-hours" not in line
    assert not (tmp_path / "exp").exists()


# ------------------------------------------------------------------ downloads: no connection, no end
def test_a_server_that_cannot_be_reached_is_said_as_such(monkeypatch, tmp_path, capsys):
    with socket.socket() as probe:  # a port of 127.0.0.1 nothing listens on: the connection is refused
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    monkeypatch.setenv(ARCHIVES_ENV, json.dumps({"dnerf": {"url": f"http://127.0.0.1:{port}/d.zip"}}))
    line = refused(capsys, ["data", "download", "dnerf", str(tmp_path / "d")], tmp_path / "d")
    assert line.startswith(f"liquidgs data: error: http://127.0.0.1:{port}/d.zip: could not reach "
                           f"127.0.0.1:{port}: "), line  # fmt: skip
    assert "refused" in line and "broke off" not in line
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def trickle():
    """A server on 127.0.0.1 that announces 10,000 bytes and sends one every 20 ms, for at most 4 s."""

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server's name
            self.send_response(200)
            self.send_header("Content-Length", "10000")
            self.end_headers()
            try:
                for _ in range(200):
                    self.wfile.write(b"x")
                    self.wfile.flush()
                    time.sleep(0.02)
            except OSError:  # the client stopped reading
                pass

        def log_message(self, *args):
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/slow.zip"
    httpd.shutdown()
    thread.join()


def test_a_download_past_its_deadline_stops_with_one_line_and_leaves_nothing(trickle, monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(fetch_module, "DEADLINE_S", 0.5)
    monkeypatch.setenv(ARCHIVES_ENV, json.dumps({"dnerf": {"url": trickle}}))
    start = time.monotonic()
    line = refused(capsys, ["data", "download", "dnerf", str(tmp_path / "d")], tmp_path / "d")
    assert time.monotonic() - start < 3  # the deadline, not the server's 4 s
    assert line.startswith(f"liquidgs data: error: {trickle}: stopped after "), line
    assert line.endswith(" bytes: a download may take at most 0.5 s (liquidgs.data.fetch.DEADLINE_S)")
    assert list(tmp_path.iterdir()) == []
