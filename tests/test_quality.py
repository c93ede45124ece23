"""Quality bars (integration, CPU): every deformation field must beat the static model.

Both scenes train the tiny preset stretched to N iterations (train.config.stretched_schedule),
all eight runs in one pool, two at a time as one-thread `liquidgs train` processes. Final test
PSNR in dB measured on the 2-core CPU machine (torch 2.13.0, compiled CPU kernels), seeds
0 / 1 / 2 (LIQUIDGS_QUALITY_SEED):
- hellwarrior downscaled to 100x100, N = 1,000:
  static 30.86 / 30.82 / 30.83, MLP 32.96 / 33.03 / 32.88, CfC 33.01 / 33.07 / 32.79,
  SDE-LNN 33.01 / 32.79 / 32.63: margins over static 1.81-2.25 dB -> every field >= static + 1.5
  (before issue 14, the preset's 1,500-iteration schedule cut at 600: margins 0.25-0.71 dB, bar
  "> static"; on the code before the compiled projection, SSIM and CfC gate the margins were
  1.52-2.13 and the bar 1.0)
- the demo's synthetic scene (puppet, 64x64, 80 frames), N = 1,200 with the demo's densification
  threshold (0.0014): static 23.69 / 23.70 / 23.71, MLP 25.00 / 24.97 / 25.13, CfC 24.73 / 25.13 /
  25.18, SDE-LNN 24.68 / 24.92 / 24.92: margins 1.00-1.48 dB -> every field >= static + 0.75
  (N = 1,000 at the preset's threshold 0.0007 gave only 0.61-1.00 on earlier code)
The pool takes 2.5-3 minutes of the suite.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from liquidgs.commands.demo import DENSIFY_GRAD_THRESHOLD
from liquidgs.data import DEFAULT_SYNTHETIC_SCENE, generate_synthetic
from liquidgs.experiments.plan import RunEntry, run_config
from liquidgs.experiments.runner import run_local
from liquidgs.settings import to_dict
from liquidgs.train.config import stretched_schedule
from shared_data import DNERF_ROOT, require_shared

HELLWARRIOR = DNERF_ROOT / "hellwarrior"
FIELDS = ("mlp", "cfc", "sde")
DNERF_MARGIN = 1.5
SYNTHETIC_MARGIN = 0.75
# The suite trains seed 0; the spread above was measured with LIQUIDGS_QUALITY_SEED=1 and 2.
SEED = int(os.environ.get("LIQUIDGS_QUALITY_SEED", "0"))

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def scores(tmp_path_factory) -> dict[str, dict[str, float]]:
    """Final test PSNR per scene and run. Every run of both scenes goes into one pool, two at a
    time and the slowest fields first, so neither CPU slot waits at the end of a scene."""
    root = tmp_path_factory.mktemp("quality")
    synthetic = generate_synthetic(DEFAULT_SYNTHETIC_SCENE, root / "scene", size=64, frames=80, seed=0)
    # The demo's scene (puppet, 64x64, 80 frames) with the demo's densification threshold.
    demo_threshold = {"densify.grad_threshold": DENSIFY_GRAD_THRESHOLD}
    scenes = {"synthetic": (Path(synthetic) / "dnerf", demo_threshold, 1200)}
    if HELLWARRIOR.is_dir():
        scenes["hellwarrior"] = (HELLWARRIOR, {"downscale": 8}, 1000)  # 100x100
    entries = []
    for field in ("sde", "cfc", "mlp", "static"):
        for scene, (path, extra, iterations) in scenes.items():
            run_settings = {"field": field, "seed": SEED, **extra, **stretched_schedule("tiny", iterations),
                            "eval.lpips_backbone": "alex", "eval.fps_frames": 2}  # fmt: skip
            cfg = run_config("tiny", path, run_settings, f"{scene}/{field}")
            run_dir = f"{scene}/{field}"
            entries.append(RunEntry("test", scene, field, cfg.resolved_lambda(), SEED, "tiny", str(path), run_dir,
                                    to_dict(cfg)))  # fmt: skip
    outcomes = run_local(entries, root, 2, lambda outcome: None)
    assert all(o.status == "done" for o in outcomes), [o.message for o in outcomes]
    results = {scene: {} for scene in scenes}
    for entry in entries:
        final = json.loads((root / entry.run_dir / "results.json").read_text())["final"]
        results[entry.scene][entry.field] = final["psnr"]
    print("final test PSNR:", results)
    return results


@pytest.mark.parametrize("field", FIELDS)
def test_fields_beat_static_on_the_default_synthetic_scene(scores, field):
    synthetic = scores["synthetic"]
    assert synthetic[field] >= synthetic["static"] + SYNTHETIC_MARGIN, synthetic


@pytest.mark.parametrize("field", FIELDS)
def test_fields_beat_static_on_a_shared_dnerf_scene(scores, field):
    require_shared(HELLWARRIOR)
    hellwarrior = scores["hellwarrior"]
    assert hellwarrior[field] >= hellwarrior["static"] + DNERF_MARGIN, hellwarrior
