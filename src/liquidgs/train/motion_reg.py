"""Motion that holds together: regularisers on the deformation, after the warm-up: two over each
Gaussian's k nearest canonical neighbours, and one on how far it moves.

Chosen from Dynamic 3D Gaussians (Luiten et al.): local rigidity and isometry, with the canonical
Gaussians (the field's zero-delta state) as the reference frame instead of the previous time step,
since a deformation field maps canonical space to each time. Not SC-GS's as-rigid-as-possible
loss: that acts on its sparse control nodes, which liquidgs's per-Gaussian fields do not have.

- rigidity: each neighbour offset turns with its Gaussian: (x_j(t) - x_i(t)) against
  R_i(t) R_i(0)^T (x_j(0) - x_i(0)), with R from the deformed and canonical rotations;
- isometry: neighbour distances are kept: | |x_j(t) - x_i(t)| - |x_j(0) - x_i(0)| |;
- stillness: how far the field moves each Gaussian's surface from its canonical place,
  |x(t) - x(0)| + (largest axis) x (angle turned), over the scene extent. An L1 cost: a small move
  costs as much per unit as a large one, so the field moves only what the pictures pay for.

Their weights depend on the field unless given. A field registered with `local_deformation`
(HexPlane: a grid, whose cells let neighbouring Gaussians move apart) has rigidity and isometry at
0.5, no stillness; one network over all of space (the MLP, the CfC, SDE-LNN), which is smooth in
space already, has stillness at 0.1 and no neighbour terms. On the real-clip benchmark
(docs/results/real-clips.md), a clip where nothing moves: without any term HexPlane scored 1.7 dB
above the static model and the MLP and CfC 0.2-0.34 dB (past the 0.3 dB a still clip allows), while
the neighbour terms at 0.5 held the MLP's and CfC's deformation still everywhere, the moving clips
too. The stillness term was added for them; the cost of each weight on the moving subjects is in
the results page.

All are means over `anchors` Gaussians drawn each step (torch's generator, so a resumed run draws
the same) and, for the neighbour terms, their k neighbours, found once per `knn_every` iterations
and whenever the Gaussians were added or removed; the neighbour table is checkpointed so a resumed
run continues bit-exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import torch
from scipy.spatial import cKDTree

from liquidgs.data.loading import check_capture_switch, for_captures
from liquidgs.errors import ConfigError, check_integer, check_number
from liquidgs.fields.registry import field_type
from liquidgs.render.projection import quat_to_rotmat

LOCAL_FIELD_WEIGHT = 0.5
"""Each neighbour term's weight, unless set, for a field registered with local_deformation."""
GLOBAL_FIELD_STILLNESS = 0.1
"""The stillness term's weight, unless set, for a field that is one network over all of space."""
MAX_NEIGHBOURS = 128
"""The most motion.neighbours: 16x the default 8 (each step compares anchors x neighbours pairs)."""


