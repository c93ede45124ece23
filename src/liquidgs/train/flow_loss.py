"""The optical-flow loss: the motion the Gaussians make on screen, held to the motion measured in the
video (data.flow).

For a train frame at time t and its neighbouring train frame at time t' (or the frame at the other
end of a track that starts or ends at it), each Gaussian's motion on screen is where the neighbour's
camera sees it at t' minus where this frame's camera sees it at t (each Gaussian deformed by the
field at its own time, each camera with its refinement). Those 2D motions are composited per pixel
with the same weights as colour - as extra feature channels of the colour pass itself (rasterize's
`features`, on every backend), so they cost no raster pass of their own - and compared with the
measured flow (L1, in pixels) where the flow is consistent both ways and the render is opaque with
Gaussians whose motion is measurable (see screen_motion: one in front of only one of the two
cameras, or moving further than the image is wide, would pull a pixel's flow by thousands of pixels
- it did on a real clip - so it neither counts nor learns). Its gradient reaches the Gaussians
through that pass, so densification's screen-space gradients carry it too.
By default (flow.weight unset) on at DEFAULT_WEIGHT for a capture with flow at the scale the run
reads (`liquidgs data flow SCENE --downscale K` makes it), off elsewhere (train.config's
with_motion_evidence decides, and config.yml records the weight decided); a weight set is used
as given, 0 for off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from liquidgs.cameras import Camera
from liquidgs.data.flow import FlowPair
from liquidgs.errors import check_number
from liquidgs.render import NEAR_PLANE, RenderOutput
from liquidgs.train.model import Deformed, render_frame

DEFAULT_WEIGHT = 0.04
"""flow.weight where it is left to the scene and the scene has flow. Chosen on the real-clip benchmark
(docs/results/real-clips.md, each field with its default split, two seeds): against 0.02 the
subject's margin is a tie for the MLP and the CfC and a gain for HexPlane (+0.19 dB), and the
rendered motion's end-point error in the motion masks is 37% (MLP), 32% (CfC) and 36% (HexPlane)
below the same runs without the loss, past the 30% the benchmark asks (at 0.02 the CfC and HexPlane
were not: 24-27%, 25%); at 0.08 the error falls further but the subject loses 0.5-0.9 dB."""
MIN_ALPHA = 0.5
"""Pixels the measurable Gaussians cover less than this are left out: their composited motion is
mostly empty space, or Gaussians whose motion cannot be measured."""


@dataclass
class FlowLossConfig:
    """The optical-flow loss on captures with flow (see liquidgs.train.flow_loss)."""

    weight: float | None = None
    """The loss's weight (L1 in pixels of the training images); 0: off. Unset: 0.04 (DEFAULT_WEIGHT)
    where the scene has optical flow at the training scale (`liquidgs data flow`), else 0."""
    tracks: bool = False
    """Hold the Gaussians to the scene's tracks too (the flow chained over 3 pairs of neighbouring
    frames), beside each frame's flow to its neighbours. Off by default: on the real-clip benchmark
    it lifts a fast subject (the running woman, +0.6 to +2.7 dB) and costs a slow one (the cat, -0.3
    to -0.8), about even over the clips for the MLP and HexPlane."""

    def __post_init__(self) -> None:
        if self.weight is not None:
            check_number("flow.weight", self.weight)


@dataclass
class _Target:
    neighbour: int  # the train index of the other frame
    flow: torch.Tensor  # [H, W, 2] measured, from this frame to the neighbour
    valid: torch.Tensor  # [H, W] bool


@dataclass
class DrawnFlow:
    """One step's flow target and each Gaussian's screen motion towards it: the motion goes to the
    colour pass as its extra features, the target to `FlowLoss.loss` with that pass's output."""

    motion: torch.Tensor  # [N, 2] pixels
    target: _Target


class FlowLoss:
    """Each train frame's measured flow to its neighbours (forward to the next, backward to the previous)
    and, where given, along the tracks that start or end at it; one of them is drawn each step."""

    def __init__(self, weight: float, pairs: list[FlowPair], train_names: list[str], device: torch.device):
        self.weight = weight
        index = {name: i for i, name in enumerate(train_names)}
        self.targets: dict[int, list[_Target]] = {}
        for pair in pairs:
            if pair.first not in index or pair.second not in index:
                continue  # a pair of frames this run does not train on (a thinned-out split)
            a, b = index[pair.first], index[pair.second]
            forward = _Target(b, _tensor(pair.forward, device), _tensor(pair.forward_consistent, device))
            backward = _Target(a, _tensor(pair.backward, device), _tensor(pair.backward_consistent, device))
            self.targets.setdefault(a, []).append(forward)
            self.targets.setdefault(b, []).append(backward)

    def target(self, index: int, rng: np.random.Generator) -> _Target | None:
        """One of the frame's neighbours' measured flow, drawn with the run's camera generator."""
        targets = self.targets.get(index)
        if not targets:
            return None
        return targets[int(rng.integers(0, len(targets)))]

    def draw(self, now: Deformed, camera: Camera, later: Deformed, later_camera: Camera, target: _Target):
        """The flow term of a step: the Gaussians' screen motion (`now` seen by `camera`, `later` by
        `later_camera`), to be rendered with this frame's colour, and the measured flow it is held to."""
        return DrawnFlow(screen_motion(now, camera, later, later_camera), target)

    def loss(self, out: RenderOutput, drawn: DrawnFlow):
        """weight x the mean L1 between the composited motion in `out` (the colour pass rendered with
        `drawn.motion` as its features) and the measured flow, over the pixels where both count;
        None where there are none."""
        rendered, covered = composited_flow(out)
        use = drawn.target.valid & (covered.detach() >= MIN_ALPHA)
        if not bool(use.any()):
            return None
        return self.weight * (rendered[use] - drawn.target.flow[use]).abs().mean()


