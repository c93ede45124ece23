"""The canonical Gaussian scene model: parameters, initialisation and PLY I/O."""

from liquidgs.gaussians.model import (
    PARAM_KEYS,
    activate,
    init_from_points,
    init_random_box,
    rgb_to_sh0,
)
from liquidgs.gaussians.neighbors import mean_sq_dist_to_neighbors
from liquidgs.gaussians.ply import read_ply, read_ply_comments, write_ply

__all__ = [
    "PARAM_KEYS",
    "activate",
    "init_from_points",
    "init_random_box",
    "mean_sq_dist_to_neighbors",
    "read_ply",
    "read_ply_comments",
    "rgb_to_sh0",
    "write_ply",
]
