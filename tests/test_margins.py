"""The fields' margin over the static model: regions, their PSNR, the margins spec and report section."""

from __future__ import annotations

import dataclasses
import json
import math
import statistics
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from liquidgs.cli import main as cli
from liquidgs.commands.train import main as train_main
from liquidgs.data import DataConfig, generate_synthetic, load_dataset
from liquidgs.data.regions import foreground_region, frame_step, moving_region
from liquidgs.data.synthetic import moving_mask
from liquidgs.errors import ConfigError, DataError
from liquidgs.eval.regions import region_psnr, region_share
from liquidgs.experiments import (
    Experiment,
    RunEntry,
    expand,
    generate_scenes,
    load_spec,
    spec_from_dict,
    write_manifest,
)
from liquidgs.experiments.report import write_report
from liquidgs.experiments.report.collect import collect
from liquidgs.experiments.report.margins import (
    RunScores,
    dataset_margin,
    margin_difference,
    margin_floor,
    margin_section,
    margin_sentences,
    scene_margins,
    verdict,
)
from liquidgs.experiments.report.references import paper_sigma
from liquidgs.experiments.report.significance import TOO_FEW, t_interval
from liquidgs.experiments.runner import train_command
from liquidgs.experiments.spec import MINI_SCHEDULE, SHARED_DNERF_SCENES
from liquidgs.train.config import preset_config, save_yaml
from shared_data import DNERF_ROOT, require_shared
from tiny_runs import one_line_error


# ----------------------------------------------------------------------------- region PSNR
def test_region_psnr_pools_the_masked_pixels_of_every_view():
    truth = [np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4, 3), np.uint8)]
    render = [np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4, 3), np.uint8)]
    render[0][0, 0] = 51  # error 0.2 on 3 values of view 0
    render[1][3, 3] = 255  # error 1.0 on 3 values of view 1, outside its mask
    masks = [np.zeros((4, 4), bool), np.zeros((4, 4), bool)]
    masks[0][0, :2] = True  # 2 pixels: one wrong by 0.2, one right
    masks[1][0, 0] = True  # 1 pixel, right
    expected = -10 * math.log10(3 * 0.2**2 / (3 * 3))
    assert region_psnr(render, truth, masks) == pytest.approx(expected)
    # the whole image of view 1 alone: 3 of 48 values off by 1
    assert region_psnr(render[1:], truth[1:], [np.ones((4, 4), bool)]) == pytest.approx(-10 * math.log10(3 / 48))
    assert region_psnr(render, truth, [np.zeros((4, 4), bool)] * 2) is None
    assert region_psnr(truth, truth, masks) == pytest.approx(120.0)
    assert region_share(masks) == pytest.approx(3 / 32)
    with pytest.raises(ConfigError, match="do not match"):
        region_psnr(render, truth, [np.ones((3, 4), bool)] * 2)


# ----------------------------------------------------------------------------- regions
@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scene")
    return Path(generate_synthetic("puppet", root / "puppet", size=16, frames=9, seed=1)) / "dnerf"


def test_moving_region_is_the_synthetic_mask_of_the_view(tiny_scene):
    dataset = load_dataset(DataConfig(tiny_scene))
    frames = [f for split in dataset.splits.values() for f in split]
    assert frame_step(frames) == pytest.approx(1 / 8)
    frame = dataset.test[0]
    mask = moving_region("puppet", frame, 1 / 8)
    cam_to_world = np.linalg.inv(frame.camera.viewmat.double().numpy())
    expected = moving_mask("puppet", frame.camera.K.double().numpy(), cam_to_world, 16, 16, frame.time, 1 / 8)
    assert mask.dtype == bool and mask.shape == (16, 16) and (mask == expected).all() and mask.any()
    with pytest.raises(DataError, match="two distinct frame times"):
        frame_step(frames[:1])


