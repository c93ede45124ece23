"""liquidgs: dynamic-scene reconstruction with deformable 3D Gaussians.

Folders, one idea each, imports flowing one way:
  gaussians/  canonical Gaussian scene model, initialisation, PLY I/O
  native.py   builds and loads the compiled CPU kernels on first use
  cameras.py  the one Camera type and the camera formulas (data, render and above share it)
  sh.py       spherical harmonics (the scene model and the rasteriser share it)
  render/     the pure-function rasteriser (torch, compiled CPU and gsplat backends)
  data/       dataset readers, synthetic scenes, validation
  fields/     deformation fields (MLP, liquid CfC, stochastic CfC and variants)
  train/      the D-3DGS trainer, densification strategy, checkpoints
  eval/       metrics (PSNR, SSIM, LPIPS) and run evaluation
  commands/   the thin `liquidgs` command family
"""

import ctypes
import os
import sys

# Idle OpenMP threads sleep instead of spinning. A training step interleaves hundreds of small
# torch ops with the compiled rasteriser; with spinning workers, each op on a 2-core machine
# waited on them (measured: bench train 63 ms -> 50 ms per step). Read when torch loads, so
# it only takes effect where liquidgs is imported first (the liquidgs command); an explicit
# setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _reuse_freed_memory() -> None:
    """Let glibc's malloc hand freed tensor memory back to the next tensor instead of to the OS.

    A CPU training step allocates and frees a few hundred MB-sized tensors; by default each one
    above glibc's (adaptive) mmap threshold is mapped fresh and page-faulted in on first touch.
    Measured on a 2-core CPU (tiny CfC field, 5k Gaussians, forward + backward): 1,300-2,200
    page faults per step, 42-47 ms; with allocations up to 32 MB kept in the heap and up to
    512 MB of free heap kept before trimming: 3-7 faults, 34-39 ms. An explicit MALLOC_*
    setting wins; other C libraries are left alone.
    """
    if not sys.platform.startswith("linux") or any(key.startswith("MALLOC_") for key in os.environ):
        return
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return
    m_trim_threshold, m_mmap_threshold = -1, -3
    mallopt(m_mmap_threshold, 32 << 20)
    mallopt(m_trim_threshold, 512 << 20)


_reuse_freed_memory()

__version__ = "0.1.0"
