"""Progress a background job's log can follow (commands.progress): plain lines where the output is
not a terminal, with counts, loss, PSNR, Gaussians, elapsed time and ETA, and the evaluations named."""

from __future__ import annotations

import re

from liquidgs.commands import progress
from tiny_runs import run_cli, tiny_flags

LINE = re.compile(
    r"^train (\d+)/40  loss (-|\d+\.\d{4})  PSNR (-|\d+\.\d\d)  Gaussians [\d,]+  "
    r"elapsed \d+:\d\d:\d\d  ETA (-|\d+:\d\d:\d\d)$"
)


def test_train_into_a_file_prints_plain_progress_lines_at_its_interval(puppet_scene, tmp_path, monkeypatch):
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 0.0)  # every step, so the test sees many
    code, _, err = run_cli(
        ["train", "--data", str(puppet_scene), "--field", "mlp", *tiny_flags(), "--out", str(tmp_path / "a")]
    )
    assert code == 0, err
    lines = err.splitlines()
    progress_lines = [m for m in map(LINE.match, lines) if m]
    steps = [int(m[1]) for m in progress_lines]
    assert steps == list(range(41)), lines[:5]  # the start, then every step (no bar redrawn)
    shown = [m.group(2, 3) for m in progress_lines]
    assert shown[0] == ("-", "-") and "-" not in {v for pair in shown[1:] for v in pair}  # nothing measured yet
    assert not re.search(r"\bnan\b", err)  # a log that reads "loss nan" looks like a diverged run
    assert "\x1b[" not in err  # no terminal escapes in a log
    assert "evaluation at iteration 20 (2 test views)" in err
    assert "training done; the final evaluation of 2 test views starts" in err
    assert lines.index("evaluation at iteration 20 (2 test views)") < next(
        i for i, line in enumerate(lines) if line.startswith("train 21/40")
    )
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 3600.0)  # a short run: the start and the end only
    code, _, err = run_cli(
        ["train", "--data", str(puppet_scene), "--field", "mlp", *tiny_flags(), "--out", str(tmp_path / "b")]
    )
    assert code == 0, err
    assert [int(m[1]) for m in map(LINE.match, err.splitlines()) if m] == [0, 40]


BAKE_LINE = re.compile(
    r"^bake (\d+)/(\d+) field samples  keyframes (\d+)  Gaussians [\d,]+  elapsed \d+:\d\d:\d\d  ETA (-|\d+:\d\d:\d\d)$"
)


def test_bake_into_a_file_prints_plain_progress_lines_one_per_field_sample(tiny_mlp_run, tmp_path, monkeypatch):
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 0.0)
    keyframes = ["--min-keyframes", "3", "--max-keyframes", "9", "--device", "cpu"]
    code, _, err = run_cli(["bake", "--run", str(tiny_mlp_run), "--out", str(tmp_path / "a"), *keyframes])
    assert code == 0, err
    lines = [m.groups() for m in map(BAKE_LINE.match, err.splitlines()) if m]
    assert "\x1b[" not in err
    # The field sampled at the 9 keyframe times of the most keyframes and the 8 midpoints between them.
    assert [int(done) for done, *_ in lines] == list(range(18)), err
    assert {total for _, total, *_ in lines} == {"17"} and {k for *_, k, _ in lines} == {"9"}
    assert lines[-1][-1] == "0:00:00"


def test_data_flow_names_a_silent_stage_at_the_interval(tmp_path, monkeypatch):
    import time

    from liquidgs.data import flow, generate_synthetic
    from shared_data import require_module

    require_module("cv2")
    scene = generate_synthetic("puppet", tmp_path / "puppet", size=32, frames=16, seed=5) / "nerfies"
    real_flow = flow.optical_flow

    def slow_first(a, b, calls=[]):  # noqa: B006 - the calls made, across calls
        calls.append(1)
        if len(calls) == 1:
            time.sleep(1.0)
        return real_flow(a, b)

    monkeypatch.setattr(flow, "optical_flow", slow_first)
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 0.1)
    code, out, err = run_cli(["data", "flow", str(scene)])
    assert code == 0, err
    lines = out.splitlines()
    first_count = next(i for i, line in enumerate(lines) if line.startswith("flow: "))
    still = [line for line in lines[:first_count] if line.startswith("data flow: still running")]
    # A second of silence in the first pair at 0.1 s: several lines (how many depends on the load).
    assert len(still) >= 2, lines
    assert all(re.fullmatch(r"data flow: still running \(last: started\)  elapsed \d:\d\d:\d\d", x) for x in still)
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 30.0)
    code, out, err = run_cli(["data", "flow", str(scene)])
    assert code == 0 and "still running" not in out, err


def test_data_video_names_colmaps_silent_feature_extraction_at_the_interval(tmp_path, monkeypatch):
    import time

    import numpy as np

    from liquidgs.media import write_video
    from shared_data import require_module

    pycolmap = require_module("pycolmap")
    require_module("cv2")
    wall = tmp_path / "wall.mp4"
    write_video(wall, [np.full((120, 160, 3), 170, np.uint8)] * 16, fps=12)
    real_extract = pycolmap.extract_features

    def slow_extract(*args, **kwargs):
        time.sleep(1.0)
        return real_extract(*args, **kwargs)

    monkeypatch.setattr(pycolmap, "extract_features", slow_extract)
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 0.1)
    code, out, err = run_cli(["data", "video", str(wall), "--out", str(tmp_path / "o"), "--threads", "1"])
    assert code == 2 and "COLMAP found no features" in err, err  # a blank wall: refused after the features
    # A second of silence in COLMAP's feature extraction at 0.1 s: several lines naming the stage before it.
    still = re.findall(
        r"^data video: still running \(last: extraction: 16 frames saved\)  elapsed \d:\d\d:\d\d$", out, re.M
    )
    assert len(still) >= 2, out
