"""Static and dynamic Gaussians: the field moves only the Gaussians the video shows moving.

Each Gaussian carries a label (the strategy state's DYNAMIC row, so densification's clones and
split children take their parent's, and checkpoints resume it bit-exactly):

- at the start, a Gaussian is dynamic when its centre projects inside the scene's motion masks
  (data.flow, at the training scale) in at least `vote` of the train frames that see it;
- with the occlusion test (`occlusion`, opt-in) a frame sees it only where nothing drawn lies well
  in front of it (its depth against the depth the Gaussians render at its pixel), so the wall a
  moving head passes in front of does not take the head's votes; the labels are then decided afresh
  at the end of the warm-up, before the field moves anything, from the scene the warm-up drew (the
  first Gaussians draw no surface to test against);
- every `every` iterations from the end of the warm-up until densification stops, the labels are
  decided again: a static Gaussian whose centre the masks now hold (a child densification placed on
  the moving subject) becomes dynamic, and a dynamic one the masks do not hold and the field moves
  by less than `still` scene extents at every train time (its surface: centre, and largest axis
  turned, as the stillness term measures) becomes static, where it stands at time 0 - a jump of at
  most `still`.

Static Gaussians never pass through the field (an iteration costs less where most of the scene is
still), so they stay exactly where they are at every time: that is the stillness the stillness term
asks for, held exactly, and the term is not trained with the split. Dynamic Gaussians alone are
the neighbour terms' anchors and neighbours; the flow loss sees every Gaussian's screen motion
(a static one's comes from the camera's).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from liquidgs.data.flow import read_motion_masks
from liquidgs.data.scene import Frame
from liquidgs.errors import ConfigError, DataError, check_integer, check_number
from liquidgs.train.flow_loss import project_with_depth

DYNAMIC = "dynamic"
"""The strategy state's row of labels (bool [N]: True for a dynamic Gaussian)."""
REDECIDE_TIMES = 8
"""Train times (evenly spread over the clip) at which a dynamic Gaussian's motion is measured."""
SURFACE_ALPHA = 0.5
"""A pixel draws a surface for the occlusion test where its rendered opacity is at least this."""

Seen = tuple[torch.Tensor, torch.Tensor | None]
"""What one train frame shows of the Gaussians: their centres as its camera sees them [N, 3], and the
depth rendered at each pixel [H, W] (infinite where nothing opaque is drawn), or None: no occlusion test."""


def where_they_stand(means: torch.Tensor) -> Callable[[int], Seen]:
    """Every train frame sees the centres `means`, with no occlusion test."""
    return lambda _index: (means, None)


