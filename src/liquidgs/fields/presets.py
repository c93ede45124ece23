"""The preset names and the built-in field families' sizes per preset (below the registry and the
configs, which both read them)."""

from __future__ import annotations

PRESET_NAMES = ("dnerf", "nerfds", "tiny")
"""The presets: field sizes here and in each registered field, and the training schedules of
train/config.py, share these names."""

# Sizes per preset and family. dnerf/nerfds MLP: the public D-3DGS code. dnerf/nerfds liquid:
# a reconstruction (the paper does not publish every size) that reproduces its cost table
# exactly: 1,553,706 and 318,602 parameters. tiny: CPU-sized fields of similar cost for
# 100-128 px scenes with 5k-20k Gaussians.
PRESETS: dict[str, dict[str, dict[str, int | str]]] = {
    "dnerf": {
        "mlp": dict(xyz_freqs=10, time_freqs=6, timenet_width=256, timenet_out=30, mlp_depth=8, mlp_width=256),
        "liquid": dict(
            xyz_freqs=10,
            time_freqs=6,
            timenet_width=256,
            timenet_out=32,
            cells=6,
            hidden=128,
            backbone_units=256,
            backbone_layers=2,
            activation="gelu",
        ),
    },
    "nerfds": {
        "mlp": dict(xyz_freqs=10, time_freqs=10, timenet_width=0, timenet_out=0, mlp_depth=8, mlp_width=256),
        "liquid": dict(
            xyz_freqs=10,
            time_freqs=10,
            timenet_width=0,
            timenet_out=0,
            cells=6,
            hidden=128,
            backbone_units=64,
            backbone_layers=2,
            activation="gelu",
        ),
    },
    "tiny": {
        "mlp": dict(xyz_freqs=10, time_freqs=6, timenet_width=64, timenet_out=16, mlp_depth=4, mlp_width=112),
        "liquid": dict(
            xyz_freqs=10,
            time_freqs=6,
            timenet_width=64,
            timenet_out=16,
            cells=3,
            hidden=32,
            backbone_units=64,
            backbone_layers=2,
            activation="gelu",
        ),
    },
}

_SHARED_SIZES = ("xyz_freqs", "time_freqs", "timenet_width", "timenet_out")
FAMILY_SIZES = {
    "static": (),
    "mlp": _SHARED_SIZES + ("mlp_depth", "mlp_width"),
    "liquid": _SHARED_SIZES + ("cells", "hidden", "backbone_units", "backbone_layers", "activation"),
}
"""The FieldOptions sizes each built-in family reads (a field registers its family, fields/registry.py)."""
