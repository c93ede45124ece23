"""Our LPIPS v0.1 against the PyPI `lpips` package, with identical backbone weights.

The package needs torchvision, which does not load beside the project's torch, so it runs in
its own environment (.venv-lpips-ref, made by scripts/setup_lpips_reference.sh; `make test`
creates it when missing) as a subprocess: tests/lpips_reference.py builds each backbone with
random weights (fixed seed) and the package's lin layers, saves the backbone as a torchvision
``features.*`` state dict and writes the distances; here our LPIPS loads that file (and the
same lin-layer file from our environment's copy of the package) and must give the same
distances to a relative 1e-5 in float32.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from liquidgs.eval import LPIPS

ROOT = Path(__file__).resolve().parents[1]
REF_VENV = ROOT / ".venv-lpips-ref"
# Written last by the set-up script, so a half-installed environment counts as missing.
REF_MARKER = REF_VENV / "installed"
REF_SCRIPT = Path(__file__).with_name("lpips_reference.py")
SETUP_COMMAND = "bash scripts/setup_lpips_reference.sh"
LPIPS_EXAMPLES = ROOT.parent / "shared" / "data" / "lpips"
# float32 on both sides; the two torch builds may pick different conv algorithms.
RTOL = 1e-5


def image_pairs() -> dict[str, np.ndarray]:
    """Deterministic pairs in [0, 1] (8-bit levels, so both sides read identical float32s)."""
    rng = np.random.default_rng(0)

    def levels(*shape: int) -> np.ndarray:
        return rng.integers(0, 256, size=shape).astype(np.float32) / 255

    pairs = {
        "noise_64": (levels(3, 64, 64, 3), levels(3, 64, 64, 3)),
        # Odd, non-square: exercises the pools' rounding (SqueezeNet's ceil_mode).
        "noise_97x80": (levels(2, 97, 80, 3), levels(2, 97, 80, 3)),
    }
    # A smooth image (red and green ramps) and a copy with faint 8-bit noise: a small distance.
    ramp = np.arange(64, dtype=np.float32) * 4 / 255
    base = np.stack(np.broadcast_arrays(ramp[None, :], ramp[:, None], np.float32(128 / 255)), -1)
    near = np.clip(base + rng.integers(-3, 4, size=base.shape) / 255, 0, 1).astype(np.float32)
    pairs["small_difference"] = (base[None], near[None])
    examples = [np.asarray(Image.open(LPIPS_EXAMPLES / f"{name}.png").convert("RGB")) for name in ("ex_p0", "ex_p1")]
    reference = np.asarray(Image.open(LPIPS_EXAMPLES / "ex_ref.png").convert("RGB"))
    pairs["lpips_examples"] = (
        np.stack(examples).astype(np.float32) / 255,
        np.stack([reference, reference]).astype(np.float32) / 255,
    )
    return {f"{name}_{side}": array for name, pair in pairs.items() for side, array in zip(("img", "ref"), pair)}


@pytest.fixture(scope="module")
def pairs() -> dict[str, np.ndarray]:
    return image_pairs()


@pytest.fixture(scope="module")
def reference(tmp_path_factory, pairs) -> tuple[Path, dict] | None:
    """Run the reference script once; None when its environment is missing (each test then fails)."""
    if not REF_MARKER.is_file():
        return None
    out_dir = tmp_path_factory.mktemp("lpips_reference")
    pairs_path = out_dir / "pairs.npz"
    np.savez(pairs_path, **pairs)
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    done = subprocess.run(
        [str(REF_VENV / "bin" / "python"), str(REF_SCRIPT), str(pairs_path), str(out_dir)],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, f"{REF_SCRIPT.name} failed in {REF_VENV}:\n{done.stderr[-3000:]}"
    return out_dir, json.loads((out_dir / "distances.json").read_text())


def require(reference: tuple[Path, dict] | None) -> tuple[Path, dict]:
    if reference is None:
        pytest.fail(
            f"the LPIPS reference environment {REF_VENV} is missing or incomplete: "
            f"create it with `{SETUP_COMMAND}` (`make test` does this)",
            pytrace=False,
        )
    return reference


def test_same_lin_layer_source(reference):
    """Both sides read the lin layers from the same release of the package."""
    _, record = require(reference)
    assert record["versions"]["lpips"] == importlib.metadata.version("lpips")


@pytest.mark.parametrize("backbone", ["vgg", "alex", "squeeze"])
def test_matches_pypi_lpips(backbone, reference, pairs):
    out_dir, record = require(reference)
    metric = LPIPS(backbone, normalize=True, weights=out_dir / f"{backbone}_features.pth")
    expected_by_pair = record["distances"][backbone]
    assert sorted(expected_by_pair) == sorted({key.rsplit("_", 1)[0] for key in pairs})
    for name, expected in expected_by_pair.items():
        ours = metric(torch.from_numpy(pairs[f"{name}_img"]), torch.from_numpy(pairs[f"{name}_ref"]))
        np.testing.assert_allclose(
            ours.numpy(),
            np.asarray(expected),
            rtol=RTOL,
            atol=0,
            err_msg=f"LPIPS-{backbone} on '{name}' vs lpips {record['versions']}",
        )