def surface_depth(depth: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """A render's expected depth [H, W] where it is at least SURFACE_ALPHA opaque, infinite elsewhere."""
    return torch.where(alpha >= SURFACE_ALPHA, depth, torch.full_like(depth, math.inf))


@dataclass
class SplitConfig:
    """Static and dynamic Gaussians (see liquidgs.train.dynamic_split); by default on where the scene
    has motion masks at the training scale."""

    apply: bool | None = None
    """Split the Gaussians into static ones, which the field never moves, and dynamic ones, decided from
    the scene's motion masks (`liquidgs data flow`, at the training scale). Captures only; the static
    model has nothing to split. Unset: on where the scene has its flow and masks at the training
    scale (for HexPlane, in place of its neighbour terms: motion_reg.split_in_place_of_neighbour_terms),
    else off."""
    vote: float = 0.05
    """A Gaussian is dynamic when its centre lies inside the motion masks in at least this share of the
    train frames that see it. Low, because a mask holds a slow subject only in the frames where its
    motion shows (on the cat clip 15 of 70 train frames' masks are empty, 22 under 0.5%): against the
    hand-drawn subject box, the cat's initial points voted at 0.05 were 88% inside it and held 68% of
    those inside (at 0.2: 98% and 9%; at 0.5 a single point was dynamic). Chosen on that one clip."""
    every: int = 500
    """Iterations between two decisions of the labels, from the end of the warm-up until densification
    stops."""
    still: float = 1e-3
    """A dynamic Gaussian outside the masks that the field moves less than this (scene extents) at every
    train time becomes static."""
    occlusion: float | None = None
    """Opt-in: a train frame counts in a Gaussian's vote only where the Gaussian is no more than this
    share of its depth behind the depth the frame renders at its pixel (where the render is at least
    half opaque), so a Gaussian hidden behind a moving subject is not held by the subject's mask; the
    labels are then decided afresh at the end of the warm-up. None (the default): every frame whose
    view holds the centre counts, and the labels stand from the start. Measured on the cat at 0.2
    (docs/results/video-pipeline.md): a fifth to a quarter fewer dynamic Gaussians and a cheaper step,
    but the background 1.0-1.5 dB worse for every field and HexPlane's subject 0.6-3 dB worse, so not
    the default."""

    def __post_init__(self) -> None:
        if self.apply is not None and not isinstance(self.apply, bool):
            raise ConfigError(f"split.apply must be true, false or unset, got {self.apply!r}")
        check_number("split.vote", self.vote)
        if not 0 < self.vote <= 1:
            raise ConfigError(f"split.vote must be in (0, 1], got {self.vote!r}")
        check_integer("split.every", self.every, 1)
        check_number("split.still", self.still)
        if self.occlusion is not None:
            check_number("split.occlusion", self.occlusion)


def split_applies(cfg: SplitConfig, field: str) -> bool:
    """Whether the run labels its Gaussians (the static model has only static ones); `cfg` as
    train.config's with_motion_evidence decided it."""
    if cfg.apply is None:
        raise ValueError("split.apply undecided: resolve the config with with_motion_evidence first")
    return cfg.apply and field != "static"


def moving_indices(labels: torch.Tensor) -> torch.Tensor:
    """int64 indices of the dynamic Gaussians: what `deform` passes through the field."""
    return torch.nonzero(labels).squeeze(1)


class MotionVotes:
    """The train frames' motion masks, and which Gaussians they hold."""

    def __init__(self, cfg: SplitConfig, scene: Path, frames: list[Frame], scene_extent: float, device):
        self.cfg = cfg
        self.scene_extent = scene_extent
        folder, masks = read_motion_masks(scene, frames)
        self.masks = torch.from_numpy(masks).to(device)
        share = float(self.masks.float().mean())
        if share == 0.0:
            raise DataError(folder, "the motion masks hold no pixel: nothing moves for the split to find")
        if share == 1.0:
            raise DataError(folder, "the motion masks hold every pixel: no static part for the split to find")
        self.cameras = [frame.camera for frame in frames]
        self.times = [f.time for f in frames]

    @torch.no_grad()
    def vote(self, seen_by: Callable[[int], Seen]) -> torch.Tensor:
        """Per Gaussian: the share of the train frames seeing it whose motion mask holds it (0 where no
        frame sees it); `seen_by(i)` is what train frame i shows of the Gaussians."""
        _, height, width = self.masks.shape
        inside = seen = None
        for index, (camera, mask) in enumerate(zip(self.cameras, self.masks, strict=True)):
            means, depth_drawn = seen_by(index)
            if inside is None:
                inside, seen = means.new_zeros(means.shape[0]), means.new_zeros(means.shape[0])
            pixel, depth = project_with_depth(means, camera)
            col, row = pixel[:, 0].floor().long(), pixel[:, 1].floor().long()
            visible = (depth > 1e-6) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
            col, row = col.clamp(0, width - 1), row.clamp(0, height - 1)
            if depth_drawn is not None:
                if depth_drawn.shape != (height, width):
                    raise ValueError(f"depth drawn {tuple(depth_drawn.shape)} for masks of {height}x{width}")
                visible &= depth <= (1 + self.cfg.occlusion) * depth_drawn[row, col].to(depth)
            seen += visible
            inside += visible & mask[row, col]
        return torch.where(seen > 0, inside / seen.clamp_min(1), torch.zeros_like(seen))

    def held(self, seen_by: Callable[[int], Seen]) -> torch.Tensor:
        """Labels from the masks alone: dynamic where the vote reaches `vote`."""
        return self.vote(seen_by) >= self.cfg.vote

    @torch.no_grad()
    def redecide(self, seen_by: Callable[[int], Seen], labels: torch.Tensor, largest_move: Callable) -> torch.Tensor:
        """New labels: static ones inside the masks become dynamic; dynamic ones outside them that
        `largest_move(indices)` (scene units, over the train times) finds still become static."""
        held = self.held(seen_by)
        dynamic = moving_indices(labels)
        new = labels | held
        if dynamic.numel():
            still = largest_move(dynamic) < self.cfg.still * self.scene_extent
            new[dynamic[still & ~held[dynamic]]] = False
        return new

    def decides_afresh(self, step: int, warmup: int) -> bool:
        """Whether every label is decided again, from the masks alone, before step `step`: the first
        step the field moves Gaussians, with the occlusion test on."""
        return self.cfg.occlusion is not None and step == max(warmup, 1)

    def redecides(self, step: int, warmup: int, densify_stop: int) -> bool:
        """Whether the labels are decided again at `step`."""
        return warmup < step < densify_stop and (step - warmup) % self.cfg.every == 0

    def sample_times(self) -> list[float]:
        """REDECIDE_TIMES train times spread over the clip."""
        ordered = sorted(self.times)
        picks = np.linspace(0, len(ordered) - 1, min(REDECIDE_TIMES, len(ordered))).round().astype(int)
        return [ordered[i] for i in picks]
