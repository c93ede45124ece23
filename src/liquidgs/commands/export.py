"""`liquidgs export --run DIR`: PLY files that standard 3DGS viewers open.

Writes DIR/export/canonical.ply, field.pt (the field's weights and config, to evaluate it
elsewhere; "moving": the rows of canonical.ply a split run's field moves, None for all), one PLY
per --time with the deltas baked in, and with --sequence N a PLY
sequence sequence/frame_0000.ply ... at N evenly spaced times (SuperSplat/brush timelines), built
beside sequence/ and renamed into place whole (an older sequence is replaced only by a complete one).
DIR may be a baked scene (`liquidgs bake`; no field.pt then). Every file records the source
of what it holds (the run's checkpoint iteration and hash, the scene print): in a PLY header
comment, field.pt's "source", the splatv header, the web folder's scene.json.

--format plyseq writes only sequence.zip, the --sequence N frames as one .zip of PLYs (Brush
plays it); --format splatv writes only scene.splatv, splaTV's motion model fitted to the run
(see liquidgs.bake.pieces: a cubic per Gaussian, or several short-lived pieces where its motion
needs them), with the share of the motion it keeps and its PSNR against the run printed;
--format web writes OUT/web, a static page with its WebGL2 player and the baked scene (a run is
baked on the way with the default budget) that plays offline from any static file server;
--format html writes OUT/scene.html, the same page with the scene inside it, one file that opens
from disk; --format spz writes time_T.spz per --time, the Gaussians at that time in Niantic's
compressed SPZ (liquidgs.bake.spz), which most 3DGS viewers open.
"""

from __future__ import annotations

import dataclasses
import math
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import torch
from rich.console import Console
from rich.progress import track

from liquidgs.atomic import build_atomically, save_torch_atomic, write_atomic
from liquidgs.bake.distil import check_finished
from liquidgs.bake.formats import (
    SPLATV_CAMERA_WIDTH,
    check_frames_finite,
    frame_params,
    parse_splatv,
    sequence_times,
    splatv_bytes,
    splatv_camera,
    write_plyseq,
)
from liquidgs.bake.pieces import MAX_PIECES, agreement, fit_splatv, fit_within_bytes, pixel_weights
from liquidgs.bake.spz import write_spz
from liquidgs.bake.web import write_web, write_web_page
from liquidgs.errors import ConfigError, check_finite
from liquidgs.gaussians import write_ply
from liquidgs.settings import parse_flags
from liquidgs.train.run import load_run
from liquidgs.train.run_folder import source_comment


@dataclass
class ExportArgs:
    run: Path
    """A run folder, or a baked scene (`liquidgs bake`)."""
    out: Path | None = None
    """Default: DIR/export."""
    time: list[float] = field(default_factory=list)
    """Times in [0,1] to export a deformed PLY (or with --format spz, an SPZ file) for."""
    sequence: int = 0
    """Number of evenly spaced frames of a PLY sequence (0: none; at most 100,000); with --format
    plyseq, of the .zip."""
    format: Literal["ply", "plyseq", "splatv", "web", "html", "spz"] = "ply"
    """ply: the PLYs above; plyseq: OUT/sequence.zip of --sequence PLYs; splatv: OUT/scene.splatv;
    web: OUT/web, a static folder that plays the scene in a browser; html: OUT/scene.html, that
    page as one file that opens from disk; spz: OUT/time_T.spz per --time, static SPZ files."""
    splatv_tolerance: float | None = None
    """--format splatv: each piece's budget, its position within this fraction of the Gaussian's size
    (counted as at least 4 pixel widths) and its rotation within this many radians wherever it shows,
    loosened for a Gaussian by how little of the picture it makes (its pixel share). Lower keeps more
    of the motion in more pieces; pieces' windows 0.7 of their spacing. Unset: for windows of 0.55,
    0.6 and 0.7, the budgets 0.5, 0.3 and the tightest that keeps the file within 4 records per
    Gaussian; the fit closest to the run on its train views is written (docs/results/sharing.md)."""
    splatv_pieces: int = MAX_PIECES
    """--format splatv: the most temporal pieces per Gaussian (of 1, 2, 3, 5, 9, 17, 33: the largest
    not above it); a Gaussian still over budget at the most is written with the most."""
    device: str = "auto"
    """auto (CUDA where torch sees a GPU, else the CPU), cpu, cuda or cuda:N."""


