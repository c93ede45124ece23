"""Baked scenes: a trained deformation field distilled into explicit per-Gaussian motion
(distil.py, motion.py), read by every command like a run (scene.py)."""
