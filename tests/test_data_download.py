"""`liquidgs data download`: against a server on 127.0.0.1 serving archives made here (never the network)."""

from __future__ import annotations

import hashlib
import http.server
import io
import json
import os
import re
import subprocess
import sys
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from liquidgs.cli import main as cli
from liquidgs.data import generate_synthetic
from liquidgs.data.clips import CLIPS, CLIPS_ENV
from liquidgs.data.download import ARCHIVES_ENV, download
from liquidgs.experiments.spec import load_spec
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
    assert "unknown dataset 'hypernerf' (choose from dnerf, nerfds, real-clips)" in one_line_error(capsys)
    assert left_beside(tmp_path) == []


def test_ctrl_c_while_unpacking_leaves_nothing(synthetic, server, monkeypatch, tmp_path):
    serve(server, monkeypatch, "interrupted.zip", zip_of({"data/spinner": synthetic / "dnerf"}))

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(zipfile.ZipFile, "extractall", interrupted)
    with pytest.raises(KeyboardInterrupt):
        download("dnerf", tmp_path / "dnerf", report=lambda line: None)
    assert left_beside(tmp_path) == []


def serve_clips(server, monkeypatch, bodies: dict[str, bytes], **fields_of) -> dict[str, str]:
    """The clip set becomes `bodies`' clips, served here, each with its true size and SHA-256 unless
    `fields_of[name]` says otherwise; returns name -> URL."""
    archives, base = server
    table, urls = {}, {}
    for name, body in bodies.items():
        archives.files[f"/clips/{name}.mp4"] = (body, len(body))
        urls[name] = f"{base}/clips/{name}.mp4"
        table[name] = {"url": urls[name], "size": len(body), "sha256": hashlib.sha256(body).hexdigest(),
                       **fields_of.get(name, {})}  # fmt: skip
    monkeypatch.setenv(CLIPS_ENV, json.dumps(table))
    return urls


def test_real_clips_are_fetched_checked_and_listed_with_their_licences(server, monkeypatch, tmp_path, capsys):
    bodies = {"apple": b"apple video bytes" * 100, "bear": b"bear video bytes" * 50}
    urls = serve_clips(server, monkeypatch, bodies)
    assert cli(["data", "download", "real-clips", str(tmp_path / "clips")]) == 0
    out, err = capsys.readouterr()
    assert f"real-clips: 2 clips in {tmp_path / 'clips'}: apple.mp4, bear.mp4" in out
    assert "got apple.mp4: 1,700 bytes, SHA-256 as recorded; licence: CC BY-NC 4.0" in err
    assert {p.name for p in (tmp_path / "clips").iterdir()} == {"apple.mp4", "bear.mp4", "clips.json"}
    assert (tmp_path / "clips" / "bear.mp4").read_bytes() == bodies["bear"]
    listing = json.loads((tmp_path / "clips" / "clips.json").read_text())
    assert listing["bear"]["url"] == urls["bear"]  # the mirror's URL, the table's licence and subject
    assert listing["bear"]["licence"] == CLIPS["bear"].licence and listing["bear"]["moving"] == CLIPS["bear"].moving
    assert left_beside(tmp_path) == ["clips"]


@pytest.mark.parametrize(
    ("case", "words"),
    [
        ("sha256", "SHA-256 "),
        ("size", "the server offers 800 bytes, the file is 801 bytes"),
        ("truncated", "got 400 of the 800 bytes the server announced: truncated"),
        ("missing", "the server answered 404 Not Found"),
    ],
)
def test_a_real_clip_that_is_not_the_recorded_one_is_one_line_and_leaves_nothing(server, monkeypatch, tmp_path,
                                                                                  capsys, case, words):  # fmt: skip
    body = bytes(range(200)) * 4
    fields_of = {"sha256": {"sha256": "0" * 64}, "size": {"size": len(body) + 1}}.get(case, {})
    urls = serve_clips(server, monkeypatch, {"apple": b"fine" * 10, "cat": body}, cat=fields_of)
    if case == "truncated":
        server[0].files["/clips/cat.mp4"] = (body[:400], len(body))
    elif case == "missing":
        server[0].files.pop("/clips/cat.mp4")
    assert cli(["data", "download", "real-clips", str(tmp_path / "clips")]) == 2
    line = one_line_error(capsys)
    assert words in line and urls["cat"] in line, line
    assert left_beside(tmp_path) == []  # not even the clip that arrived whole