@dataclass
class MotionRegConfig:
    """Regularisers on the deformation: Dynamic 3D Gaussians' rigidity and isometry, and stillness."""

    apply: Literal["auto", "on", "off"] = "auto"
    """auto: on for captures (the Nerfies layout), off for D-NeRF: the regularisers at their weights
    and the sizes held (fixed_sizes). A config.yml made before these regularisers existed has none,
    and trains without them (off). Only fields that deform."""
    rigidity: float | None = None
    """Weight of the local-rigidity term; None: the field's (0.5 for a field registered with
    local_deformation, such as hexplane; 0 for mlp, cfc, sde)."""
    isometry: float | None = None
    """Weight of the isometry term; None: the field's, as for rigidity."""
    stillness: float | None = None
    """Weight of the stillness term: the mean distance the field moves a Gaussian's surface (its centre,
    and its largest axis turned) from its canonical place, in scene extents; None: the field's (0.1 for
    one network over all of space, such as mlp, cfc, sde; 0 for a field registered with
    local_deformation, which the neighbour terms hold). A config.yml made before this term existed
    trained without it (0)."""
    neighbours: int = 8
    """Nearest canonical neighbours of each anchor the rigidity and isometry terms compare, at most
    128 (MAX_NEIGHBOURS): each step's cost grows with them."""
    anchors: int = 2048
    """Gaussians the terms are averaged over each step (all when fewer)."""
    knn_every: int = 100
    """Iterations between two searches of each Gaussian's nearest canonical neighbours."""
    fixed_sizes: bool = True
    """The field moves and turns Gaussians but does not resize them (Dynamic 3D Gaussians keeps sizes
    constant). A field that may resize Gaussians frame by frame fits what a frame shows from its
    viewpoint alone: on a clip where nothing moves it scored 1.9 dB above the static model. A
    config.yml made before this setting trained with sizes free (false)."""

    def weights(self, field: str) -> tuple[float, float, float]:
        """(rigidity, isometry, stillness) for a run of `field`: each as set, or the field's default."""
        local = field_type(field).local_deformation
        defaults = (LOCAL_FIELD_WEIGHT, LOCAL_FIELD_WEIGHT, 0.0) if local else (0.0, 0.0, GLOBAL_FIELD_STILLNESS)
        rigidity, isometry, stillness = (
            default if w is None else float(w)
            for default, w in zip(defaults, (self.rigidity, self.isometry, self.stillness), strict=True)
        )
        return rigidity, isometry, stillness

    def __post_init__(self) -> None:
        check_capture_switch("motion.apply", self.apply)
        check_integer("motion.neighbours", self.neighbours, 1, MAX_NEIGHBOURS)
        for name in ("anchors", "knn_every"):  # more anchors than Gaussians means all of them
            check_integer(f"motion.{name.replace('_', '-')}", getattr(self, name), 1)
        if not isinstance(self.fixed_sizes, bool):
            raise ConfigError(f"motion.fixed-sizes must be true or false, got {self.fixed_sizes!r}")
        for name in ("rigidity", "isometry", "stillness"):
            if getattr(self, name) is not None:
                check_number(f"motion.{name}", getattr(self, name))


def split_in_place_of_neighbour_terms(cfg: MotionRegConfig, field: str) -> MotionRegConfig:
    """`cfg` for a run whose static/dynamic split was decided from the scene: a field registered
    local_deformation trains without the neighbour terms it has by default (their weights, where
    unset, set to 0, so config.yml and the identity say so), since the split holds the Gaussians the
    masks call still exactly still - what the terms were for. On the real-clip benchmark (HexPlane,
    flow loss 0.04) the split without the terms scored the subject 0.43 dB above the terms without
    the split (ten pairs of clip and seed, a gain by the verdict rule) and kept the still clip at the
    static model's score, where the terms without the split had cost the subject 0.65 dB and dropping
    them alone put the still clip 1.2 dB above it (docs/results/real-clips.md). Weights given are kept."""
    if not field_type(field).local_deformation:
        return cfg
    return replace(cfg, rigidity=0.0 if cfg.rigidity is None else cfg.rigidity,
                   isometry=0.0 if cfg.isometry is None else cfg.isometry)  # fmt: skip


def motion_applies(cfg: MotionRegConfig, data_format: str | None, field: str) -> bool:
    """Whether these settings shape the run's motion (its regularisers at their weights, its sizes)."""
    return field != "static" and for_captures(cfg.apply, data_format)


def regularisation(cfg: MotionRegConfig, data_format: str | None, field: str) -> tuple[float, float, float] | None:
    """The run's (rigidity, isometry, stillness) weights, or None where it trains without any."""
    if not motion_applies(cfg, data_format, field):
        return None
    weights = cfg.weights(field)
    return weights if any(w > 0 for w in weights) else None


def holds_sizes(cfg: MotionRegConfig, data_format: str | None, field: str) -> bool:
    """Whether the field's size deltas are dropped in this run (see MotionRegConfig.fixed_sizes)."""
    return cfg.fixed_sizes and motion_applies(cfg, data_format, field)


