"""Old and new camera registration on the same clips, paired in one sitting: wall and CPU seconds, and
how far the new poses are from the old (liquidgs.data.pose_accuracy).

    python scripts/registration_bench.py --old-src /path/to/old/checkout/src --out DIR CLIP.mp4 ...

Each clip is registered by `data video --frames 80 --max-size 640 --no-flow` (the real-clip
benchmark's settings, without the flow that follows registration) with the old checkout's code, then
with this one's; CPU time is the child's (resource.getrusage), so other load on the machine shows in
wall time only. Prints one line per run and the pose agreement per clip.
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

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "src"))
from liquidgs.data.pose_accuracy import score_scenes  # noqa: E402

NEW_SRC = Path(__file__).resolve().parent.parent / "src"


def register(src: Path, clip: Path, out: Path) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    command = [sys.executable, "-m", "liquidgs.cli", "data", "video", str(clip), "--out", str(out),
               "--frames", "80", "--max-size", "640", "--no-flow"]  # fmt: skip
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old-src", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("clips", type=Path, nargs="+")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=False)
    results = {}
    for clip in args.clips:
        runs = {}
        for name, src in (("old", args.old_src), ("new", NEW_SRC)):
            print(f"{clip.stem} {name}: load {os.getloadavg()[0]:.2f}", flush=True)
            runs[name] = register(src, clip, args.out / f"{clip.stem}-{name}")
            print(f"{clip.stem} {name}: {json.dumps(runs[name])}", flush=True)
        if runs["old"]["code"] == runs["new"]["code"] == 0:
            score = score_scenes(args.out / f"{clip.stem}-new", args.out / f"{clip.stem}-old")
            runs["agreement"] = score.describe()
            print(f"{clip.stem} new against old: {score.describe()}", flush=True)
        results[clip.stem] = runs
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