def test_foreground_is_any_alpha_in_the_downscaled_block(tmp_path, tiny_scene):
    frame = load_dataset(DataConfig(tiny_scene)).test[0]
    rgba = np.zeros((8, 12, 4), np.uint8)
    rgba[0, 0, 3] = 1  # one faint sub-pixel: block (0, 0) is foreground
    rgba[5:8, 6:9, 3] = 255  # at factor 2: block rows 2-3, block columns 3-4
    Image.fromarray(rgba, "RGBA").save(tmp_path / "view.png")
    small_camera = dataclasses.replace(frame.camera, width=6, height=4)
    small = dataclasses.replace(frame, camera=small_camera, image_path=tmp_path / "view.png")
    mask = foreground_region(small)
    expected = np.zeros((4, 6), bool)
    expected[0, 0] = True
    expected[2:4, 3:5] = True
    assert (mask == expected).all()
    Image.fromarray(rgba[..., :3], "RGB").save(tmp_path / "rgb.png")
    assert foreground_region(dataclasses.replace(small, image_path=tmp_path / "rgb.png")).all()
    with pytest.raises(DataError, match="whole multiple"):
        foreground_region(dataclasses.replace(small, camera=dataclasses.replace(small_camera, width=5)))


# ----------------------------------------------------------------------------- margins
def scores(dataset, scene, field, seed, whole, moving=None) -> RunScores:
    return RunScores(dataset, scene, field, seed, {"whole": whole, "foreground": whole - 1, "moving": moving})


def test_margins_are_paired_by_seed_with_mean_and_sample_std():
    static = {0: 20.0, 1: 21.0, 2: 19.0}
    mlp = {0: 22.0, 1: 22.5, 2: 21.5}
    runs = [scores("d", "a", "static", s, v, v - 5) for s, v in static.items()]
    runs += [scores("d", "a", "mlp", s, v, v - 4) for s, v in mlp.items()]
    runs += [scores("d", "a", "cfc", 0, 20.5), scores("d", "a", "cfc", 7, 30.0)]  # seed 7 has no static run
    runs += [scores("d", "b", "static", 0, 30.0), scores("d", "b", "mlp", 0, 29.0)]
    margins = scene_margins(runs)
    a = margins[("d", "a")]
    diffs = [mlp[s] - static[s] for s in (0, 1, 2)]
    whole = a.margins[("mlp", "whole")]
    assert whole.mean == pytest.approx(statistics.mean(diffs)) and whole.std == pytest.approx(statistics.stdev(diffs))
    assert a.margins[("mlp", "moving")].mean == pytest.approx(statistics.mean(diffs) + 1)
    assert a.static["whole"].mean == pytest.approx(20.0) and a.static["moving"].mean == pytest.approx(15.0)
    cfc = a.margins[("cfc", "whole")]
    assert cfc.n == 1 and cfc.mean == pytest.approx(0.5) and cfc.std is None
    assert ("cfc", "moving") not in a.margins  # no moving score: no margin, not a zero
    assert a.static_runs["whole"] == [20.0, 21.0, 19.0]
    # the dataset margin: mean of the scene means; spread over the seeds both scenes finished (seed 0 only)
    both = dataset_margin([a, margins[("d", "b")]], "mlp", "whole")
    assert both.mean == pytest.approx((statistics.mean(diffs) - 1.0) / 2) and both.n == 1 and both.std is None
    assert dataset_margin([a, margins[("d", "b")]], "cfc", "whole") is None  # scene b has no cfc


def many_scenes(margin: dict[str, list[float]], static_spread: float = 0.1) -> list:
    """Scenes (name -> the field's margin per seed) over a static model whose PSNR moves by
    +-static_spread between seeds."""
    runs = []
    for name, margins in margin.items():
        for seed, value in enumerate(margins):
            static = 20.0 + static_spread * (-1) ** seed
            runs += [scores("d", name, "static", seed, static), scores("d", name, "mlp", seed, static + value)]
    return list(scene_margins(runs).values())