MOST_SPLATV_PIECES = 33
"""The most --splatv-pieces: at 33 a piece's window still shows it at about 11 of the 129 motion samples
its cubic is fitted to; at 65, about 5."""
MAX_SEQUENCE = 100_000
"""The most --sequence frames (one PLY each): 100x a 1,000-frame capture."""


def time_file_name(time: float, suffix: str = ".ply") -> str:
    return f"time_{time + 0.0:.4f}{suffix}"  # + 0.0 turns -0.0 into 0.0


def export_run(args: ExportArgs, console: Console | None = None) -> list[Path]:
    """The files written, each once: times that name the same file (0.5 twice, -0.0 and 0.0) write it once."""
    names: dict[str, float] = {}
    for t in args.time:
        if not (math.isfinite(t) and 0.0 <= t <= 1.0):
            raise ConfigError(f"--time {t} is outside [0, 1]")
        name = time_file_name(t, ".spz" if args.format == "spz" else ".ply")
        if name in names and names[name] != t:
            raise ConfigError(f"--time {names[name]} and {t} would both be written to {name}")
        names[name] = t
    if not 0 <= args.sequence <= MAX_SEQUENCE:
        raise ConfigError(f"--sequence must be between 0 and {MAX_SEQUENCE:,}, got {args.sequence:,}")
    if args.format not in ("ply", "spz") and args.time:
        raise ConfigError(f"--time writes single PLYs or SPZs: it goes with --format ply or spz, not {args.format}")
    if args.format == "spz" and not args.time:
        raise ConfigError("--format spz needs --time T, the time in [0, 1] to export (one file per --time)")
    if (
        args.format in ("splatv", "web", "html", "spz") and args.sequence
    ):  # their motion is continuous: no frames to count
        raise ConfigError(f"--sequence has no effect with --format {args.format}: it sets the frames of ply and plyseq")
    if args.splatv_tolerance is not None and not (math.isfinite(args.splatv_tolerance) and args.splatv_tolerance > 0):
        raise ConfigError(f"--splatv-tolerance must be a positive number, got {args.splatv_tolerance}")
    if not 1 <= args.splatv_pieces <= MOST_SPLATV_PIECES:
        raise ConfigError(f"--splatv-pieces must be between 1 and {MOST_SPLATV_PIECES}, got {args.splatv_pieces}")
    if args.format != "splatv" and (args.splatv_tolerance is not None or args.splatv_pieces != MAX_PIECES):
        raise ConfigError(
            f"--splatv-tolerance and --splatv-pieces set the splatv fit: no effect with --format {args.format}"
        )
    if args.format == "plyseq" and args.sequence < 2:
        raise ConfigError("--format plyseq needs --sequence N, the number of frames (at least 2)")
    run = load_run(args.run, args.device)
    if args.format in ("web", "html"):  # it bakes the run on the way, which bake does for finished runs only
        check_finished(run, f"export --format {args.format}")
    if console is not None and not run.finished:
        console.print(f"[yellow]note:[/] {args.run}: {run.progress_label}")
    out = args.out or args.run / "export"
    if args.format == "plyseq":
        return [write_plyseq(out / "sequence.zip", run, args.sequence)]
    if args.format == "splatv":
        return [export_splatv(run, out / "scene.splatv", console, args.splatv_tolerance, args.splatv_pieces)]
    if args.format == "web":
        return [write_web(out / "web", run, run.scene())]
    if args.format == "html":
        return [write_web_page(out / "scene.html", run, run.scene())]
    if args.format == "spz":
        check_frames_finite(run, list(names.values()))
        return [write_spz(out / name, frame_params(run, t), run.sh_degree) for name, t in names.items()]
    check_frames_finite(run, [*names.values(), *sequence_times(args.sequence)])
    field_weights = {} if run.field is None else run.field.state_dict()  # a baked scene has no network
    check_finite(args.run, "the field's weights", field_weights)
    source = run.source()
    comments = (source_comment(source),)
    written = [write_ply(out / "canonical.ply", run.params, comments)]
    if run.field is not None:
        payload = {
            "config": dataclasses.asdict(run.config.field_config()),
            "state_dict": field_weights,
            "source": source,
            # A split run's field moves only these rows of canonical.ply (None: every row).
            "moving": None if getattr(run, "moving", None) is None else run.moving.cpu(),
        }
        written.append(save_torch_atomic(out / "field.pt", payload))
    for name, t in names.items():
        written.append(write_ply(out / name, frame_params(run, t), comments))
    if args.sequence:
        written += export_sequence(run, out / "sequence", args.sequence, comments, console)
    return written


