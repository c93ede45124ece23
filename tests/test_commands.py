"""`liquidgs eval`, `render` and `export` on a small trained run."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v2 as imageio
import pytest
import torch

from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config, train
from liquidgs.data import generate_synthetic
from liquidgs.fields import FieldConfig, build_field
from liquidgs.gaussians import activate, read_ply
from liquidgs.render import rasterize
from liquidgs.train.run import load_run
from shared_data import optional_lpips_dir


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("cmd")
    scene = Path(generate_synthetic("spinner", root / "spinner", size=40, frames=24, seed=2)) / "dnerf"
    out = root / "run"
    flags = [
        "--data",
        str(scene),
        "--field",
        "sde",
        "--preset",
        "tiny",
        "--iterations",
        "30",
        "--warmup",
        "10",
        "--init-points",
        "600",
        "--eval.start",
        "30",
        "--eval.fps-frames",
        "2",
        "--out",
        str(out),
    ]
    lpips_dir = optional_lpips_dir()
    if lpips_dir:
        flags += ["--eval.lpips-weights", str(lpips_dir)]
    cfg, run_dir = resolve_config(flags)
    train(cfg, run_dir)
    return out


def test_eval_reproduces_the_final_training_evaluation(trained_run):
    assert cli(["eval", "--run", str(trained_run)]) == 0
    record = json.loads((trained_run / "eval.json").read_text())
    results = json.loads((trained_run / "results.json").read_text())
    assert record["kind"].startswith("re-evaluation")
    assert record["iteration"] == results["final"]["iteration"]
    for key in ("psnr", "ssim", "lpips"):
        assert record[key] == pytest.approx(results["final"][key], abs=1e-6)
    per_view = json.loads((trained_run / "eval_per_view.json").read_text())["views"]
    assert len(per_view) == record["n_views"]


def test_eval_says_plainly_when_lpips_vgg_is_unavailable(trained_run, tmp_path, capsys):
    """No VGG weights anywhere: eval.json names LPIPS-VGG, the reason, and that no backbone stood in."""
    no_weights = tmp_path / "no_weights"
    no_weights.mkdir()
    assert cli(["eval", "--run", str(trained_run), "--lpips-backbone", "vgg", "--lpips-weights", str(no_weights)]) == 0
    record = json.loads((trained_run / "eval.json").read_text())
    assert record["lpips"] is None and record["lpips_std"] is None
    reason = record["lpips_unavailable"]
    assert reason.startswith("LPIPS-VGG unavailable: backbone weights not found; looked for: ")
    assert f"{no_weights / 'vgg16_features.pth'}, {no_weights / 'vgg16-397923af.pth'} " in reason
    assert reason.endswith("; no other LPIPS backbone was used instead")
    assert not any(key in record for key in ("lpips_backbone", "lpips_metric", "lpips_weights"))
    assert all(view["lpips"] is None for view in json.loads((trained_run / "eval_per_view.json").read_text())["views"])
    assert "(LPIPS-VGG unavailable: backbone weights not found" in capsys.readouterr().out


def test_export_bakes_the_deltas_in(trained_run, tmp_path):
    out = tmp_path / "export"
    assert cli(["export", "--run", str(trained_run), "--out", str(out), "--time", "0.25", "--sequence", "3"]) == 0
    run = load_run(trained_run, "cpu")
    canonical = read_ply(out / "canonical.ply")
    for key, value in canonical.items():
        assert torch.equal(value, run.params[key].detach()), key
    assert sorted(p.name for p in (out / "sequence").iterdir()) == [f"frame_{i:04d}.ply" for i in range(3)]

    # A viewer rendering the exported PLY sees what the model renders at that time.
    frame_time = 0.25
    baked = activate(read_ply(out / "time_0.2500.ply"))
    live = run.at_time(frame_time)
    viewmat = torch.tensor([[1.0, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 4.0], [0, 0, 0, 1]])
    K = torch.tensor([[60.0, 0, 32], [0, 60, 32], [0, 0, 1]])
    kwargs = dict(viewmat=viewmat, K=K, width=64, height=64, sh_degree=run.sh_degree, backend="torch")
    from_ply = rasterize(baked["means"], baked["quats"], baked["scales"], baked["opacities"], baked["colors"], **kwargs)
    from_model = rasterize(live.means, live.quats, live.scales, live.opacities, live.colors, **kwargs)
    assert from_model.alpha.max() > 0.1
    assert torch.allclose(from_ply.rgb, from_model.rgb, atol=1e-5)

    # The field's weights travel with their config and evaluate the same elsewhere.
    payload = torch.load(out / "field.pt", weights_only=False)
    field = build_field(FieldConfig(**payload["config"]))
    field.load_state_dict(payload["state_dict"])
    field.eval()
    xyz = run.params["means"].detach()
    t = torch.full((xyz.shape[0], 1), 0.6)
    for a, b in zip(field(xyz, t), run.field(xyz, t)):
        assert torch.equal(a, b)


def test_render_writes_views_sweep_and_orbit(trained_run, tmp_path):
    out = tmp_path / "renders"
    args = ["render", "--run", str(trained_run), "--out", str(out), "--sweep-frames", "6", "--orbit-frames", "8"]
    assert cli(args) == 0
    test_names = sorted(p.name for p in (out / "test" / "render").iterdir())
    assert test_names and test_names == sorted(p.name for p in (out / "test" / "gt").iterdir())
    assert len(list((out / "test" / "depth").iterdir())) == len(test_names)
    sweep = imageio.mimread(out / "sweep.mp4")
    orbit = imageio.mimread(out / "orbit.mp4")
    assert len(sweep) == 6 and len(orbit) == 8
    assert sweep[0].shape[:2] == (40, 40)
    # The orbit really moves around the object: consecutive frames differ.
    assert any(abs(orbit[i].astype(int) - orbit[i + 1].astype(int)).mean() > 0.5 for i in range(7))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["render", "--orbit-time", "2"], "--orbit-time 2.0 is outside [0, 1]"),
        (["export", "--time", "-0.5"], "--time -0.5 is outside [0, 1]"),
        (["render", "--sweep-camera", "99"], "--sweep-camera 99 is not a test view"),
    ],
)
def test_bad_arguments_are_one_line_errors(trained_run, tmp_path, capsys, args, message):
    assert cli([*args[:1], "--run", str(trained_run), *args[1:]]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_commands_on_a_folder_that_is_no_run(tmp_path, capsys):
    for command in ("eval", "render", "export"):
        assert cli([command, "--run", str(tmp_path)]) == 2
        err = capsys.readouterr().err.strip()
        assert "not a liquidgs run folder" in err and len(err.splitlines()) == 1


def test_uncertainty_maps_from_monte_carlo_renders(trained_run, tmp_path):
    out = tmp_path / "mc"
    args = ["render", "--run", str(trained_run), "--out", str(out), "--sweep-frames", "2", "--orbit-frames", "2",
            "--uncertainty-samples", "4"]  # fmt: skip
    assert cli(args) == 0
    summary = json.loads((out / "uncertainty.json").read_text())
    assert summary["samples"] == 4 and summary["lambda"] == pytest.approx(0.05)
    views = summary["views"]
    assert views and sorted(views) == sorted(p.stem for p in (out / "test" / "uncertainty").iterdir())
    assert max(v["max_std"] for v in views.values()) == pytest.approx(summary["white_is_std"])
    assert summary["white_is_std"] > 0, "the sde field's noise must show as per-pixel spread"
    assert len(list((out / "test" / "mc_mean").iterdir())) == len(views)


def test_uncertainty_needs_the_sde_field(trained_run, tmp_path, capsys):
    import shutil

    import yaml

    cfc_run = tmp_path / "cfc_run"
    shutil.copytree(trained_run, cfc_run)
    config = yaml.safe_load((cfc_run / "config.yml").read_text())
    config["field"], config["lambda_"] = "cfc", 0.0
    (cfc_run / "config.yml").write_text(yaml.safe_dump(config))
    assert cli(["render", "--run", str(cfc_run), "--uncertainty-samples", "4"]) == 2
    err = capsys.readouterr().err.strip()
    assert "needs a run of the 'sde' field" in err and len(err.splitlines()) == 1