def test_a_margin_is_called_over_scene_seed_clusters_beyond_two_sigma():
    # one scene of 3 seeds: a 5 dB margin is still too few runs to call (a sign-flip test of 3 cannot)
    (one,) = many_scenes({"a": [5.0, 5.1, 4.9]})
    floor, source = margin_floor([one], "whole")
    sigma = statistics.stdev([20.1, 19.9, 20.1])
    assert floor == pytest.approx(2 * sigma) and "pooled over 1 scenes (3 runs)" in source
    assert verdict(margin_difference([one], "mlp", "whole", floor)) == TOO_FEW
    # two scenes x 3 seeds = 6 clusters: called, on the t-interval of the six margins
    scenes = many_scenes({"a": [1.0, 1.2, 0.9], "b": [1.1, 0.8, 1.0]})
    floor, _ = margin_floor(scenes, "whole")
    both = margin_difference(scenes, "mlp", "whole", floor)
    mean, low, high = t_interval([1.0, 1.2, 0.9, 1.1, 0.8, 1.0])
    assert (both.clusters, both.mean, both.low, both.high) == (6, pytest.approx(mean), pytest.approx(low),
                                                               pytest.approx(high))  # fmt: skip
    assert low > floor and verdict(both) == "gain"
    by_scene = dict(zip("ab", scenes))
    (sentence,) = margin_sentences("d", by_scene, ["mlp"], {"whole": floor}, complete=True)
    assert sentence == (
        f"- d, D-3DGS (MLP) minus static: whole image +0.97 (b) to +1.03 dB (a); per scene {TOO_FEW} "
        f"on every scene; over all 6 scene-seed runs +1.00 dB, t-interval {both.interval_text(2)}: gain."
    )
    # a scene of the dataset missing: no dataset verdict
    (partial,) = margin_sentences("d", by_scene, ["mlp"], {"whole": floor}, complete=False)
    assert "scene-seed runs" not in partial
    # a margin whose interval reaches inside 2 sigma is a tie, however far its mean is from 0
    close = many_scenes({"a": [0.3, 0.1, 0.5], "b": [0.2, 0.4, 0.0]})
    difference = margin_difference(close, "mlp", "whole", margin_floor(close, "whole")[0])
    assert difference.mean == pytest.approx(0.25) and difference.low > 0 and verdict(difference) == "tie"
    lost = many_scenes({"a": [-1.0, -1.2, -0.9], "b": [-1.1, -0.8, -1.0]})
    assert verdict(margin_difference(lost, "mlp", "whole", margin_floor(lost, "whole")[0])) == "loss"
    # one static run per scene: no spread here, so the paper's sigma
    single = many_scenes({"a": [1.0], "b": [1.0]})
    floor, source = margin_floor(single, "whole")
    assert floor == pytest.approx(2 * paper_sigma()[0]) and source.startswith("one static run per scene")


def hand_built_margins(tmp_path: Path) -> Path:
    """dnerf scene hook: static / mlp / cfc x seeds 0-2, results written by hand (no checkpoints)."""
    directory, data = tmp_path / "exp", tmp_path / "data"
    data.mkdir()
    runs = []
    for field, base in (("static", 20.0), ("mlp", 22.0), ("cfc", 20.05)):
        for seed in (0, 1, 2):
            run_dir = f"dnerf/hook/{field}/s{seed}"
            runs.append(RunEntry("dnerf", "hook", field, 0.0, seed, "tiny", str(data), run_dir, None))
            cfg = preset_config("tiny", data)
            cfg.field, cfg.seed = field, seed
            save_yaml(cfg, directory / run_dir / "config.yml")
            score = {"psnr": base + 0.1 * seed, "ssim": 0.9, "lpips": None, "lpips_unavailable": "test"}
            results = {"final": score, "best_of": score, "fps": 1.0, "num_gaussians": 1, "field_parameters": 0,
                       "field_flops_per_gaussian": 0, "train_seconds": 1.0, "peak_memory_mb": 1.0}  # fmt: skip
            (directory / run_dir / "results.json").write_text(json.dumps(results))
    write_manifest(Experiment({"name": "hand"}, str(data), directory, tuple(runs)))
    return directory


