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

__version__ = "0.1.0"
