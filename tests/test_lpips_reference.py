"""Our LPIPS v0.1 against the PyPI `lpips` package, with identical backbone weights.

The package needs torchvision, which does not load beside the project's torch, so its distances
were recorded once in its own environment (tests/lpips_reference.py, `make lpips-reference`) into
tests/data/lpips_pypi_reference.json: lpips 0.1.4 with seeded backbones for vgg / alex /
squeeze, inputs normalised and not, square and non-square image pairs. Here our LPIPS loads the
same seeded weights (and the lin layers from our environment's copy of the same package release)
and must give the same distances to a relative 1e-5 in float32.
"""

from __future__ import annotations

import importlib.metadata
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from liquidgs.eval import LPIPS
from lpips_cases import BACKBONES, NORMALIZE, checksum, image_pairs, seeded_features

RECORD = Path(__file__).with_name("data") / "lpips_pypi_reference.json"
# float32 on both sides; the two torch builds may pick different conv algorithms.
RTOL = 1e-5


@pytest.fixture(scope="module")
def record() -> dict:
    return json.loads(RECORD.read_text())


@pytest.fixture(scope="module")
def pairs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return image_pairs()


def test_inputs_are_the_recorded_ones(record, pairs):
    """Same lin-layer release, same images, same weights: else a mismatch below would mean nothing."""
    assert record["versions"]["lpips"] == importlib.metadata.version("lpips")
    assert sorted(pairs) == sorted(record["input_checksums"])
    for name, (img, ref) in pairs.items():
        assert checksum({"img": img, "ref": ref}) == pytest.approx(record["input_checksums"][name], rel=1e-12), name
    for backbone in BACKBONES:
        weights = seeded_features(record["backbone_shapes"][backbone])
        assert checksum(weights) == pytest.approx(record["weight_checksums"][backbone], rel=1e-12), backbone
    assert any(img.shape[1] != img.shape[2] for img, _ in pairs.values())  # a non-square pair is covered


@pytest.fixture(scope="module")
def weight_files(tmp_path_factory, record) -> dict[str, Path]:
    """The recorded seeded backbones as torchvision ``features.*`` state dicts, as users pass them."""
    folder = tmp_path_factory.mktemp("seeded_lpips")
    files = {}
    for backbone in BACKBONES:
        state = {k: torch.from_numpy(v) for k, v in seeded_features(record["backbone_shapes"][backbone]).items()}
        files[backbone] = folder / f"{backbone}_features.pth"
        torch.save(state, files[backbone])
    return files


@pytest.mark.parametrize("mode", sorted(NORMALIZE))
@pytest.mark.parametrize("backbone", BACKBONES)
def test_matches_pypi_lpips(backbone, mode, record, pairs, weight_files):
    metric = LPIPS(backbone, normalize=NORMALIZE[mode], weights=weight_files[backbone])
    expected_by_pair = record["distances"][backbone][mode]
    assert sorted(expected_by_pair) == sorted(pairs)
    for name, (img, ref) in pairs.items():
        ours = metric(torch.from_numpy(img), torch.from_numpy(ref))
        np.testing.assert_allclose(
            ours.numpy(),
            np.asarray(expected_by_pair[name]),
            rtol=RTOL,
            atol=0,
            err_msg=f"LPIPS-{backbone} ({mode}) on '{name}' vs lpips {record['versions']}",
        )
    # Distinct pairs give distinct distances: the comparison is not between constants.
    assert len({round(v, 6) for values in expected_by_pair.values() for v in values}) > 3