def test_the_section_states_each_margin_and_its_verdict(tmp_path):
    collection = collect(hand_built_margins(tmp_path))

    def fake_render(collection, device):
        out = []
        for run in collection.finished:
            whole = run.results["final"]["psnr"]
            foreground = whole - 3 + ((run.entry.field, run.entry.seed) == ("cfc", 1))
            regions = {"whole": whole, "foreground": foreground, "moving": None}
            out.append(RunScores("dnerf", "hook", run.entry.field, run.entry.seed, regions))
        return out, {("dnerf", "hook"): {"whole": 1.0, "foreground": 0.25, "moving": None}}, []

    md, tex = [], []
    margin_section(collection, md, tex, device="cpu", render=fake_render)
    text = "\n".join(md)
    assert "| scene | foreground share | static whole PSNR | static foreground PSNR |" in text
    assert "moving" not in text.split("| scene |")[1].split("\n")[0]  # no moving region on this dataset
    cfc = [0.05, 1.05, 0.05]  # the CfC's foreground margins over the seeds: mean 0.38, std 0.58
    cells = f"+0.05 ± 0.00 | +{statistics.mean(cfc):.2f} ± {statistics.stdev(cfc):.2f}"
    assert f"| hook | 25.0% | 20.10 ± 0.10 | 17.10 ± 0.10 | +2.00 ± 0.00 | +2.00 ± 0.00 | {cells} |" in text
    assert "| mean |" not in text  # one scene: no mean row
    # one scene of 3 seeds: every margin is described, none called
    assert (f"D-3DGS (MLP) minus static: whole image +2.00 dB; per scene {TOO_FEW} on hook; foreground (alpha > 0) "
            f"+2.00 dB; per scene {TOO_FEW} on hook.") in text  # fmt: skip
    assert f"Liquid CfC minus static: whole image +0.05 dB; per scene {TOO_FEW} on hook" in text
    assert "scene-seed runs" not in text  # one scene: no dataset verdict
    assert "Ties floor (2 sigma): whole image 0.200 dB (the static model's spread over seeds, pooled over 1 " in text
    assert "tab:dnerf-margins" in tex[0] and "20.10 $\\pm$ 0.10" in tex[0] and "±" not in tex[0]
    # no static run planned: no section
    md = []
    margin_section(collection.restricted(lambda r: r.field != "static"), md, [], device="cpu", render=fake_render)
    assert md == []


def test_runs_without_a_checkpoint_are_reported_not_fatal(tmp_path):
    text = write_report(hand_built_margins(tmp_path)).read_text()
    assert "## Margin over the static model" in text
    assert "could not be re-rendered" in text
    assert "| hook |" in text.split("## Margin over the static model")[1]


SUBJECT_GAIN = {"a": [1.0, 1.2, 0.9], "b": [1.1, 0.8, 1.0]}
ALIGNED_GAIN = {"a": [0.4, -0.3, 0.2], "b": [-0.2, 0.5, -0.3], "c": [0.5, 0.6, 0.7]}


def refined_clips(tmp_path: Path) -> Path:
    """Scenes a, b, c x seeds 0-2 of static and MLP runs that refined cameras: results.json with
    final_aligned, and eval.json with masked_aligned on a and b (c has no masks); no checkpoints."""
    directory, data = tmp_path / "exp", tmp_path / "data"
    data.mkdir()
    runs = []
    for scene in ("a", "b", "c"):
        for field in ("static", "mlp"):
            for seed in (0, 1, 2):
                run_dir = f"clips/{scene}/{field}/s{seed}"
                runs.append(RunEntry("clips", scene, field, 0.0, seed, "tiny", str(data), run_dir, None))
                cfg = preset_config("tiny", data)
                cfg.field, cfg.seed = field, seed
                save_yaml(cfg, directory / run_dir / "config.yml")
                static = 20.0 + 0.05 * (-1) ** seed
                gain = field == "mlp"
                aligned = static + 3 + (ALIGNED_GAIN[scene][seed] if gain else 0)
                subject = static - 4 + (SUBJECT_GAIN.get(scene, [0] * 3)[seed] if gain else 0)
                score = {"psnr": static, "ssim": 0.9, "lpips": None, "lpips_unavailable": "test"}
                results = {"final": score, "best_of": score, "final_aligned": {"psnr": aligned, "ssim": 0.9},
                           "fps": 1.0, "num_gaussians": 1, "field_parameters": 0, "field_flops_per_gaussian": 0,
                           "train_seconds": 1.0, "peak_memory_mb": 1.0}  # fmt: skip
                (directory / run_dir / "results.json").write_text(json.dumps(results))
                if scene == "c":
                    continue  # no masks
                region = {"psnr": subject, "ssim": 0.8, "share": 0.125}
                masked = {"inside": region, "outside": {**region, "share": 0.875}}
                (directory / run_dir / "eval.json").write_text(json.dumps({"masked_aligned": masked}))
    write_manifest(Experiment({"name": "refined"}, str(data), directory, tuple(runs)))
    return directory


