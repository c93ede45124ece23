"""Differentiable Gaussian rasterisation: a portable PyTorch backend, compiled CPU kernels and gsplat's CUDA kernels."""

from liquidgs.render.contract import RenderOutput
from liquidgs.render.rasterize import BACKENDS, NEAR_PLANE, rasterize

__all__ = ["BACKENDS", "NEAR_PLANE", "RenderOutput", "rasterize"]
