"""Training: configuration and presets, the D-3DGS loop, densification, checkpoints."""
