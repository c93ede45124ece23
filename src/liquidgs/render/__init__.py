"""Differentiable Gaussian rasterisation: a portable PyTorch backend and gsplat's CUDA kernels."""

from liquidgs.render.rasterize import BACKENDS, RenderOutput, focal_from_fov, rasterize
from liquidgs.render.sh import eval_sh

__all__ = ["BACKENDS", "RenderOutput", "eval_sh", "focal_from_fov", "rasterize"]
