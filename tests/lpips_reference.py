"""Reference LPIPS distances from the PyPI `lpips` package, run in .venv-lpips-ref (not in .venv).

Usage: python lpips_reference.py PAIRS.npz OUT_DIR

PAIRS.npz holds arrays ``<name>_img`` and ``<name>_ref``, [B, H, W, 3] float32 in [0, 1].
For each backbone this builds ``lpips.LPIPS(net=..., pretrained=True, pnet_rand=True,
version='0.1')`` after ``torch.manual_seed(SEED)``: the package's own lin-layer weights with a
randomly initialised torchvision backbone (the ImageNet weights are not available offline).
It writes OUT_DIR/<backbone>_features.pth, the backbone as a torchvision ``features.*`` state
dict, and OUT_DIR/distances.json: ``{"versions": {...}, "distances": {backbone: {name: [B floats]}}}``.
This file imports neither liquidgs nor anything from the project's environment.
"""

from __future__ import annotations

import json
import sys
import warnings
from importlib.metadata import version
from pathlib import Path

import lpips
import numpy as np
import torch
import torchvision

SEED = 0
BACKBONES = ("vgg", "alex", "squeeze")


def torchvision_features_state(model: lpips.LPIPS) -> dict[str, torch.Tensor]:
    """lpips splits torchvision's ``features`` into slices whose children keep their original
    indices as names (``net.slice2.5.weight`` is ``features.5.weight``); undo the split."""
    state = {}
    for slice_module in model.net.children():
        for index, layer in slice_module.named_children():
            for key, tensor in layer.state_dict().items():
                state[f"features.{index}.{key}"] = tensor.clone()
    return state


def main(pairs_path: Path, out_dir: Path) -> None:
    pairs = np.load(pairs_path)
    names = sorted({key.rsplit("_", 1)[0] for key in pairs.files})
    distances: dict[str, dict[str, list[float]]] = {}
    for backbone in BACKBONES:
        torch.manual_seed(SEED)
        with warnings.catch_warnings():  # lpips still passes torchvision's deprecated `pretrained=`
            warnings.simplefilter("ignore", UserWarning)
            model = lpips.LPIPS(net=backbone, pretrained=True, pnet_rand=True, version="0.1", verbose=False)
        model.eval()
        torch.save(torchvision_features_state(model), out_dir / f"{backbone}_features.pth")
        distances[backbone] = {}
        with torch.no_grad():
            for name in names:
                img = torch.from_numpy(pairs[f"{name}_img"]).permute(0, 3, 1, 2)
                ref = torch.from_numpy(pairs[f"{name}_ref"]).permute(0, 3, 1, 2)
                scores = model(img, ref, normalize=True)  # [B, 1, 1, 1]
                distances[backbone][name] = scores.flatten().tolist()
    versions = {"torch": torch.__version__, "torchvision": torchvision.__version__, "lpips": version("lpips")}
    record = {"versions": versions, "seed": SEED, "distances": distances}
    (out_dir / "distances.json").write_text(json.dumps(record, indent=1))


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(f"usage: {sys.argv[0]} PAIRS.npz OUT_DIR")
    main(Path(sys.argv[1]), Path(sys.argv[2]))
