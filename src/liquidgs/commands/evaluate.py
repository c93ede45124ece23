"""`liquidgs eval --run DIR`: re-evaluate a run's checkpoint on its test split.

Writes DIR/eval.json (summary, labelled with the checkpoint's iteration and whether the run
had finished) and DIR/eval_per_view.json, each with the source record of the checkpoint it scored
(its iteration and content hash; `experiment report` refuses scores the run has trained past);
results.json, the training record, is left as it was. A run in progress may be evaluated: its
record says "unfinished run".

The scores are with the test cameras as given. A run that refined its cameras or compensated
exposure is scored a second time with each test view aligned to the frozen scene (its pose, its
exposure), under "aligned" (its "cameras" says how).
--mask DIR adds PSNR / SSIM inside and outside per-view masks of the moving subject, under "masked"
(cameras as given) and, for a run that refined its cameras, "masked_aligned" (test cameras aligned);
--mask auto takes the scene's own motion masks (`data flow`: flow/<k>x/masks at the run's scale).
--flow-error adds, under "flow_error", the end-point error of the Gaussians' rendered motion against
the scene's measured flow over the train pairs (train cameras as given), over the consistent pixels
and inside the motion masks.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from rich.console import Console

from liquidgs.atomic import write_json_atomic
from liquidgs.data.flow import AUTO_MASKS, image_scale, read_flow_pairs, read_motion_masks, scene_motion_masks
from liquidgs.data.nerfies import RGB_FOLDER
from liquidgs.errors import ConfigError
from liquidgs.eval import LPIPS, LPIPSUnavailable, describe_lpips, evaluate_views
from liquidgs.eval.masks import masked_scores, read_masks
from liquidgs.eval.metrics import quantize_8bit
from liquidgs.settings import parse_flags
from liquidgs.train.camera_opt import aligned_render
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.flow_loss import flow_error
from liquidgs.train.model import render_frame
from liquidgs.train.run import load_run
from liquidgs.train.run_folder import EVAL, EVAL_PER_VIEW, check_scene_print, write_per_view


@dataclass
class EvalArgs:
    run: Path
    """Run folder written by `liquidgs train`."""
    split: Literal["test", "val", "train"] = "test"
    """The split to score (val: D-NeRF's val views)."""
    lpips_backbone: Literal["vgg", "alex", "squeeze"] | None = None
    """Default: the backbone the run was trained with."""
    lpips_normalize: bool | None = None
    """LPIPS input normalisation to [-1, 1] (default: as the run was trained)."""
    lpips_weights: Path | None = None
    """LPIPS backbone weights file or folder (default: the run's, else $LIQUIDGS_LPIPS_WEIGHTS)."""
    quantize_8bit: bool | None = None
    """Score renders quantised to 8 bits (default: as the run was trained)."""
    device: str = "auto"
    """auto (CUDA where torch sees a GPU, else the CPU), cpu, cuda or cuda:N."""
    mask: Path | None = None
    """Folder of masks of the moving subject, <view name>.png at the view's size, nonzero grey level
    inside (the masks `data video --mask-dynamic` takes); a mask whose grey level is flat marks the
    subject by nonzero alpha, one whose grey and alpha both vary must agree. One view's mask may be
    empty; every view's empty, or every pixel covered, is refused. Scores inside and outside them,
    with the cameras as given. `auto`: the scene's own motion masks (flow/<k>x/masks at the run's
    scale, made by `data video` or `data flow`), checked against the frames they were computed from."""
    flow_error: bool = False
    """Also score the Gaussians' rendered motion: its end-point error (pixels) against the scene's
    measured optical flow between neighbouring train frames, both ways, over the pixels where the flow
    is consistent and inside the motion masks (needs the flow at the run's scale: `data flow`)."""


def evaluate_run(args: EvalArgs) -> dict:
    run = load_run(args.run, args.device)
    cfg = run.config
    backbone = args.lpips_backbone or cfg.eval.lpips_backbone
    normalize = cfg.eval.lpips_normalize if args.lpips_normalize is None else args.lpips_normalize
    quantize = cfg.eval.quantize_8bit if args.quantize_8bit is None else args.quantize_8bit
    check_scene_print(args.run, cfg.data.path)
    dataset = load_run_dataset(cfg)
    if args.split not in dataset.splits:
        raise ConfigError(f"{cfg.data.path}: the dataset has no '{args.split}' split")
    try:
        lpips, lpips_error = (
            LPIPS(
                backbone,
                normalize=normalize,
                weights=args.lpips_weights or cfg.eval.lpips_weights,
                device=run.device,
            ),
            None,
        )
    except LPIPSUnavailable as err:
        lpips, lpips_error = None, str(err)
    background = torch.tensor(dataset.background, dtype=torch.float32)
    views = dataset.splits[args.split]
    mask_dir = scene_motion_masks(cfg.data.path, views) if str(args.mask) == AUTO_MASKS else args.mask
    masks = read_masks(mask_dir, views) if mask_dir is not None else None  # checked before any work
    flow = _flow_evidence(cfg.data.path, dataset.train) if args.flow_error else None
    renders, aligned_renders = [], []
    render = _keeping(lambda frame: run.render(frame.camera, frame.time, background).rgb, renders)
    summary, per_view = evaluate_views(render, views, lpips=lpips, lpips_error=lpips_error, quantize=quantize)
    aligned = None
    alignment = cfg.alignment(dataset.format)
    if alignment is not None:
        render_aligned = aligned_render(
            run.at_time,
            lambda gaussians, camera: render_frame(gaussians, camera, sh_degree=run.sh_degree,
                                                   background=background, backend=cfg.backend).rgb,
            cfg.cameras, dataset.camera_extent, cfg.ssim_weight, alignment,
        )  # fmt: skip
        aligned_summary, _ = evaluate_views(
            _keeping(render_aligned, aligned_renders), views, lpips=lpips, lpips_error=lpips_error, quantize=quantize
        )
        aligned = {**aligned_summary, "cameras": alignment.protocol(cfg.cameras)}
    record = {
        "kind": "re-evaluation of the final checkpoint"
        if run.finished
        else f"re-evaluation of an unfinished run (checkpoint at iteration {run.iteration} of {run.config.iterations})",
        "iteration": run.iteration,
        "iterations": run.config.iterations,
        "finished": run.finished,
        "split": args.split,
        "field": cfg.field,
        "scene": dataset.scene_name,
        "cameras": "as given",
        **summary,
        "source": run.source(),
    }
    if aligned is not None:
        record["aligned"] = aligned
    if masks is not None:
        truths = [frame.image().clamp(0, 1) for frame in views]

        def shown(images):
            return [quantize_8bit(r.cpu()) for r in images] if quantize else [r.cpu() for r in images]

        record["masked"] = {"masks": str(mask_dir), "cameras": "as given",
                            **masked_scores(shown(renders), truths, masks)}  # fmt: skip
        if aligned is not None:  # a refined model's test cameras as given miss it by its refinement: both, labelled
            record["masked_aligned"] = {"masks": str(mask_dir), "cameras": aligned["cameras"],
                                        **masked_scores(shown(aligned_renders), truths, masks)}  # fmt: skip
    if flow is not None:
        record["flow_error"] = flow_error(run.at_time, dataset.train, *flow, backend=cfg.backend)
    write_json_atomic(args.run / EVAL, record)
    write_per_view(args.run / EVAL_PER_VIEW, run.iteration, per_view, record["source"])
    return record


def _flow_evidence(scene: Path, train: list) -> tuple[list, np.ndarray]:
    """The scene's flow pairs and the train frames' motion masks at the run's scale (checked: missing
    or stale is one line)."""
    if not train or train[0].image_path.parent.parent.name != RGB_FOLDER:
        raise ConfigError(f"--flow-error: {scene} is not a capture with optical flow (data flow reads captures)")
    return read_flow_pairs(scene, image_scale(scene, train)), read_motion_masks(scene, train)[1]


def main(argv: list[str]) -> int:
    args = parse_flags(EvalArgs, argv, prog="liquidgs eval", description=__doc__)
    record = evaluate_run(args)
    unfinished = "" if record["finished"] else f" (unfinished run, {record['iterations']} planned)"
    Console().print(
        f"{record['scene']} / {record['field']} @ {record['iteration']}{unfinished} ({record['split']}): "
        f"PSNR {record['psnr']:.2f}  SSIM {record['ssim']:.4f}  {describe_lpips(record)} -> {args.run / EVAL}",
        highlight=False,
        soft_wrap=True,
    )
    for line in _more_lines(record):
        Console().print(line, highlight=False, soft_wrap=True)
    return 0


def _keeping(render, kept: list):
    """`render`, also keeping each image it returns (clamped to [0, 1]) in `kept`, for the masked scores."""

    def render_and_keep(frame):
        rgb = render(frame)
        kept.append(rgb.clamp(0, 1))
        return rgb

    return render_and_keep


def _more_lines(record: dict) -> list[str]:
    """The labelled second scores, one line each: aligned cameras, and inside / outside the masks."""
    lines = []
    if "aligned" in record:
        a = record["aligned"]
        lines.append(f"  test cameras aligned to the scene: PSNR {a['psnr']:.2f}  SSIM {a['ssim']:.4f}  "
                     f"{describe_lpips(a)}  ({record['aligned']['cameras']})")  # fmt: skip
    for key, cameras in (("masked", "cameras as given"), ("masked_aligned", "test cameras aligned")):
        for region in ("inside", "outside") if key in record else ():
            m = record[key][region]
            psnr = "n/a (empty)" if m["psnr"] is None else f"{m['psnr']:.2f}"
            ssim = "n/a" if m["ssim"] is None else f"{m['ssim']:.4f}"
            lines.append(f"  {region} the masks ({100 * m['share']:.1f}% of pixels), {cameras}: "
                         f"PSNR {psnr}  SSIM {ssim}")  # fmt: skip
    if "flow_error" in record:
        f = record["flow_error"]
        px = {key: "n/a" if f[key + "_px"] is None else f"{f[key + '_px']:.2f} px"
              for key in ("consistent", "inside_masks")}  # fmt: skip
        lines.append(f"  rendered motion against the measured flow ({f['pairs']} train pairs, both ways, cameras as "
                     f"given): end-point error {px['consistent']} where consistent, {px['inside_masks']} inside the "
                     "motion masks")  # fmt: skip
    return lines