def test_a_real_clip_set_that_is_not_json_objects_is_one_line(monkeypatch, tmp_path, capsys):
    bad_name = '{"../x": {"url": "u", "size": 1, "sha256": "0", "licence": "l", "moving": ""}}'
    cases = (("[1]", "not a non-empty object of objects"), ('{"apple": {"colour": 1}}', "unknown field 'colour'"),
             (bad_name, "not a file name"))  # fmt: skip
    for raw, words in cases:
        monkeypatch.setenv(CLIPS_ENV, raw)
        assert cli(["data", "download", "real-clips", str(tmp_path / "clips")]) == 2
        line = one_line_error(capsys)
        assert f" {CLIPS_ENV}: " in line and words in line, line
    assert left_beside(tmp_path) == []


def test_the_real_clip_table_pins_each_clip_and_says_its_licence():
    for name, clip in CLIPS.items():
        # A commit, not a branch: the bytes behind the recorded SHA-256 cannot change.
        pinned = r"https://raw\.githubusercontent\.com/[\w.-]+/[\w.-]+/[0-9a-f]{40}/\S+\.mp4"
        assert re.fullmatch(pinned, clip.url), name
        assert re.fullmatch(r"[0-9a-f]{64}", clip.sha256) and clip.size > 0, name
        assert "CC BY" in clip.licence, name
    assert sum(not clip.moving for clip in CLIPS.values()) >= 1 and sum(bool(c.moving) for c in CLIPS.values()) >= 4


STUB_LIQUIDGS = """
import json, pathlib, sys
args = sys.argv[1:]
with open(sys.argv[0] + ".calls", "a") as log:
    log.write(json.dumps(args) + "\\n")
if args[:2] == ["data", "download"]:  # the real downloader, against the tests' server
    from liquidgs.cli import main
    sys.exit(main(args))
if args[:2] == ["data", "video"]:  # COLMAP's part, played: one clip refused, the others registered
    if "refused" in args[2]:
        print("liquidgs data video: error: COLMAP could not start a model from any two of the 40 frames")
        sys.exit(2)
    pathlib.Path(args[args.index("--out") + 1]).mkdir()
    print("done: 80/80 frames registered, mean reprojection error 0.30 px, 7755 points")
if args[0] == "eval":  # the scores' files, so the script's resuming can be checked
    from liquidgs.train.run_folder.provenance import source_record
    run = pathlib.Path(args[args.index("--run") + 1])
    source = source_record(run, "0123abcd", 1500, run / "checkpoint.pt")
    (run / "eval.json").write_text(json.dumps({"masks": args[args.index("--mask") + 1], "iteration": 1500,
                                               "finished": True, "source": source}))
    (run / "eval_per_view.json").write_text("{}")
if args[:2] == ["experiment", "run"]:  # one finished run of the cat, one unfinished
    runs = pathlib.Path(args[args.index("--out") + 1]) / "real-clips" / "cat"
    for field, done in (("mlp", True), ("cfc", False)):
        (runs / field / "0123abcd").mkdir(parents=True, exist_ok=True)
        if done:
            (runs / field / "0123abcd" / "checkpoint.pt").write_bytes(b"trained")
            (runs / field / "0123abcd" / "results.json").write_text(
                '{"seed": 0, "iterations": 1500, "final_aligned": {"psnr": 20.0}}')
"""


