"""Quality bars (integration, CPU): every deformation field must beat the static model.

Both scenes train the tiny preset stretched to 1,000 iterations (train.config.stretched_schedule),
the runs two at a time as one-thread `liquidgs train` processes. Final test PSNR in dB measured
on the 2-core CPU machine (torch 2.13.0), seeds 0 / 1 / 2:
- hellwarrior downscaled to 100x100:
  static 30.85 / 30.80 / 30.84, MLP 32.79 / 32.87 / 32.95, CfC 32.37 / 32.81 / 32.97,
  SDE-LNN 32.66 / 32.89 / 32.86: margins over static 1.52-2.13 dB -> every field >= static + 1.0
  (before issue 14, the preset's 1,500-iteration schedule cut at 600: margins 0.25-0.71 dB)
- the demo's synthetic scene (puppet, 64x64, 80 frames):
  static 23.66 / 23.71 / 23.62, MLP 24.66 / 24.69 / 24.51, CfC 24.46 / 24.32 / 24.38,
  SDE-LNN 24.31 / 24.38 / 24.44: margins 0.61-1.00 dB -> every field >= static + 0.5
  (the old bar, static + 0.75 at 128x128 with the preset's 1,500 iterations, is not kept:
  this cheaper run learns less of the motion; the demo's 2,000 iterations give 2.1-2.6 dB)
Each field run takes 45-65 s on one thread; the quality tests about 4 minutes of the suite.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from liquidgs.data import DEFAULT_SYNTHETIC_SCENE, generate_synthetic
from liquidgs.experiments.plan import RunEntry
from liquidgs.experiments.runner import run_local
from liquidgs.train.config import stretched_schedule

SHARED = Path(__file__).resolve().parents[2] / "shared"
FIELDS = ("mlp", "cfc", "sde")
ITERATIONS = 1000
DNERF_MARGIN = 1.0
SYNTHETIC_MARGIN = 0.5

pytestmark = pytest.mark.slow


def final_psnrs(scene: Path, root: Path, extra: list[str]) -> dict[str, float]:
    """Final test PSNR of static and each field, trained two at a time (slowest first)."""
    entries = []
    for field in ("sde", "cfc", "mlp", "static"):
        args = ["--data", str(scene), "--preset", "tiny", "--field", field, *extra]
        args += [*stretched_schedule("tiny", ITERATIONS), "--eval.lpips-backbone", "alex", "--eval.fps-frames", "2"]
        entries.append(RunEntry("test", scene.name, field, 0.0, 0, "tiny", str(scene), field, tuple(args)))
    outcomes = run_local(entries, root, 2, lambda outcome: None)
    assert all(o.status == "done" for o in outcomes), [o.message for o in outcomes]
    return {e.field: json.loads((root / e.run_dir / "results.json").read_text())["final"]["psnr"] for e in entries}


@pytest.fixture(scope="module")
def synthetic_scores(tmp_path_factory) -> dict[str, float]:
    """The demo's synthetic scene: puppet at 64x64, 80 frames."""
    root = tmp_path_factory.mktemp("quality")
    scene = Path(generate_synthetic(DEFAULT_SYNTHETIC_SCENE, root / "scene", size=64, frames=80, seed=0)) / "dnerf"
    scores = final_psnrs(scene, root / "runs", [])
    print("synthetic 64x64 final test PSNR:", scores)
    return scores


@pytest.fixture(scope="module")
def dnerf_scores(tmp_path_factory) -> dict[str, float]:
    """A shared D-NeRF scene downscaled to 100x100."""
    scene = SHARED / "data" / "dnerf" / "hellwarrior"
    if not scene.is_dir():
        pytest.skip(f"shared D-NeRF scene not found at {scene}")
    scores = final_psnrs(scene, tmp_path_factory.mktemp("dnerf"), ["--downscale", "8"])
    print("hellwarrior 100x100 final test PSNR:", scores)
    return scores


@pytest.mark.parametrize("field", FIELDS)
def test_fields_beat_static_on_the_default_synthetic_scene(synthetic_scores, field):
    assert synthetic_scores[field] >= synthetic_scores["static"] + SYNTHETIC_MARGIN, synthetic_scores


@pytest.mark.parametrize("field", FIELDS)
def test_fields_beat_static_on_a_shared_dnerf_scene(dnerf_scores, field):
    assert dnerf_scores[field] >= dnerf_scores["static"] + DNERF_MARGIN, dnerf_scores
