"""Exact k-nearest-neighbour distances for initial Gaussian scales."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree


def mean_sq_dist_to_neighbors(points: torch.Tensor | np.ndarray, k: int = 3) -> torch.Tensor:
    """Mean squared distance from each point to its k nearest *other* points.

    Exact, via a KD-tree: O(N log N) time and O(N) memory (100k points take well under a
    second on a CPU), never an N x N matrix. Duplicate points count as neighbours at
    distance 0, as in 3DGS's simple-knn. Returns float32 [N] on the input's device.
    """
    device = points.device if isinstance(points, torch.Tensor) else torch.device("cpu")
    xyz = points.detach().cpu().double().numpy() if isinstance(points, torch.Tensor) else np.asarray(points)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    n = xyz.shape[0]
    if n < 2:
        return torch.zeros(n, dtype=torch.float32, device=device)
    kk = min(k, n - 1)
    # k+1 because the closest hit of each query is the point itself (distance 0, own index).
    dist, idx = cKDTree(xyz).query(xyz, k=kk + 1)
    self_hit = idx == np.arange(n)[:, None]
    # Drop exactly one self hit per row (duplicates keep their zero distance).
    first_self = np.argmax(self_hit, axis=1)
    keep = np.ones_like(self_hit)
    keep[np.arange(n), first_self] = False
    keep[~self_hit.any(axis=1), -1] = False  # self not among the hits: drop the farthest
    neighbour_d2 = (dist[keep].reshape(n, kk)) ** 2
    return torch.from_numpy(neighbour_d2.mean(axis=1)).float().to(device)
