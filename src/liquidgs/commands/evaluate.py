"""`liquidgs eval --run DIR`: re-evaluate a run's checkpoint on its test split.

Writes DIR/eval.json (summary, labelled with the checkpoint's iteration and whether the run
had finished) and DIR/eval_per_view.json; results.json, the training record, is left as it
was. A run in progress may be evaluated: its record says "unfinished run".
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import torch
from rich.console import Console

from liquidgs.atomic import write_json_atomic
from liquidgs.errors import ConfigError
from liquidgs.eval import LPIPS, LPIPSUnavailable, describe_lpips, evaluate_views
from liquidgs.settings import parse_flags
from liquidgs.train.run import load_run, load_run_dataset
from liquidgs.train.run_folder import EVAL, EVAL_PER_VIEW, check_scene_print, write_per_view


@dataclass
class EvalArgs:
    run: Path
    """Run folder written by `liquidgs train`."""
    split: Literal["test", "val", "train"] = "test"
    lpips_backbone: Literal["vgg", "alex", "squeeze"] | None = None
    """Default: the backbone the run was trained with."""
    lpips_normalize: bool | None = None
    lpips_weights: Path | None = None
    quantize_8bit: bool | None = None
    device: str = "auto"


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

    def render(frame):
        return run.render(frame.camera, frame.time, background).rgb

    summary, per_view = evaluate_views(
        render, dataset.splits[args.split], lpips=lpips, lpips_error=lpips_error, quantize=quantize
    )
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
        **summary,
    }
    write_json_atomic(args.run / EVAL, record)
    write_per_view(args.run / EVAL_PER_VIEW, run.iteration, per_view)
    return record


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
    return 0