def export_sequence(run, folder: Path, frames: int, comments: tuple[str, ...], console: Console | None) -> list[Path]:
    """frame_0000.ply ... at `frames` evenly spaced times, built beside `folder` and renamed into
    place whole: a player never finds part of a sequence, nor frames of an older one."""
    times = sequence_times(frames)
    names = [f"frame_{i:04d}.ply" for i in range(frames)]

    def build(building: Path) -> None:
        # closing: a failed frame ends the progress bar before the error line, not at the next GC.
        with closing(track(times, description="PLY sequence", console=console, disable=console is None)) as shown:
            for name, t in zip(names, shown):
                write_ply(building / name, frame_params(run, t), comments)

    build_atomically(folder, build, replace=True)
    return [folder / name for name in names]


def export_splatv(
    run, path: Path, console: Console | None, tolerance: float | None = None, pieces: int = MAX_PIECES
) -> Path:
    """splaTV's motion model fitted to the run (or baked scene); the dataset's cameras go along,
    test views first (the player starts at the first), resized for a player's window. Prints the
    pieces, the budget, the share of the motion kept and the PSNR of the file against the run on its
    test views."""
    dataset = run.scene()
    frames = [*dataset.test, *dataset.train]
    background = torch.tensor(dataset.background, dtype=torch.float32)
    if tolerance is None:
        fitted = fit_within_bytes(run, frames, dataset.train, background, pieces)
    else:
        fitted = fit_splatv(run, [f.camera for f in frames], tolerance, pieces, pixel_weights(run, frames, background))
    check_finite(run.run_dir, "the fitted splatv model", vars(fitted.model))
    cameras = [splatv_camera(f.camera, f.name, SPLATV_CAMERA_WIDTH) for f in frames]
    data = splatv_bytes(fitted.model, cameras, run.source())
    as_stored, _ = parse_splatv(data, path)
    scores = agreement(run, as_stored, dataset.test or dataset.train[:AGREEMENT_VIEWS], background)
    written = write_atomic(path, lambda tmp: tmp.write_bytes(data))
    if console is not None:
        report = fitted.report
        n = run.params["means"].shape[0]
        pieces = ", ".join(f"{count:,} x {p}" for p, count in report["pieces"].items())
        kept = fitted.motion_kept
        kept = (
            "the run has no motion (no Gaussian moves), so there is none to keep"
            if kept is None
            else f"it keeps {100 * kept:.1f}% of the motion"
        )
        by_share = report.get("motion_kept_by_share")
        if kept is not None and by_share is not None:  # None: what moves shows in no view
            kept += f" ({100 * by_share:.1f}% weighted by each Gaussian's pixel share)"
        against = "the field" if run.field is not None else "the baked scene"
        console.print(
            f"splatv: {kept}; {report['records']:,} records for {n:,} Gaussians (Gaussians x pieces: {pieces}; "
            f"budget {report['tolerance']:.3g}, weighted by each Gaussian's pixel share; "
            f"windows {report['window']:g} of the pieces' spacing); "
            f"{sum(scores) / len(scores):.1f} dB against {against} on {len(scores)} views (worst {min(scores):.1f})",
            highlight=False,
        )
    return written


AGREEMENT_VIEWS = 5
"""Views the splatv file is scored on where the scene has no test views: the first training views."""


def main(argv: list[str]) -> int:
    args = parse_flags(ExportArgs, argv, prog="liquidgs export", description=__doc__)
    console = Console(stderr=True)
    written = export_run(args, console)
    console.print(f"wrote {len(written)} files under {written[0].parent}")
    return 0