def test_runs_that_refine_add_their_aligned_and_subject_scores_in_columns_of_their_own(tmp_path):
    """Three scenes x 3 seeds of static and MLP runs that recorded final_aligned (results.json), two
    of them also `eval --mask`'s masked_aligned (eval.json; the third has no masks, as a clip where
    nothing moves): the section gives the margin on each, its own floor (the static model's spread
    of that score) and the verdict over the scene-seed runs that have the score, whatever the
    renders could not give."""
    directory = refined_clips(tmp_path)
    md, tex = [], []
    margin_section(collect(directory), md, tex, device="cpu")
    text = "\n".join(md)
    lines = text.splitlines()
    header = next(line for line in lines if line.startswith("| scene |"))
    assert "| subject share |" in header and "| static aligned PSNR | static subject PSNR |" in header
    assert "D-3DGS (MLP) - static, aligned | D-3DGS (MLP) - static, subject |" in header
    assert next(line for line in lines if line.startswith("| a |")).startswith("| a | 12.5% |")
    floor = 2 * statistics.stdev([20.05, 19.95, 20.05])  # the static model's spread, the same on every score
    sentence = next(line for line in lines if line.startswith("- clips, D-3DGS (MLP) minus static"))
    mean, low, high = t_interval([m for scene in "ab" for m in SUBJECT_GAIN[scene]])
    assert low > floor
    assert (f"inside the masks (eval --mask) with test cameras aligned +0.97 (b) to +1.03 dB (a); per scene "
            f"{TOO_FEW} on every scene; over all 6 scene-seed runs +1.00 dB, t-interval [{low:+.2f}, {high:+.2f}]: "
            "gain") in sentence  # fmt: skip
    mean, low, high = t_interval([m for scene in "abc" for m in ALIGNED_GAIN[scene]])
    assert low < floor
    aligned = (
        f"whole image with test cameras aligned +0.00 (b) to +0.60 dB (c); per scene {TOO_FEW} on every "
        f"scene; over all 9 scene-seed runs {mean:+.2f} dB, t-interval [{low:+.2f}, {high:+.2f}]: tie"
    )
    assert aligned in sentence
    mean_row = next(line for line in lines if line.startswith("| mean |")).split(" | ")
    assert mean_row[1] == "-" and mean_row[-1] == "+1.00 ± 0.05 |"  # the subject's mean over the scenes with masks
    assert next(line for line in lines if line.startswith("| c |")).startswith("| c | - |")
    assert f"inside the masks (eval --mask) with test cameras aligned {floor:.3f} dB" in text
    assert "could not be re-rendered" in text  # no checkpoints: the rendered regions are missing, said so


def test_a_malformed_eval_json_is_one_line_naming_it(tmp_path, capsys):
    directory = refined_clips(tmp_path)
    broken = directory / "clips" / "b" / "mlp" / "s1" / "eval.json"
    broken.write_text(json.dumps({"masked_aligned": {"inside": {"psnr": 20.0}}}))
    assert cli(["experiment", "report", str(directory)]) == 2
    error = f"liquidgs experiment: error: {broken}: field 'masked_aligned"
    assert one_line_error(capsys) == f"{error}' must be an object with inside, outside"
    broken.write_text(json.dumps({"masked_aligned": {"inside": {"psnr": 20.0}, "outside": {"psnr": "?", "share": 1}}}))
    assert cli(["experiment", "report", str(directory)]) == 2
    assert one_line_error(capsys) == f"{error}.inside' must be an object with numbers psnr (or null), share"
    assert not (directory / "report" / "report.md").exists()


