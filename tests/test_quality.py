"""Quality bars (integration, CPU): every deformation field must beat the static model.

The bars were set after measuring on the 2-core CPU machine (torch 2.13.0, seed 0), final
test PSNR in dB:
- default synthetic scene (puppet, 128x128), tiny preset (1,500 iterations):
  static 22.96, MLP 24.41, CfC 24.30, SDE-LNN 24.25  -> every field >= static + 0.75 dB
- hellwarrior downscaled to 100x100, tiny preset cut to 600 iterations:
  static 29.55, MLP 30.29, CfC 30.02, SDE-LNN 29.76  -> every field > static
  (SDE-LNN's margin over static at seeds 1 and 2: +0.87 and +1.20 dB; seed 0, used here, is the
  low end at +0.20, so a failure on another CPU should first be checked against other seeds)
Together these runs take about 12 minutes of the suite.
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