@pytest.mark.slow  # COLMAP and an experiment
def test_the_rebuild_script_downloads_registers_each_clip_and_runs_the_spec(server, monkeypatch, tmp_path):
    """scripts/real_clips.sh with the real downloader against 127.0.0.1 and `data video` / `experiment`
    played by a stub: every clip registered as the benchmark was, a refused clip said and passed over,
    the spec run on the scenes; run again, only the experiment steps repeat."""
    serve_clips(server, monkeypatch, {"apple": b"a" * 300, "refused": b"r" * 200, "cat": b"c" * 100},
                refused={"licence": "CC BY 4.0", "moving": "nothing"})  # fmt: skip
    stub = tmp_path / "liquidgs_stub.py"
    stub.write_text(STUB_LIQUIDGS)
    script = Path(__file__).parents[1] / "scripts" / "real_clips.sh"
    env = {**os.environ, "LIQUIDGS": f"{sys.executable} {stub}", "PYTHON": sys.executable}
    run = subprocess.run(["bash", str(script), str(tmp_path / "bench")], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    calls = [json.loads(line) for line in (tmp_path / "liquidgs_stub.py.calls").read_text().splitlines()]
    bench = tmp_path / "bench"
    assert calls[0] == ["data", "download", "real-clips", str(bench / "clips")]
    videos = sorted(call[2] for call in calls if call[:2] == ["data", "video"])
    assert videos == [str(bench / "clips" / f"{name}.mp4") for name in ("apple", "cat", "refused")]
    for call in calls[1:4]:
        clip = Path(call[2]).stem
        assert call[3:] == ["--out", str(bench / "scenes" / clip), "--max-size", "640", "--frames", "80",
                            "--threads", "1"]  # fmt: skip
    specs = script.parents[1] / "docs" / "experiments"
    scenes, masks = str(bench / "scenes"), str(bench / "masks" / "cat")
    experiment, without = str(bench / "experiment"), str(bench / "experiment-without-regularisers")
    motion = ["defaults", "defaults-3000", "3000", "motion", "motion-with-tracks", "motion-without-flow",
              "motion-without-split"]  # fmt: skip
    assert calls[4:14] == [
        ["experiment", "run", str(specs / "real-clips.yml"), "--data-root", scenes, "--out", experiment],
        ["experiment", "run", str(specs / "real-clips-without-regularisers.yml"), "--data-root", scenes,
         "--out", without],
        *(["experiment", "run", str(specs / f"real-clips-{spec}.yml"), "--data-root", scenes, "--out",
           str(bench / f"experiment-{spec}")] for spec in motion),
        ["eval", "--run", f"{without}/real-clips/cat/mlp/0123abcd", "--mask", masks],
    ]  # fmt: skip
    # The runs with and without the motion evidence: scored in the scene's own masks (kept aside), then
    # in the boxes.
    motion_runs = [bench / folder / "real-clips" / "cat" / "mlp" / "0123abcd"
                   for folder in ["experiment", *(f"experiment-{spec}" for spec in motion)]]  # fmt: skip
    scored = [["eval", "--run", str(r), "--mask", m, *(["--flow-error"] if m == "auto" else [])]
              for r in motion_runs for m in ("auto", masks)]  # fmt: skip
    assert sorted(calls[14:30]) == sorted(scored)
    for motion_run in motion_runs:
        assert calls.index(["eval", "--run", str(motion_run), "--mask", "auto", "--flow-error"]) < \
            calls.index(["eval", "--run", str(motion_run), "--mask", masks])  # fmt: skip
        assert json.loads((motion_run / "eval-auto.json").read_text())["masks"] == "auto"
        assert json.loads((motion_run / "eval.json").read_text())["masks"] == masks
        assert (motion_run / "eval-auto_per_view.json").is_file() and (motion_run / "eval_per_view.json").is_file()
    reports = [experiment, without, *(str(bench / f"experiment-{spec}") for spec in motion)]
    assert calls[30:] == [["experiment", "report", folder] for folder in reports]
    # The specs compared pair by pair: the stub's runs have no static model beside them.
    assert (bench / "comparisons.md").read_text().startswith("nothing to compare yet")
    # The masks: every test view of every moving clip, its box 255 inside at the view's size.
    boxes = json.loads((script.parents[1] / "docs" / "experiments" / "real-clips-boxes.json").read_text())["clips"]
    assert sorted(p.name for p in (bench / "masks").iterdir()) == sorted(boxes) and "apple" not in boxes
    for clip, entry in boxes.items():
        for view, (x0, y0, x1, y1) in entry["boxes"].items():
            mask = np.asarray(Image.open(bench / "masks" / clip / f"{view}.png"))
            assert mask.shape == (entry["size"][1], entry["size"][0]) and mask.sum() == 255 * (x1 - x0) * (y1 - y0)
            assert mask[y0, x0] == mask[y1 - 1, x1 - 1] == 255
    assert "apple: done: 80/80 frames registered" in run.stdout
    assert "refused: data video refused it: liquidgs data video: error: COLMAP could not start" in run.stderr
    assert sorted(p.name for p in (bench / "scenes").iterdir()) == ["apple", "cat"]
    again = subprocess.run(["bash", str(script), str(bench)], env=env, capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    calls_again = [json.loads(line) for line in (tmp_path / "liquidgs_stub.py.calls").read_text().splitlines()][39:]
    # The runs with and without the motion evidence, scored both ways, are not scored again.
    assert [call[:2] for call in calls_again] == [["data", "video"]] + [["experiment", "run"]] * 9 + \
        [["eval", "--run"]] + [["experiment", "report"]] * 9  # fmt: skip
    assert calls_again[0][2] == str(bench / "clips" / "refused.mp4")  # the refused clip is tried again


def test_the_subject_boxes_are_drawn_on_the_test_views_the_rebuild_script_registers():
    """real-clips-boxes.json names, for each moving clip, exactly the test views that `data video
    --frames N` (N from scripts/real_clips.sh) holds out of a clip of that many frames, at the size the
    spec trains at: boxes drawn for another registration would score nothing or the wrong frames."""
    from liquidgs.data.capture import CaptureSettings, held_out_views
    from liquidgs.data.video import select_evenly

    root = Path(__file__).parents[1]
    frames = int(re.search(r"--frames (\d+)", (root / "scripts" / "real_clips.sh").read_text()).group(1))
    boxes = json.loads((root / "docs" / "experiments" / "real-clips-boxes.json").read_text())["clips"]
    spec = load_spec(str(root / "docs" / "experiments" / "real-clips.yml"))
    downscale = {g.scenes[0]: g.overrides["downscale"] for g in spec.grids}
    assert set(boxes) == {name for name, clip in CLIPS.items() if clip.moving and name in downscale}
    for clip, entry in boxes.items():
        ids = [f"{n:06d}" for n in select_evenly(entry["clip_frames"], frames)]
        assert list(entry["boxes"]) == held_out_views(ids, CaptureSettings().holdout_every), clip
        assert entry["downscale"] == downscale[clip], clip


def test_the_rebuild_script_wants_one_folder(tmp_path):
    script = Path(__file__).parents[1] / "scripts" / "real_clips.sh"
    run = subprocess.run(["bash", str(script)], capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 2 and run.stderr == "usage: scripts/real_clips.sh DIR\n"
    assert list(tmp_path.iterdir()) == []


def test_the_benchmark_spec_trains_every_field_on_clips_of_the_set_with_their_quick_look():
    """docs/experiments/real-clips.yml: static / MLP / CfC / HexPlane with the quick look that
    `data video` prints for the clip's registered size (scripts/real_clips.sh's 640 px, 80 frames)."""
    from liquidgs.commands.data import quick_look_commands

    spec = load_spec(str(Path(__file__).parents[1] / "docs" / "experiments" / "real-clips.yml"))
    registered = {"apple": (632, 352), "cat": (368, 484), "lady-running": (644, 360), "backpack": (364, 472),
                  "teddy": (352, 464), "pillow": (364, 476)}
    for grid in spec.grids:
        assert grid.fields == ("static", "mlp", "cfc", "hexplane") and grid.preset == "tiny"
        (clip,) = grid.scenes
        assert clip in CLIPS
        printed = quick_look_commands(Path("scenes") / clip, registered[clip])[1]
        # No motion evidence, written out so the runs do not follow the defaults (real-clips-motion.yml: with it).
        assert grid.overrides["flow.weight"] == 0 and grid.overrides["split.apply"] is False, clip
        for setting, value in grid.overrides.items():
            if setting not in ("flow.weight", "split.apply"):
                assert f"--{setting.replace('_', '-')} {value:g}" in printed, (clip, setting, printed)
    assert {g.scenes[0] for g in spec.grids} == set(registered)
    # Two seeds of every clip: ten (clip, seed) pairs of moving clips for the verdict rule, the static
    # model's seed spread (the rule's floor) measured on each of them, and the still clip's bound twice.
    assert all(list(g.seeds) == [0, 1] for g in spec.grids)


def test_the_benchmark_with_the_motion_evidence_differs_from_the_benchmark_only_in_it():
    """docs/experiments/real-clips-motion.yml: real-clips.yml's runs (every field, both seeds) with the
    flow loss and the split set on; its ablations the fields that deform with one piece off each."""
    folder = Path(__file__).parents[1] / "docs" / "experiments"
    spec = load_spec(str(folder / "real-clips.yml"))
    base = {(g.scenes, f, tuple(g.seeds)): g.overrides for g in spec.grids for f in g.fields}
    pieces = {"real-clips-motion": {"flow.weight": 0.02, "split.apply": True},
              "real-clips-motion-with-tracks": {"flow.weight": 0.02, "flow.tracks": True, "split.apply": True},
              "real-clips-motion-without-flow": {"flow.weight": 0, "split.apply": True},
              "real-clips-motion-without-split": {"flow.weight": 0.02, "split.apply": False}}  # fmt: skip
    for name, evidence in pieces.items():
        motion = load_spec(str(folder / f"{name}.yml"))
        runs = {(g.scenes, f, tuple(g.seeds)): g.overrides for g in motion.grids for f in g.fields}
        wanted = {key for key in base if "without" not in name or key[1] != "static"}
        assert runs.keys() == wanted and motion.name == name, name
        for key, overrides in runs.items():
            assert overrides == {**base[key], **evidence}, (name, key)


def test_the_benchmark_at_the_defaults_differs_from_the_benchmark_only_in_the_defaults_evidence():
    """docs/experiments/real-clips-defaults.yml: real-clips.yml's runs with the motion evidence a capture
    with flow gets by default, written out: the flow loss at its default weight, the split, and HexPlane
    (the built-in field with neighbour terms) without them, as the split decided from the scene sets them."""
    from liquidgs.train.flow_loss import DEFAULT_WEIGHT
    from liquidgs.train.motion_reg import MotionRegConfig, split_in_place_of_neighbour_terms

    folder = Path(__file__).parents[1] / "docs" / "experiments"
    base = {(g.scenes, f, tuple(g.seeds)): g.overrides for g in load_spec(str(folder / "real-clips.yml")).grids
            for f in g.fields}  # fmt: skip
    spec = load_spec(str(folder / "real-clips-defaults.yml"))
    runs = {(g.scenes, v.field, tuple(g.seeds)): {**g.overrides, **v.overrides} for g in spec.grids for v in g.variants}
    assert runs.keys() == base.keys() and spec.name == "real-clips-defaults"
    for key, overrides in runs.items():
        terms = split_in_place_of_neighbour_terms(MotionRegConfig(), key[1])
        dropped = {f"motion.{name}": 0 for name in ("rigidity", "isometry") if getattr(terms, name) == 0.0}
        assert bool(dropped) == (key[1] == "hexplane"), key
        assert overrides == {**base[key], "flow.weight": DEFAULT_WEIGHT, "split.apply": True, **dropped}, key


@pytest.mark.parametrize("quick_name", ["real-clips", "real-clips-defaults"])
def test_the_benchmark_at_3000_iterations_differs_from_its_quick_look_only_in_the_schedule(quick_name):
    """docs/experiments/real-clips-3000.yml and real-clips-defaults-3000.yml: the runs of real-clips.yml
    (no motion evidence) and real-clips-defaults.yml (the evidence) with the quick look's schedule
    doubled - the learning rates decaying over 3,000 steps, densification stopping at twice the quick
    look's step, still no opacity reset within the run - and one evaluation, at the end."""
    from liquidgs.train.config import preset_config

    folder = Path(__file__).parents[1] / "docs" / "experiments"

    def runs(name):
        spec = load_spec(str(folder / f"{name}.yml"))
        return spec, {(g.scenes, v.field, tuple(g.seeds)): {**g.overrides, **v.overrides}
                      for g in spec.grids for v in g.field_variants()}  # fmt: skip

    _, quick = runs(quick_name)
    spec, longer = runs(f"{quick_name}-3000")
    tiny = preset_config("tiny", Path("."))
    schedule = {"iterations": 2 * tiny.iterations, "optim.means_lr_steps": 2 * tiny.iterations,
                "optim.field_lr_steps": 2 * tiny.iterations, "densify.stop": 2 * tiny.densify.stop,
                "densify.opacity_reset_interval": 6000, "eval.start": 2 * tiny.iterations}  # fmt: skip
    assert longer.keys() == quick.keys() and spec.name == f"{quick_name}-3000"
    for key, overrides in longer.items():
        assert overrides == {**quick[key], **schedule}, key
        assert overrides["densify.opacity_reset_interval"] > overrides["iterations"]  # no reset within the run


def test_the_benchmark_without_regularisers_differs_from_the_benchmark_only_in_them():
    """docs/experiments/real-clips-without-regularisers.yml: seed 0 of the same runs of the fields that
    deform, with every motion weight at 0 and nothing else changed, where by default each field has one
    of them; so its margins against real-clips.yml say what the regularisers do."""
    from liquidgs.train.motion_reg import MotionRegConfig

    folder = Path(__file__).parents[1] / "docs" / "experiments"
    spec = load_spec(str(folder / "real-clips.yml"))
    without = load_spec(str(folder / "real-clips-without-regularisers.yml"))
    runs = {(g.scenes, f): g.overrides for g in spec.grids for f in g.fields if f != "static"}
    bare = {(g.scenes, f): g.overrides for g in without.grids for f in g.fields}
    assert bare.keys() == runs.keys() and all(list(g.seeds) == [0] for g in without.grids)
    for (scenes, field), overrides in runs.items():
        assert any(MotionRegConfig().weights(field)), field
        assert bare[scenes, field] == {**overrides, "motion.rigidity": 0, "motion.isometry": 0, "motion.stillness": 0}