def test_a_run_whose_masks_leave_a_region_empty_is_n_a_in_its_columns_not_a_refusal(tmp_path, capsys):
    """eval.json written before such mask sets were refused: a region's psnr null. The report is written;
    that run's cells say n/a, with a note saying why, and the margins use the runs that have the score."""
    directory = refined_clips(tmp_path)
    empty = directory / "clips" / "b" / "mlp" / "s1" / "eval.json"
    record = json.loads(empty.read_text())
    record["masked_aligned"]["inside"].update(psnr=None, ssim=None, share=0.0)
    record["masked"] = {**record["masked_aligned"], "outside": {"psnr": 31.5, "ssim": 0.9, "share": 1.0}}
    empty.write_text(json.dumps(record))
    assert cli(["experiment", "report", str(directory)]) == 0
    text = (directory / "report" / "report.md").read_text()
    assert ("clips-b-mlp-s1: its masks hold no subject pixel in any test view (eval.json's masked_aligned.inside.psnr "
            "is null); its subject score is n/a") in text  # fmt: skip
    row = next(line for line in text.splitlines() if line.startswith("| clips / b | D-3DGS (MLP) | 1 |"))
    outside = 20.0 - 0.05 - 4 + SUBJECT_GAIN["b"][1]  # as refined_clips writes it, seed 1
    assert row.endswith(f"| n/a | 31.50 | n/a | {outside:.2f} |"), row
    assert "n/a: the run's masks leave that region without a pixel in every test view" in text


# ----------------------------------------------------------------------------- the spec and a real run
def test_margins_spec_trains_static_and_two_fields_over_three_seeds(tmp_path):
    spec = load_spec("margins")
    assert [g.dataset for g in spec.grids] == ["dnerf", "synthetic"]
    for grid in spec.grids:
        assert grid.fields == ("static", "mlp", "cfc") and grid.seeds == (0, 1, 2) and grid.preset == "tiny"
        assert {k: v for k, v in grid.overrides.items() if k != "downscale"} == MINI_SCHEDULE
    assert spec.grids[0].scenes == SHARED_DNERF_SCENES and spec.grids[0].overrides["downscale"] == 8
    experiment = expand(spec, require_shared(DNERF_ROOT), tmp_path / "margins")
    assert len(experiment.runs) == (4 + 2) * 3 * 3
    cells = {(r.dataset, r.scene, r.field): set() for r in experiment.runs}
    for run in experiment.runs:
        cells[(run.dataset, run.scene, run.field)].add(run.seed)
    assert all(seeds == {0, 1, 2} for seeds in cells.values())
    assert {s for d, s, _ in cells if d == "synthetic"} == {"puppet-64px", "spinner-64px"}
    static = [r for r in experiment.runs if r.field == "static"]
    assert len(static) == 18 and all(r.train_config().field == "static" for r in static)


def test_a_static_and_field_grid_runs_and_reports_its_margins(tmp_path):
    """A built-in scene at 16 px, static and MLP, 2 seeds of 16 iterations: the report scores the moving pixels."""
    fast = {"iterations": 16, "warmup": 4, "init_points": 200, "checkpoint_every": 8,
            "eval": {"start": 16, "fps_frames": 2}}  # fmt: skip
    spec = spec_from_dict({"name": "m", "dataset": "synthetic", "preset": "tiny", "scenes": ["synthetic:puppet:16"],
                           "fields": ["static", "mlp"], "seeds": [0, 1], "overrides": fast}, "test")  # fmt: skip
    directory = tmp_path / "exp"
    experiment = expand(spec, tmp_path, directory)
    write_manifest(experiment)
    generate_scenes(experiment)
    for run in experiment.runs:  # in this process: a subprocess each would spend longer importing torch
        assert train_main(train_command(run, directory)[4:]) == 0
    text = write_report(tmp_path / "exp").read_text()
    section = text.split("## Margin over the static model")[1].split("\n## ")[0]
    assert "| scene | foreground share | moving share | static whole PSNR |" in section
    row = next(line for line in section.splitlines() if line.startswith("| puppet-16px |"))
    assert row.count("±") == 3 + 3  # static whole / foreground / moving, and the MLP's margins on the three
    assert "D-3DGS (MLP) minus static: whole image" in section and "moving pixels" in section
    assert "reproduces its results.json whole-image PSNR" in section
