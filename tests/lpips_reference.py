"""Record (or re-check) the PyPI `lpips` package's distances that tests/test_lpips_reference.py holds ours to.

Usage, in an environment with lpips 0.1.4 and torchvision (`make lpips-reference` makes
.venv-lpips-ref and runs both):
    python tests/lpips_reference.py write tests/data/lpips_pypi_reference.json
    python tests/lpips_reference.py check tests/data/lpips_pypi_reference.json

For each backbone this builds ``lpips.LPIPS(net=..., pretrained=True, pnet_rand=True,
version='0.1')`` - the package's own lin-layer weights - and replaces the backbone's weights with
lpips_cases.seeded_features (the ImageNet weights are not available offline, and seeded weights
can be rebuilt from a few numbers instead of shipping a 58 MB VGG file). It then scores every
pair of lpips_cases.image_pairs with normalize=True and False. `write` records the distances, the
backbone's tensor names and shapes, and checksums of every input; `check` recomputes them and
fails if any distance moved by more than a relative 1e-5 from the record.
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

from lpips_cases import BACKBONES, NORMALIZE, SEED, checksum, image_pairs, seeded_features

RTOL = 1e-5


def backbone_layers(model: lpips.LPIPS):
    """lpips splits torchvision's ``features`` into slices whose children keep their original
    indices as names (``net.slice2.5.weight`` is ``features.5.weight``): yield (index, layer)."""
    for slice_module in model.net.children():
        yield from slice_module.named_children()


def seeded_model(backbone: str) -> tuple[lpips.LPIPS, dict[str, list[int]]]:
    with warnings.catch_warnings():  # lpips still passes torchvision's deprecated `pretrained=`
        warnings.simplefilter("ignore", UserWarning)
        model = lpips.LPIPS(net=backbone, pretrained=True, pnet_rand=True, version="0.1", verbose=False)
    model.eval()
    shapes = {
        f"features.{index}.{key}": list(tensor.shape)
        for index, layer in backbone_layers(model)
        for key, tensor in layer.state_dict().items()
    }
    weights = seeded_features(shapes)
    with torch.no_grad():
        for index, layer in backbone_layers(model):
            state = {key: torch.from_numpy(weights[f"features.{index}.{key}"]) for key in layer.state_dict()}
            layer.load_state_dict(state)
    return model, shapes


def record() -> dict:
    pairs = image_pairs()
    distances: dict[str, dict[str, dict[str, list[float]]]] = {}
    shapes_by_backbone = {}
    weight_checksums = {}
    for backbone in BACKBONES:
        model, shapes = seeded_model(backbone)
        shapes_by_backbone[backbone] = shapes
        weight_checksums[backbone] = checksum(seeded_features(shapes))
        distances[backbone] = {}
        for mode, normalize in NORMALIZE.items():
            with torch.no_grad():
                distances[backbone][mode] = {
                    name: model(
                        torch.from_numpy(img).permute(0, 3, 1, 2),
                        torch.from_numpy(ref).permute(0, 3, 1, 2),
                        normalize=normalize,
                    )
                    .flatten()
                    .tolist()
                    for name, (img, ref) in pairs.items()
                }
    return {
        "about": "PyPI lpips 0.1.4 distances on seeded backbones; regenerate with `make lpips-reference`",
        "versions": {
            "lpips": version("lpips"),
            "torch": torch.__version__,
            "torchvision": torchvision.__version__,
            "numpy": np.__version__,
        },
        "seed": SEED,
        "input_checksums": {name: checksum({"img": img, "ref": ref}) for name, (img, ref) in pairs.items()},
        "weight_checksums": weight_checksums,
        "backbone_shapes": shapes_by_backbone,
        "distances": distances,
    }


def check(recorded: dict, fresh: dict) -> list[str]:
    problems = []
    for backbone, modes in recorded["distances"].items():
        for mode, by_pair in modes.items():
            for name, expected in by_pair.items():
                got = fresh["distances"][backbone][mode][name]
                if not np.allclose(got, expected, rtol=RTOL, atol=0):
                    problems.append(f"{backbone} {mode} {name}: recorded {expected}, now {got}")
    return problems


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("write", "check"):
        print(f"usage: {Path(sys.argv[0]).name} write|check RECORD.json", file=sys.stderr)
        return 2
    path = Path(argv[1])
    fresh = record()
    if argv[0] == "write":
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(fresh, indent=1) + "\n")
        print(f"wrote {path} (lpips {fresh['versions']['lpips']})")
        return 0
    problems = check(json.loads(path.read_text()), fresh)
    for line in problems:
        print(line, file=sys.stderr)
    print(f"{path}: {'differs from' if problems else 'matches'} lpips {fresh['versions']['lpips']} here")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
