"""Old and new camera registration on the same clips, paired in one sitting: wall and CPU seconds, and
how far the new poses are from the old (liquidgs.data.pose_accuracy), and from the truth where known.

    python scripts/registration_bench.py --old-src /path/to/old/checkout/src --out DIR [--new-args ARGS] CLIP ...

A video is registered by `data video --frames 80 --max-size 640 --no-flow` (the real-clip
benchmark's settings, without the flow that follows registration), a folder of images by `data images
--max-size 640 --no-flow`, with the old checkout's code, then with this one's; CPU time is the child's
(resource.getrusage), so other load on the machine shows in wall time only. A folder may have a
truth.txt beside it (<folder>.truth.txt): one line per image, camera centre x y z then its
camera-to-world rotation row by row, in OpenGL's camera axes (x right, y up, z backwards; the New
Tsukuba truth's); both runs are then scored against it. Prints one line per run
and the scores per clip.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "src"))
from liquidgs.data.pose_accuracy import scene_poses, score_poses, score_scenes  # noqa: E402

NEW_SRC = Path(__file__).resolve().parent.parent / "src"


def register(src: Path, clip: Path, out: Path, extra: list[str]) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    if clip.is_dir():
        command = [sys.executable, "-m", "liquidgs.cli", "data", "images", str(clip), "--out", str(out),
                   "--max-size", "640", "--no-flow", *extra]  # fmt: skip
    else:
        command = [sys.executable, "-m", "liquidgs.cli", "data", "video", str(clip), "--out", str(out),
                   "--frames", "80", "--max-size", "640", "--no-flow", *extra]  # fmt: skip
    result = subprocess.run(command, env={**os.environ, "PYTHONPATH": str(src)}, capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    (out.parent / f"{out.name}.log").write_text(result.stdout + result.stderr)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    record = {"wall_s": round(time.perf_counter() - started, 1), "cpu_s": round(cpu, 1), "code": result.returncode}
    if result.returncode == 0:
        capture = json.loads((out / "capture.json").read_text())
        record |= {key: capture[key] for key in ("frames_registered", "mean_reprojection_error_px")}
        record["attempt"] = capture["camera_solve"]["attempt"]
        record["stages_s"] = capture["seconds"]
    else:
        record["error"] = result.stderr.strip().splitlines()[-1] if result.stderr.strip() else ""
    return record


def truth_poses(truth_file: Path) -> np.ndarray:
    """truth.txt's cameras as [N, 4, 4] camera-to-world poses in OpenCV's camera axes, the scenes'."""
    rows = np.loadtxt(truth_file).reshape(-1, 12)
    truth = np.tile(np.eye(4), (len(rows), 1, 1))
    opengl_to_opencv = np.diag([1.0, -1.0, -1.0])  # y and z flipped
    truth[:, :3, 3], truth[:, :3, :3] = rows[:, :3], rows[:, 3:].reshape(-1, 3, 3) @ opengl_to_opencv
    return truth


def against_truth(scene: Path, truth_file: Path) -> str:
    """The scene's cameras (image folder runs: ids are positions in name order) against truth.txt's."""
    truth = truth_poses(truth_file)
    poses = scene_poses(scene)
    return score_poses(np.stack(list(poses.values())), truth[[int(i) for i in poses]]).describe()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old-src", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--new-args", default="", help="more arguments for the new run, e.g. '--matcher flow'")
    parser.add_argument("clips", type=Path, nargs="+")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=False)
    results = {}
    for clip in args.clips:
        runs = {}
        for name, src in (("old", args.old_src), ("new", NEW_SRC)):
            print(f"{clip.stem} {name}: load {os.getloadavg()[0]:.2f}", flush=True)
            extra = args.new_args.split() if name == "new" else []
            runs[name] = register(src, clip, args.out / f"{clip.stem}-{name}", extra)
            print(f"{clip.stem} {name}: {json.dumps(runs[name])}", flush=True)
        if runs["old"]["code"] == runs["new"]["code"] == 0:
            score = score_scenes(args.out / f"{clip.stem}-new", args.out / f"{clip.stem}-old")
            runs["agreement"] = score.describe()
            print(f"{clip.stem} new against old: {score.describe()}", flush=True)
        truth_file = clip.with_name(f"{clip.name}.truth.txt")
        if truth_file.is_file():
            for name in ("old", "new"):
                if runs[name]["code"] == 0:
                    runs[f"{name}_against_truth"] = against_truth(args.out / f"{clip.stem}-{name}", truth_file)
                    print(f"{clip.stem} {name} against the truth: {runs[f'{name}_against_truth']}", flush=True)
        results[clip.stem] = runs
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