def screen_motion(now: Deformed, camera: Camera, later: Deformed, later_camera: Camera) -> torch.Tensor:
    """Each Gaussian's motion on screen in pixels, its projection by `later_camera` at `later` minus its
    projection by `camera` at `now`, and a third channel, 1 where that motion is measurable: the
    Gaussian at least the rasteriser's NEAR_PLANE in front of both cameras and its motion no longer
    than the image's longer side (the flow cannot hold a longer one). Elsewhere both are 0: [N, 3]."""
    start, start_depth = project_with_depth(now.means, camera)
    end, end_depth = project_with_depth(later.means, later_camera)
    motion = end - start
    longest = max(camera.width, camera.height)
    measurable = (start_depth >= NEAR_PLANE) & (end_depth >= NEAR_PLANE) & (motion.detach().norm(dim=-1) <= longest)
    motion = torch.where(measurable[:, None], motion, motion.new_zeros(()))
    return torch.cat([motion, measurable[:, None].to(motion.dtype)], dim=1)


def composited_flow(out: RenderOutput):
    """The motion a render with `screen_motion` as its features composited over the measurable
    Gaussians, and their weight: ([H, W, 2] pixels, [H, W])."""
    measurable = out.features[..., 2]
    return out.features[..., :2] / measurable.clamp_min(MIN_ALPHA)[..., None], measurable


def rendered_flow(now: Deformed, camera: Camera, later: Deformed, later_camera: Camera, backend: str = "auto"):
    """The colour pass with the screen motion as its features, as the trainer renders it (SH degree 0:
    the flow, not the picture, is wanted): (flow [H, W, 2], the measurable Gaussians' weight [H, W])."""
    motion = screen_motion(now, camera, later, later_camera)
    background = now.means.new_zeros(3)
    return composited_flow(render_frame(now, camera, sh_degree=0, background=background, backend=backend,
                                        features=motion))  # fmt: skip


def project_with_depth(means: torch.Tensor, camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel positions [N, 2] of world points [N, 3] through a pinhole camera (points behind it
    project through a depth clamped at 1e-6), and each point's depth in front of the camera [N]."""
    viewmat = camera.viewmat.to(means)
    K = camera.K.to(means)
    in_camera = means @ viewmat[:3, :3].T + viewmat[:3, 3]
    depth = in_camera[:, 2]
    return (in_camera[:, :2] / depth.clamp_min(1e-6)[:, None]) @ K[:2, :2].T + K[:2, 2], depth


def _tensor(array: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(array)).to(device)


@torch.no_grad()
def flow_error(at_time, frames: list, pairs: list[FlowPair], masks: np.ndarray, backend: str = "auto") -> dict:
    """The end-point error (pixels) of the Gaussians' rendered motion (`at_time(t)`: the Gaussians at
    t) against the measured flow of every pair of train frames, both ways, with the cameras as given:
    over the pixels where the flow is consistent and the measurable Gaussians cover them, and over
    those of them inside the first frame's motion mask (`masks` [F, H, W] in `frames` order)."""
    index = {frame.name: i for i, frame in enumerate(frames)}
    gaussians: dict[str, Deformed] = {}

    def at(name: str) -> Deformed:
        if name not in gaussians:
            gaussians[name] = at_time(frames[index[name]].time)
        return gaussians[name]

    sums = {"consistent": [0.0, 0], "inside_masks": [0.0, 0]}
    used = 0
    for pair in pairs:
        if pair.first not in index or pair.second not in index:
            continue
        used += 1
        directions = ((pair.first, pair.second, pair.forward, pair.forward_consistent),
                      (pair.second, pair.first, pair.backward, pair.backward_consistent))  # fmt: skip
        for a, b, measured, consistent in directions:
            frame_a, frame_b = frames[index[a]], frames[index[b]]
            rendered, covered = rendered_flow(at(a), frame_a.camera, at(b), frame_b.camera, backend)
            error = (rendered.cpu() - torch.from_numpy(measured)).norm(dim=-1)
            use = torch.from_numpy(consistent) & (covered.cpu() >= MIN_ALPHA)
            inside = use & torch.from_numpy(masks[index[a]])
            for key, region in (("consistent", use), ("inside_masks", inside)):
                sums[key][0] += float(error[region].sum())
                sums[key][1] += int(region.sum())
    record = {"pairs": used, "cameras": "as given"}
    for key, (total, pixels) in sums.items():
        record[f"{key}_px"] = total / pixels if pixels else None
        record[f"{key}_pixels"] = pixels
    return record
