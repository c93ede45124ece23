"""liquidgs: dynamic-scene reconstruction with deformable 3D Gaussians.

Folders, one idea each, imports flowing one way:
  gaussians/  canonical Gaussian scene model, initialisation, PLY I/O
  render/     the pure-function rasteriser (portable torch backend, gsplat backend)
  data/       dataset readers, synthetic scenes, validation
  fields/     deformation fields (MLP, liquid CfC, stochastic CfC and variants)
  train/      the D-3DGS trainer, densification strategy, checkpoints
  eval/       metrics (PSNR, SSIM, LPIPS) and run evaluation
  commands/   the thin `liquidgs` command family
"""

import os

# Idle OpenMP threads sleep instead of spinning. A training step interleaves hundreds of small
# torch ops with the compiled rasteriser; with spinning workers, each op on a 2-core machine
# waited on them (measured: bench train 63 ms -> 50 ms per step). Read when torch loads, so
# it only takes effect where liquidgs is imported first (the liquidgs command); an explicit
# setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