def nearest_neighbours(points: torch.Tensor, k: int) -> torch.Tensor:
    """int64 [N, k'] indices of each point's k nearest other points (k' = min(k, N - 1))."""
    xyz = points.detach().cpu().double().numpy()
    kk = min(k, len(xyz) - 1)
    if kk < 1:
        return torch.zeros(len(xyz), 0, dtype=torch.int64)
    _, idx = cKDTree(xyz).query(xyz, k=kk + 1)
    own = idx == np.arange(len(xyz))[:, None]
    # Drop each row's own index (or, with duplicates elsewhere, its farthest hit).
    drop = np.where(own.any(axis=1), own.argmax(axis=1), kk)
    keep = np.ones_like(own)
    keep[np.arange(len(xyz)), drop] = False
    return torch.from_numpy(idx[keep].reshape(len(xyz), kk)).long()


def surface_move(x0: torch.Tensor, q0: torch.Tensor, xt: torch.Tensor, qt: torch.Tensor, sizes: torch.Tensor):
    """How far each Gaussian's surface moves from (x0, q0) to (xt, qt): its centre, plus its largest
    axis (`sizes` [N, 3]) times the angle turned (the chord between the unit quaternions, either sign)."""
    q0 = torch.nn.functional.normalize(q0, dim=-1)
    qt = torch.nn.functional.normalize(qt, dim=-1)
    turn = 2 * (qt - torch.sign((qt * q0).sum(-1, keepdim=True)) * q0).norm(dim=-1)
    return (xt - x0).norm(dim=-1) + sizes.max(dim=-1).values * turn


class MotionRegulariser:
    def __init__(self, cfg: MotionRegConfig, weights: tuple[float, float, float], scene_extent: float = 1.0):
        self.cfg = cfg
        self.rigidity, self.isometry, self.stillness = weights
        self.scene_extent = scene_extent
        self.table: torch.Tensor | None = None
        self.table_step = -1

    def loss(self, step: int, canonical_means, canonical_quats, means, quats, sizes) -> torch.Tensor:
        """The weighted terms at this step: canonical (params) and deformed Gaussians (sizes: their
        scales, for the stillness term)."""
        c = self.cfg
        n = canonical_means.shape[0]
        neighbours = self.rigidity > 0 or self.isometry > 0
        stale = self.table is None or self.table.shape[0] != n or step - self.table_step >= c.knn_every
        if neighbours and stale:
            self.table, self.table_step = nearest_neighbours(canonical_means, c.neighbours), step
        anchors = torch.randperm(n, device=canonical_means.device)[: c.anchors] if n > c.anchors else None
        i = torch.arange(n, device=canonical_means.device)[:, None] if anchors is None else anchors[:, None]
        x0 = canonical_means.detach()
        terms = canonical_means.new_zeros(())
        if self.stillness > 0:
            a = i[:, 0]
            moved = surface_move(x0[a], canonical_quats.detach()[a], means[a], quats[a], sizes[a].detach())
            terms = terms + self.stillness * moved.mean() / self.scene_extent
        if not neighbours or self.table.shape[1] == 0:
            return terms
        table = self.table.to(canonical_means.device)
        rows = table if anchors is None else table[anchors]
        offset0 = x0[rows] - x0[i]  # [A, k, 3]
        offset_t = means[rows] - means[i]
        if self.rigidity > 0:
            r0 = quat_to_rotmat(canonical_quats.detach()[i[:, 0]])
            rt = quat_to_rotmat(quats[i[:, 0]])
            turned = torch.einsum("aij,akj->aki", rt @ r0.transpose(1, 2), offset0)
            terms = terms + self.rigidity * (offset_t - turned).norm(dim=-1).mean()
        if self.isometry > 0:
            terms = terms + self.isometry * (offset_t.norm(dim=-1) - offset0.norm(dim=-1)).abs().mean()
        return terms

    def forget_neighbours(self) -> None:
        """The Gaussians regularised changed (a split run's labels): the next step searches anew."""
        self.table = None

    def state_dict(self) -> dict:
        return {"table": self.table, "table_step": self.table_step}

    def load_state_dict(self, saved: dict | None) -> None:
        if saved is not None:
            self.table, self.table_step = saved["table"], int(saved["table_step"])
