"""COLMAP's SIFT settings against the time they cost and the poses they give, on one clip's frames.

    python scripts/sift_settings_bench.py CLIP --out DIR VARIANT ...

CLIP is a video (80 frames kept) or a folder of images, scaled to a 640-px longer side as
scripts/registration_bench.py scales them. Each VARIANT ("base", or comma-separated key=value:
n = sift.max_num_features, oct = sift.first_octave, pt = sift.peak_threshold, mo =
sift.max_num_orientations, size = max_image_size, ov = the sequential overlap) runs features,
sequential matching and the global mapper with the pipeline's settings (liquidgs.data.colmap),
all cores, and prints one JSON line: wall and CPU seconds per stage (this process, every thread),
keypoints per frame, frames registered, mean reprojection error, the lens, and the poses scored
(liquidgs.data.pose_accuracy) against the truth (a folder's <folder>.truth.txt, registration_bench's
format) and against the "base" variant's poses when that ran first into the same DIR.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "src"))
from registration_bench import truth_poses  # noqa: E402

from liquidgs.data.colmap import CAMERA_MODEL, GLOBAL_TRACKS_PER_VIEW, SEED, SEQUENTIAL_OVERLAP  # noqa: E402
from liquidgs.data.pose_accuracy import score_poses  # noqa: E402
from liquidgs.data.stage_times import StageTimes  # noqa: E402
from liquidgs.data.video import collect_image_frames, extract_video_frames  # noqa: E402

SIFT_KEYS = {"n": ("max_num_features", int), "oct": ("first_octave", int), "pt": ("peak_threshold", float),
             "mo": ("max_num_orientations", int)}  # fmt: skip


def frames_of(clip: Path, out: Path) -> Path:
    frames = out / "frames"
    if not frames.exists():
        frames.mkdir(parents=True)
        if clip.is_dir():
            collect_image_frames(clip, frames, max_size=640, log=lambda _: None)
        else:
            extract_video_frames(clip, frames, fps=None, frames=80, max_size=640, log=lambda _: None)
    return frames


def run_variant(pycolmap, frames: Path, work: Path, variant: str) -> tuple[dict, dict[str, np.ndarray]]:
    settings = dict(item.split("=") for item in variant.split(",")) if variant != "base" else {}
    database = work / "database.db"
    times = StageTimes()
    with times.stage("features"):
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = CAMERA_MODEL
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.max_image_size = int(settings.get("size", -1))
        for key, (name, kind) in SIFT_KEYS.items():
            if key in settings:
                setattr(extraction.sift, name, kind(settings[key]))
        names = sorted(path.name for path in frames.iterdir())
        pycolmap.extract_features(
            database, frames, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
            extraction_options=extraction, device=pycolmap.Device.cpu,
        )  # fmt: skip
    with times.stage("matching"):
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = int(settings.get("ov", SEQUENTIAL_OVERLAP))
        pycolmap.match_sequential(database, pairing_options=pairing, device=pycolmap.Device.cpu)
    with times.stage("mapping"):
        mapping = pycolmap.GlobalPipelineOptions()
        mapping.random_seed = SEED
        mapping.mapper.track_required_tracks_per_view = GLOBAL_TRACKS_PER_VIEW
        (work / "sparse").mkdir()
        models = pycolmap.global_mapping(database, frames, work / "sparse", options=mapping)
    with pycolmap.Database.open(database) as opened:
        keypoints = opened.num_keypoints() / opened.num_images()
    model = max(models.values(), key=lambda m: (m.num_reg_images(), m.num_points3D()))
    poses = {}
    for image in model.images.values():
        if image.has_pose:
            poses[image.name] = np.eye(4)
            poses[image.name][:3, :4] = image.cam_from_world().inverse().matrix()
    recorded = times.record()
    record = {"variant": variant, "load": round(os.getloadavg()[0], 2), "keypoints_per_frame": round(keypoints),
              "wall_s": recorded["wall"], "cpu_s": recorded["cpu"], "registered": model.num_reg_images(),
              "frames": len(names), "points": model.num_points3D(),
              "reprojection_px": round(model.compute_mean_reprojection_error(), 3),
              "camera": [round(float(value), 4) for value in model.cameras[1].params]}  # fmt: skip
    return record, poses


def score(poses: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> str:
    shared = sorted(set(poses) & set(reference))
    return score_poses(np.stack([poses[k] for k in shared]), np.stack([reference[k] for k in shared])).describe()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clip", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("variants", nargs="+")
    args = parser.parse_args()
    import pycolmap

    pycolmap.logging.minloglevel = 3
    frames = frames_of(args.clip, args.out)
    truth_file = args.clip.with_name(f"{args.clip.name}.truth.txt")
    for variant in args.variants:
        work = args.out / variant
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir()
        started = time.perf_counter()
        record, poses = run_variant(pycolmap, frames, work, variant)
        if truth_file.is_file():
            truth = truth_poses(truth_file)
            record["against_truth"] = score(poses, {f"{n:06d}.png": pose for n, pose in enumerate(truth)})
        base = args.out / "base" / "poses.npz"
        if variant != "base" and base.is_file():
            record["against_base"] = score(poses, dict(np.load(base)))
        np.savez(work / "poses.npz", **poses)
        shutil.rmtree(work / "sparse")
        (work / "database.db").unlink()
        record["total_wall_s"] = round(time.perf_counter() - started, 1)
        print(json.dumps(record), flush=True)


if __name__ == "__main__":
    main()
