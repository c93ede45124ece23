"""D-3DGS densification as a strategy object over a dict of parameters and a dict of optimizers.

Mirrors the reference (Deformable-3D-Gaussians) rather than gsplat's DefaultStrategy: clone
small / split large Gaussians whose view-space gradient exceeds a threshold, prune by
opacity, screen radius (pixels) and world size, and reset opacities every N steps. gsplat
1.5.3's DefaultStrategy never resets opacity (operator-precedence bug), one reason this
strategy is our own; the other is that its size tests are normalised differently. The
bookkeeping (removing, duplicating, resetting opacity along with the Adam moments and this
strategy's statistics) is gsplat.strategy.ops; only the split and the statistics of new
Gaussians differ from it (see _split and _duplicate_unmeasured).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
from gsplat.strategy import ops as gsplat_ops

from liquidgs.render.projection import quat_to_rotmat

STATISTICS = ("grad_accum", "count", "max_radii")
"""The strategy state's rows it measures; a new Gaussian starts them at zero."""


@dataclass
class DensifyConfig:
    gradient: Literal["absolute", "standard"] = "absolute"
    """'absolute' (AbsGS, the current reference code, threshold 0.0007) or 'standard' (0.0002)."""
    grad_threshold: float = 0.0007
    """Mean screen-space position gradient above which a Gaussian is cloned or split."""
    start: int = 500
    """Densify and prune when step > start and step % interval == 0 ..."""
    stop: int = 15_000
    """... and step < stop (statistics are collected while step < stop)."""
    interval: int = 100
    """Iterations between densification steps."""
    opacity_reset_interval: int = 3000
    """Iterations between opacity resets (every opacity set to reset_opacity_to)."""
    prune_opacity: float = 0.005
    """Gaussians below this opacity are pruned at each densification step."""
    percent_dense: float = 0.01
    """Clone if the largest scale <= percent_dense * extent, else split."""
    max_screen_radius: float = 20.0
    """Prune Gaussians wider than this many pixels once step > opacity_reset_interval."""
    max_world_size: float = 0.1
    """... or larger than this fraction of the scene extent."""
    split_count: int = 2
    """Children of a split Gaussian; their scales are the parent's / (0.8 x split_count), as D-3DGS."""
    reset_opacity_to: float = 0.01
    """The opacity an opacity reset sets every Gaussian to (at most)."""
    max_per_pixel: float = 0.0
    """Cap on the Gaussians densification may grow to, per pixel of a training image (0: no cap,
    as the reference). The thresholds above are the reference's for 800x800 images; at 162x90
    they grew a real clip to 5.6 Gaussians per pixel in 1,500 iterations. When a step's clones
    and splits would pass the cap, those with the largest gradients go first (a split counts as
    its split_count - 1 extra Gaussians); pruning is not capped."""


