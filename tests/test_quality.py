"""Quality bars (integration, CPU): every deformation field must beat the static model.

The bars were set after measuring on the 2-core CPU machine (torch 2.13.0, seed 0), final
test PSNR in dB; re-measured on the compiled CPU rasteriser, fused Adam and single-product
field heads (issue 14), which move every number by rounding only:
- default synthetic scene (puppet, 128x128), tiny preset (1,500 iterations):
  static 22.97, MLP 24.44, CfC 24.09, SDE-LNN 24.33  -> every field >= static + 0.75 dB
  (before issue 14: 22.96, 24.41, 24.30, 24.25)
- hellwarrior downscaled to 100x100, tiny preset cut to 600 iterations:
  static 29.59, MLP 30.30, CfC 30.26, SDE-LNN 29.84  -> every field > static
  (before: 29.55, 30.29, 30.02, 29.76; SDE-LNN's margin at seeds 1 and 2 was then +0.87 and
  +1.20 dB, seed 0 the low end, so a failure on another CPU should first be checked against
  other seeds; the seed spread has not been re-measured on this code)
Together these runs take about 6 minutes of the suite (12 before issue 14).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from liquidgs.commands.train import resolve_config, train
from liquidgs.data import DEFAULT_SYNTHETIC_SCENE, generate_synthetic

SHARED = Path(__file__).resolve().parents[2] / "shared"
FIELDS = ("mlp", "cfc", "sde")

pytestmark = pytest.mark.slow


def final_psnr(args: list[str]) -> float:
    cfg, run_dir = resolve_config([*args, "--eval.lpips-backbone", "alex", "--eval.fps-frames", "2"])
    results = train(cfg, run_dir)
    return float(json.loads(json.dumps(results))["final"]["psnr"])


@pytest.fixture(scope="module")
def synthetic_scores(tmp_path_factory) -> dict[str, float]:
    """The default synthetic scene at its default size, the tiny preset, each field and static."""
    root = tmp_path_factory.mktemp("quality")
    scene = Path(generate_synthetic(DEFAULT_SYNTHETIC_SCENE, root / "scene", seed=0)) / "dnerf"
    scores = {}
    for field in ("static", *FIELDS):
        scores[field] = final_psnr(
            ["--data", str(scene), "--field", field, "--preset", "tiny", "--out", str(root / field)]
        )
    print("synthetic final test PSNR:", scores)
    return scores


@pytest.fixture(scope="module")
def dnerf_scores(tmp_path_factory) -> dict[str, float]:
    """A shared D-NeRF scene downscaled to 100x100, a short run of each field and static."""
    scene = SHARED / "data" / "dnerf" / "hellwarrior"
    if not scene.is_dir():
        pytest.skip(f"shared D-NeRF scene not found at {scene}")
    root = tmp_path_factory.mktemp("dnerf")
    scores = {}
    for field in ("static", *FIELDS):
        scores[field] = final_psnr(
            ["--data", str(scene), "--downscale", "8", "--field", field, "--preset", "tiny",
             "--iterations", "600", "--eval.start", "600", "--out", str(root / field)]
        )  # fmt: skip
    print("hellwarrior 100x100 final test PSNR:", scores)
    return scores


@pytest.mark.parametrize("field", FIELDS)
def test_fields_beat_static_on_the_default_synthetic_scene(synthetic_scores, field):
    assert synthetic_scores[field] >= synthetic_scores["static"] + 0.75, synthetic_scores


@pytest.mark.parametrize("field", FIELDS)
def test_fields_beat_static_on_a_shared_dnerf_scene(dnerf_scores, field):
    assert dnerf_scores[field] > dnerf_scores["static"], dnerf_scores