class D3DGSStrategy:
    """Densification state lives in a plain dict so checkpoints can save and restore it."""

    def __init__(self, config: DensifyConfig, scene_extent: float):
        self.config = config
        self.scene_extent = scene_extent

    def initial_state(self, n: int, device: torch.device) -> dict[str, torch.Tensor]:
        """The statistics; other rows added to the state (a Gaussian's label) are carried as they are:
        a clone or split child takes its parent's."""
        return {key: torch.zeros(n, device=device) for key in STATISTICS}

    def step_post_backward(
        self,
        params: torch.nn.ParameterDict,
        optimizers: dict[str, torch.optim.Optimizer],
        state: dict[str, torch.Tensor],
        step: int,
        info: dict,
        generator: torch.Generator | None = None,
    ) -> dict[str, int]:
        """Call after loss.backward() and before the optimizers step. Returns what changed.

        `params` holds only the Gaussians' parameters, each with its own optimizer in
        `optimizers`: gsplat's ops resize every entry of `params`."""
        cfg = self.config
        report = {"cloned": 0, "split": 0, "pruned": 0, "reset": 0, "pruned_all": 0}
        if step >= cfg.stop:
            return report
        self._accumulate(state, info)
        if step > cfg.start and step % cfg.interval == 0:
            pixels = int(info["width"]) * int(info["height"])
            report.update(self._densify_and_prune(params, optimizers, state, step, generator, pixels))
        if step % cfg.opacity_reset_interval == 0:
            # min(opacity, reset_opacity_to) with zeroed Adam moments, as the reference.
            gsplat_ops.reset_opa(params, optimizers, state, cfg.reset_opacity_to)
            report["reset"] = 1
        return report

    @torch.no_grad()
    def _accumulate(self, state: dict[str, torch.Tensor], info: dict) -> None:
        means2d = info["means2d"]
        grad = means2d.absgrad if self.config.gradient == "absolute" else means2d.grad
        if grad is None:
            return
        visible = info["radii"] > 0
        # Pixel-space gradients to the NDC units the 3DGS thresholds were tuned for.
        grad = grad.detach().clone()
        grad[:, 0] *= info["width"] / 2.0
        grad[:, 1] *= info["height"] / 2.0
        state["grad_accum"][visible] += grad[visible].norm(dim=-1)
        state["count"][visible] += 1
        state["max_radii"][visible] = torch.maximum(
            state["max_radii"][visible], info["radii"][visible].to(state["max_radii"].dtype)
        )

    @torch.no_grad()
    def _densify_and_prune(self, params, optimizers, state, step, generator, pixels: int) -> dict[str, int]:
        cfg = self.config
        grads = state["grad_accum"] / state["count"]
        grads[~torch.isfinite(grads)] = 0.0
        high_grad = grads >= cfg.grad_threshold
        max_scale = torch.exp(params["scales"]).max(dim=-1).values
        small = max_scale <= cfg.percent_dense * self.scene_extent
        if cfg.max_per_pixel > 0:
            high_grad = self._within_cap(high_grad, small, grads, pixels)

        clone_mask = high_grad & small
        n_clone = int(clone_mask.sum())
        if n_clone:
            _duplicate_unmeasured(params, optimizers, state, clone_mask)

        # Split uses the masks padded over the clones just appended, as the reference does.
        pad = params["means"].shape[0] - high_grad.shape[0]
        split_mask = torch.cat([high_grad & ~small, high_grad.new_zeros(pad)])
        n_split = int(split_mask.sum())
        if n_split:
            _split(params, optimizers, state, split_mask, cfg.split_count, generator)

        prune = torch.sigmoid(params["opacities"]) < cfg.prune_opacity
        if step > cfg.opacity_reset_interval:
            too_wide_on_screen = state["max_radii"] > cfg.max_screen_radius
            too_big_in_world = torch.exp(params["scales"]).max(dim=-1).values > cfg.max_world_size * self.scene_extent
            prune |= too_wide_on_screen | too_big_in_world
        # Never prune to nothing: an empty scene cannot recover. The report says it happened.
        pruned_all = bool(prune.all())
        if pruned_all:
            prune[torch.argmax(params["opacities"])] = False
        n_pruned = int(prune.sum())
        if n_pruned:
            gsplat_ops.remove(params, optimizers, state, prune)

        for key in STATISTICS:
            state[key].zero_()
        return {"cloned": n_clone, "split": n_split, "pruned": n_pruned, "pruned_all": int(pruned_all)}

    def cap(self, pixels: int) -> int:
        """The most Gaussians densification grows to on images of `pixels` pixels."""
        return int(self.config.max_per_pixel * pixels)

    def _within_cap(self, high_grad, small, grads, pixels) -> torch.Tensor:
        """The candidates to clone or split, cut to the largest gradients that fit under the cap."""
        n = high_grad.shape[0]
        room = self.cap(pixels) - n
        cost = torch.where(small, 1, self.config.split_count - 1)[high_grad]
        if int(cost.sum()) <= room:
            return high_grad
        candidates = torch.nonzero(high_grad).squeeze(1)
        order = torch.argsort(grads[candidates], descending=True, stable=True)
        fits = torch.cumsum(cost[order], dim=0) <= max(room, 0)
        kept = high_grad.new_zeros(n)
        kept[candidates[order[fits]]] = True
        return kept


@torch.no_grad()
def _duplicate_unmeasured(params, optimizers, state, mask: torch.Tensor, copies: int = 1) -> None:
    """Append `copies` copies of the Gaussians in `mask` by gsplat's duplicate (zero Adam moments),
    then zero the copies' densification statistics (any other state row, a label, is the source's).

    gsplat's duplicate gives each copy its source's statistics; in D-3DGS a new Gaussian starts
    unmeasured, so the screen-radius prune later in the same step does not judge a clone by the
    radius its source reached.
    """
    n = mask.shape[0]
    for _ in range(copies):
        grown = params["means"].shape[0] - n
        gsplat_ops.duplicate(params, optimizers, state, torch.cat([mask, mask.new_zeros(grown)]))
    for key in STATISTICS:
        state[key][n:] = 0


@torch.no_grad()
def _split(params, optimizers, state, mask: torch.Tensor, count: int, generator: torch.Generator | None) -> None:
    """Replace each Gaussian in `mask` by `count` children drawn inside it, each 0.8 * count times smaller.

    Not gsplat's split, which always makes two children, divides by 1.6 (= 0.8 * 2) and draws
    from the global generator: D-3DGS's split count is a setting and the draws come from
    `generator`. The rows come out as gsplat's: the others in order, then the children
    (all first children, then all second ...).
    """
    scales = torch.exp(params["scales"][mask]).repeat(count, 1)
    samples = torch.normal(torch.zeros_like(scales), scales, generator=generator)
    rotmats = quat_to_rotmat(params["quats"][mask]).repeat(count, 1, 1)
    means = torch.bmm(rotmats, samples[..., None])[..., 0] + params["means"][mask].repeat(count, 1)
    n = mask.shape[0]
    _duplicate_unmeasured(params, optimizers, state, mask, copies=count)
    params["means"][n:] = means
    params["scales"][n:] = torch.log(scales / (0.8 * count))
    gsplat_ops.remove(params, optimizers, state, torch.cat([mask, mask.new_zeros(count * int(mask.sum()))]))
