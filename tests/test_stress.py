"""Stress tests: perturbed training data, every noise variant through `liquidgs train`, the
stress specs, and the significance code of the 'does noise help?' report."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from scipy import stats

from liquidgs.cli import main as cli_main
from liquidgs.data import DataConfig, PerturbConfig, load_dataset, perturb_dataset
from liquidgs.data.perturb import NoisyFrame
from liquidgs.errors import ConfigError
from liquidgs.experiments import BUILTIN_SPECS, expand, generate_scenes, spec_from_dict
from liquidgs.experiments.report.collect import collect
from liquidgs.experiments.report.significance import MIN_CLUSTERS, TOO_FEW, paired_difference, smallest_sign_flip_p
from liquidgs.experiments.report.stress import Comparison, compare, verdict_sentence
from liquidgs.experiments.spec import load_spec
from liquidgs.train.config import (
    TrainConfig,
    config_hash,
    identity,
    legacy_config_hash,
    legacy_identity,
    load_yaml,
    preset_config,
)
from shared_data import DNERF_ROOT, require_shared
from tiny_runs import tiny_flags

# 12 iterations: these runs check what is recorded, not what is learnt.
FAST = tiny_flags({"iterations": 12, "eval.start": 12})


@pytest.fixture(scope="session")
def scene(puppet_scene) -> Path:
    return puppet_scene


@pytest.fixture(scope="module")
def dataset(scene):
    return load_dataset(DataConfig(path=scene))


def many_frames(dataset, copies: int):
    """The scene's training frames repeated, at mid-range times, for sample statistics."""
    frames = [f for f in dataset.train for _ in range(copies)]
    return [type(f)(**{**f.__dict__, "time": 0.5}) for f in frames]


def with_train(dataset, frames):
    import dataclasses

    return dataclasses.replace(dataset, splits={**dataset.splits, "train": frames})


# ------------------------------------------------------------------ perturbations


def test_time_jitter_has_the_asked_standard_deviation(dataset):
    big = with_train(dataset, many_frames(dataset, 300))
    jittered = perturb_dataset(big, PerturbConfig(time_jitter=0.05), seed=1)
    shifts = np.array([f.time - 0.5 for f in jittered.train])
    assert len(shifts) > 2000
    assert abs(shifts.std(ddof=1) - 0.05) < 0.004 and abs(shifts.mean()) < 0.004
    clipped = perturb_dataset(dataset, PerturbConfig(time_jitter=5.0), seed=1)
    assert all(0.0 <= f.time <= 1.0 for f in clipped.train)


def rotation_angle_deg(a: torch.Tensor, b: torch.Tensor) -> float:
    relative = (a[:3, :3].double() @ b[:3, :3].double().T).numpy()
    return math.degrees(math.acos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)))


def test_rotation_angles_follow_the_asked_distribution(dataset):
    big = with_train(dataset, many_frames(dataset, 200))
    moved = perturb_dataset(big, PerturbConfig(pose_rot_deg=2.0), seed=4)
    angles = np.array([rotation_angle_deg(m.camera.viewmat, f.camera.viewmat) for m, f in zip(moved.train, big.train)])
    # |N(0, R^2)|: RMS R, mean R * sqrt(2 / pi).
    assert abs(math.sqrt((angles**2).mean()) - 2.0) < 0.1
    assert abs(angles.mean() - 2.0 * math.sqrt(2 / math.pi)) < 0.1
    # Rotation about the camera centre: the centre stays put.
    for m, f in zip(moved.train[:20], big.train[:20]):
        assert torch.allclose(m.camera.centre, f.camera.centre, atol=1e-4)


def test_translation_has_the_asked_rms_length(dataset):
    big = with_train(dataset, many_frames(dataset, 200))
    moved = perturb_dataset(big, PerturbConfig(pose_trans=0.1), seed=2)
    shifts = torch.stack([m.camera.centre - f.camera.centre for m, f in zip(moved.train, big.train)]).double()
    rms = float(shifts.norm(dim=1).pow(2).mean().sqrt())
    assert abs(rms / (0.1 * big.camera_extent) - 1.0) < 0.05


def test_time_split_boundary_is_exactly_t0(dataset):
    times = sorted({f.time for f in dataset.train + dataset.test})
    t0 = next(t for t in times if t > 0.5)  # a frame sits exactly on the boundary
    split = perturb_dataset(dataset, PerturbConfig(time_split=t0), seed=0)
    assert split.train and split.test
    assert all(f.time < t0 for f in split.train)
    assert all(f.time >= t0 for f in split.test)
    assert len(split.train) == sum(f.time < t0 for f in dataset.train)
    assert len(split.test) == sum(f.time >= t0 for f in dataset.test)


def test_keep_frames_keeps_evenly_spaced_frames(dataset):
    kept = perturb_dataset(dataset, PerturbConfig(keep_frames=3), seed=0).train
    times = sorted(f.time for f in dataset.train)
    middle = round((len(times) - 1) / 2)
    assert sorted(f.time for f in kept) == [times[0], times[middle], times[-1]]
    every = perturb_dataset(dataset, PerturbConfig(keep_frames=len(times)), seed=0).train
    assert [(f.name, f.time, f.image_path) for f in every] == [(f.name, f.time, f.image_path) for f in dataset.train]
    assert all(torch.equal(a.camera.viewmat, b.camera.viewmat) for a, b in zip(every, dataset.train))
    with pytest.raises(ConfigError, match="perturb.keep-frames 999"):
        perturb_dataset(dataset, PerturbConfig(keep_frames=999), seed=0)


def test_image_noise_is_fixed_per_frame_and_has_the_asked_std(dataset):
    noisy = perturb_dataset(dataset, PerturbConfig(image_noise=0.05), seed=3)
    frame, clean = noisy.train[0], dataset.train[0]
    assert isinstance(frame, NoisyFrame)
    assert torch.equal(frame.image(), frame.image())  # the same corruption on every read
    residual = (frame.image() - clean.image()).flatten()
    inside = ((clean.image() > 0.2) & (clean.image() < 0.8)).flatten()  # away from the clip at 0 and 1
    assert abs(float(residual[inside].std()) - 0.05) < 0.01


def test_test_views_are_untouched_and_the_same_seed_gives_the_same_perturbation(dataset):
    cfg = PerturbConfig(time_jitter=0.02, pose_rot_deg=1.0, pose_trans=0.01, image_noise=0.02)
    a, b = perturb_dataset(dataset, cfg, seed=7), perturb_dataset(dataset, cfg, seed=7)
    other = perturb_dataset(dataset, cfg, seed=8)
    assert a.test == dataset.test and all(type(f) is not NoisyFrame for f in a.test)
    for fa, fb in zip(a.train, b.train):
        assert fa.time == fb.time and torch.equal(fa.camera.viewmat, fb.camera.viewmat)
        assert torch.equal(fa.image(), fb.image())
    assert any(fa.time != fo.time for fa, fo in zip(a.train, other.train))
    assert perturb_dataset(dataset, PerturbConfig(), seed=7) is dataset


@pytest.mark.parametrize(
    ("flag", "value", "message"),
    [
        ("--perturb.time-jitter", "-0.1", "perturb.time-jitter must be a finite number >= 0"),
        ("--perturb.pose-rot-deg", "nan", "perturb.pose-rot-deg must be a finite number >= 0"),
        ("--perturb.image-noise", "-1", "perturb.image-noise"),
        ("--perturb.time-split", "1.0", "perturb.time-split must be a number in (0, 1)"),
        ("--perturb.time-split", "0", "perturb.time-split must be a number in (0, 1)"),
        ("--perturb.keep-frames", "0", "perturb.keep-frames must be an integer >= 1"),
    ],
)
def test_bad_perturbations_are_one_line_errors(scene, tmp_path, capsys, flag, value, message):
    code = cli_main(["train", "--data", str(scene), "--out", str(tmp_path / "r"), *FAST, flag, value])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists()


def test_an_unperturbed_config_has_the_version_1_identity_of_before_perturbations(scene):
    clean = preset_config("tiny", scene)
    assert "perturb" not in legacy_identity(clean)
    assert legacy_identity(clean)["field_options"]["name"] == "mlp"  # the hashed placeholder of version 1
    perturbed = preset_config("tiny", scene)
    perturbed.perturb.time_jitter = 0.01
    assert identity(perturbed)["perturb"]["time_jitter"] == 0.01
    assert config_hash(perturbed) != config_hash(clean)


def test_a_config_yml_of_an_older_version_still_loads(tmp_path, scene):
    cfg = preset_config("tiny", scene)
    raw = yaml.safe_load(yaml.safe_dump(json.loads(json.dumps(legacy_identity(cfg)))))
    raw["field_options"].update(name="cfc", preset="dnerf", lambda_=None)  # an old file had them, any value
    (tmp_path / "config.yml").write_text(yaml.safe_dump(raw))
    loaded = load_yaml(tmp_path / "config.yml")
    assert legacy_config_hash(loaded) == legacy_config_hash(cfg) and config_hash(loaded) == config_hash(cfg)


def test_perturbation_is_recorded_and_resume_keeps_it(scene, tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "--data", str(scene), "--out", str(out), *FAST, "--perturb.time-jitter", "0.03",
            "--perturb.time-split", "0.6"]  # fmt: skip
    assert cli_main(argv) == 0
    stored = load_yaml(out / "config.yml")
    assert stored.perturb == PerturbConfig(time_jitter=0.03, time_split=0.6)
    results = json.loads((out / "results.json").read_text())
    assert results["perturb"] == {"time_jitter": 0.03, "time_split": 0.6}
    split = perturb_dataset(load_dataset(DataConfig(path=scene)), stored.perturb, stored.seed)
    assert results["views"] == {"train": len(split.train), "test": len(split.test)}
    views = json.loads((out / "per_view.json").read_text())["views"]
    assert len(views) == len(split.test)

    # Extend it: the stored perturbation comes back; asking for another is refused.
    assert cli_main(["train", "--out", str(out), "--resume", "--iterations", "14"]) == 0
    assert load_yaml(out / "config.yml").perturb == stored.perturb
    assert json.loads((out / "results.json").read_text())["perturb"] == results["perturb"]
    code = cli_main(["train", "--out", str(out), "--resume", "--iterations", "16", "--perturb.time-jitter", "0.1"])
    assert code == 2 and "perturb.time_jitter" in capsys.readouterr().err


# ------------------------------------------------------------------ noise variants from the command line


@pytest.mark.parametrize(
    "options",
    [
        ["--field-options.noise", "ou"],
        ["--field-options.noise", "solver"],
        ["--field-options.noise", "ou", "--field-options.ltc-leak", "0.5"],
        ["--field-options.adaptive-lambda"],
        ["--field-options.lambda-schedule", "linear", "--field-options.lambda-decay-steps", "10"],
        ["--field-options.lambda-schedule", "cosine", "--field-options.lambda-decay-steps", "10"],
    ],
    ids=["ou", "solver", "ou-leak", "adaptive", "linear", "cosine"],
)
def test_every_noise_variant_trains_through_the_cli(scene, tmp_path, options):
    out = tmp_path / "run"
    argv = ["train", "--data", str(scene), "--out", str(out), *FAST, "--field", "sde", "--lambda", "0.1", *options]
    assert cli_main(argv) == 0
    field = load_yaml(out / "config.yml").field_config()
    flags = dict(zip(options[::2], options[1::2])) if len(options) > 1 else {}
    assert field.name == "sde" and field.lambda_ == 0.1
    if "--field-options.noise" in flags:
        assert field.noise == flags["--field-options.noise"]
    if "--field-options.lambda-schedule" in flags:
        assert field.lambda_schedule == flags["--field-options.lambda-schedule"]
    if options == ["--field-options.adaptive-lambda"]:
        assert field.adaptive_lambda
    assert math.isfinite(json.loads((out / "results.json").read_text())["final"]["psnr"])


def test_a_noise_variant_on_a_deterministic_field_is_one_line(scene, tmp_path, capsys):
    argv = ["train", "--data", str(scene), "--out", str(tmp_path / "r"), "--field", "cfc"]
    argv += ["--field-options.noise", "ou"]
    assert cli_main(argv) == 2
    assert "apply to the 'sde' field only, not to 'cfc'" in capsys.readouterr().err


def test_field_options_have_no_name_preset_or_lambda_of_their_own():
    names = set(TrainConfig.__dataclass_fields__["field_options"].default_factory().__dataclass_fields__)
    assert not names & {"name", "preset", "lambda_"}


# ------------------------------------------------------------------ specs


def test_stress_specs_expand_with_named_runs(tmp_path):
    root = require_shared(DNERF_ROOT / "hellwarrior").parent
    experiment = expand(BUILTIN_SPECS["stress-mini"], root, tmp_path / "e")
    assert len(experiment.runs) == sum(g.run_count() for g in BUILTIN_SPECS["stress-mini"].grids) == 64
    names = {r.name for r in experiment.runs}
    assert "synthetic-puppet-64px-sde-ou-time-jitter0.1-s1" in names
    assert "dnerf-hellwarrior-cfc-s0" in names and len(names) == 64
    assert {r.perturb for r in experiment.runs} == {"", "time_jitter", "time_split"}
    (scene_spec, folder), = experiment.synthetic_scenes
    assert scene_spec.size == 64 and folder == (tmp_path / "e" / "scenes" / "puppet-64px").resolve()
    assert not (tmp_path / "e").exists()  # planning writes nothing


def test_a_yaml_stress_spec_runs_variants_and_perturbations_on_a_synthetic_scene(tmp_path):
    spec = spec_from_dict(
        {
            "name": "s",
            "preset": "tiny",
            "scenes": ["synthetic:spinner:16"],
            "variants": {
                "cfc": {"field": "cfc"},
                "sde-annealed": {"field": "sde", "lambda": 0.1, "overrides": {
                    "field_options": {"lambda_schedule": "linear", "lambda_decay_steps": 8}}},
            },
            "perturb": {"time-jitter": [0, 0.05], "keep_frames": [0, 4]},
            "seeds": [0],
            "overrides": {"iterations": 8, "warmup": 2, "init_points": 200, "eval": {"start": 8, "fps_frames": 1}},
        },
        "s.yml",
    )  # fmt: skip
    experiment = expand(spec, tmp_path, tmp_path / "e")
    conditions = ("", "-time-jitter0.05", "-keep-frames4")
    assert [r.name for r in experiment.runs] == [
        f"tiny-spinner-16px-{v}{c}-s0" for v in ("cfc", "sde-annealed") for c in conditions
    ]
    assert experiment.runs[2].train_config().perturb.keep_frames == 4
    assert generate_scenes(experiment) == [(tmp_path / "e" / "scenes" / "spinner-16px").resolve()]
    assert generate_scenes(experiment) == []  # once
    assert (Path(experiment.runs[0].data) / "transforms_train.json").is_file()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ({"variants": {"x": {"field": "nerf"}}}, "variants.x.field': unknown field 'nerf'"),
        ({"variants": {"x": {"field": "sde", "lam": 1}}}, "unknown key 'lam'"),
        ({"variants": {"x": {"field": "sde"}}, "fields": ["mlp"]}, "either 'variants' or 'fields'"),
        ({"perturb": {"blur": [0, 1]}}, "unknown perturbation 'blur'"),
        ({"perturb": {"time_jitter": [-1]}}, "'perturb.time_jitter' must hold finite numbers >= 0"),
        ({"perturb": {"keep_frames": [2.5]}}, "'perturb.keep_frames' must hold whole numbers"),
        ({"scenes": ["synthetic:teapot:32"]}, "synthetic:NAME:SIZE"),
    ],
)
def test_bad_stress_specs_are_one_line_errors(extra, message):
    raw = {"name": "x", "preset": "tiny", "scenes": ["a"], **({"fields": ["cfc"]} if "variants" not in extra else {})}
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        spec_from_dict({**raw, **extra}, "x.yml")


# ------------------------------------------------------------------ significance

# The four (scene, seed) cluster means of OU noise minus the CfC at the 0.75 time split on an
# AVX-512 machine (issue 22): a percentile bootstrap called it 'hurts' with [-1.391, -0.308].
OU_CLUSTER_MEANS = [-0.20, -0.57, -0.76, -1.54]


def spread_clusters(means, views: int = 20, seed: int = 0) -> list[np.ndarray]:
    """One array of per-view differences per cluster, with exactly the given cluster means."""
    rng = np.random.default_rng(seed)
    out = []
    for mean in means:
        noise = rng.normal(0.0, 0.3, views)
        out.append(mean + noise - noise.mean())
    return out


def test_the_interval_is_the_t_interval_on_the_cluster_means():
    d = paired_difference(spread_clusters(OU_CLUSTER_MEANS))
    mean, s, n = np.mean(OU_CLUSTER_MEANS), np.std(OU_CLUSTER_MEANS, ddof=1), len(OU_CLUSTER_MEANS)
    low, high = stats.t.interval(0.95, n - 1, loc=mean, scale=s / math.sqrt(n))
    assert d.low <= low + 1e-12 and d.high >= high - 1e-12  # at least as wide as the t-interval
    assert (round(d.low, 2), round(d.high, 2)) == (-1.67, 0.13)  # the interval the issue computed
    assert d.clusters == 4 and d.pairs == 80 and d.mean == pytest.approx(mean)
    # The views of a cluster share its runs' training: more views, or tighter views, change nothing.
    tight = paired_difference(spread_clusters(OU_CLUSTER_MEANS, views=500, seed=1))
    assert (tight.low, tight.high) == pytest.approx((d.low, d.high))


def test_below_the_minimum_number_of_clusters_nothing_is_called():
    # The sign-flip bound behind the minimum: 5 clusters cannot reach p < 0.05, 6 can.
    assert smallest_sign_flip_p(MIN_CLUSTERS - 1) >= 0.05 > smallest_sign_flip_p(MIN_CLUSTERS)
    for n in range(1, MIN_CLUSTERS):
        huge = paired_difference(spread_clusters([5.0 + 0.01 * k for k in range(n)]))
        assert huge.verdict == TOO_FEW, n
    assert paired_difference(spread_clusters(OU_CLUSTER_MEANS)).verdict == TOO_FEW
    one = paired_difference([np.array([1.0, 2.0])])
    assert math.isnan(one.low) and one.interval_text() == "-" and one.verdict == TOO_FEW
    ou = paired_difference(spread_clusters(OU_CLUSTER_MEANS))
    sentence = verdict_sentence("time_split", [Comparison("sde-ou", 0.75, ou)])
    assert sentence == ("time split: too few runs to call: every comparison rests on 4 scene-seed clusters, "
                        "fewer than the 6 a verdict needs.")  # fmt: skip


def test_a_clear_gain_is_significant_and_its_interval_holds_the_truth():
    rng = np.random.default_rng(0)
    clusters = [1.0 + rng.normal(0.0, 0.2, 20) for _ in range(MIN_CLUSTERS)]
    d = paired_difference(clusters)
    assert d.verdict == "helps" and d.low < 1.0 < d.high and d.pairs == 120 and d.clusters == MIN_CLUSTERS
    assert paired_difference([-c for c in clusters]).verdict == "hurts"


def test_no_difference_is_a_tie():
    d = paired_difference(spread_clusters([-0.3, 0.3, -0.1, 0.1, -0.2, 0.2]))
    assert d.mean == pytest.approx(0.0) and d.low < 0 < d.high and d.verdict == "tie"


def test_a_gain_in_one_run_only_is_not_significant():
    # Views of a run are correlated: one run far ahead is no evidence, however many views it has.
    d = paired_difference([np.full(30, 2.0) + np.linspace(-0.01, 0.01, 30)] + [np.full(30, 0.01)] * 5)
    assert d.verdict == "tie"


def test_a_difference_is_called_only_when_its_interval_clears_the_ties_floor():
    # Every cluster +0.05 dB: the interval excludes 0, but not the floor of 2 sigma = 0.1 dB.
    clusters = spread_clusters([0.05, 0.04, 0.06, 0.05, 0.045, 0.055])
    assert paired_difference(clusters).verdict == "helps"
    assert paired_difference(clusters, floor=0.1).verdict == "tie"
    assert paired_difference([-c for c in clusters], floor=0.1).verdict == "tie"
    assert paired_difference([c + 0.2 for c in clusters], floor=0.1).verdict == "helps"
    assert paired_difference([-c - 0.2 for c in clusters], floor=0.1).verdict == "hurts"
    # A mean above the floor is not enough: the interval reaches below it.
    wide = paired_difference(spread_clusters([0.05, 0.3, 0.1, 0.25, 0.15, 0.2]), floor=0.1)
    assert wide.mean > 0.1 and 0 < wide.low < 0.1 and wide.verdict == "tie"


def test_the_sentence_names_where_noise_helps_hurts_and_ties():
    help_ = paired_difference(spread_clusters([0.5, 0.45, 0.55, 0.5, 0.52, 0.48]))
    hurt = paired_difference(spread_clusters([-0.4, -0.35, -0.45, -0.4, -0.42, -0.38]))
    tie = paired_difference(spread_clusters([-1.0, 1.0, 0.5, -0.5, 0.2, -0.2]))
    few = paired_difference(spread_clusters([1.0, 1.1]))
    sentence = verdict_sentence("time_jitter", [Comparison("sde-ou", 0.1, help_), Comparison("sde-l0.1", 0.0, hurt),
                                                Comparison("x", 0.03, tie), Comparison("y", 0.03, few)])  # fmt: skip
    assert "noise helps: sde-ou at 0.1 (+0.5" in sentence and "it hurts: sde-l0.1 at 0 (-0.4" in sentence
    assert "1 of 3 comparisons are ties" in sentence
    assert "1 more rest on fewer than 6 scene-seed clusters: too few runs to call" in sentence


STRESS_VARIANTS = (("cfc", "cfc", 0.0), ("sde-l0.1", "sde", 0.1), ("sde-ou", "sde", 0.1))


def hand_built_stress(directory: Path, scenes, seeds, psnr_of) -> Path:
    """A stress experiment written by hand: STRESS_VARIANTS x (clean, time jitter 0.1) x scenes x seeds,
    per-view PSNRs from psnr_of(scene, variant, perturb, seed) -> list of view PSNRs."""
    from liquidgs.experiments import Experiment, RunEntry, write_manifest
    from liquidgs.train.config import save_yaml

    data = directory.parent / "data"
    data.mkdir(exist_ok=True)
    runs = []
    for scene in scenes:
        for variant, field, lam in STRESS_VARIANTS:
            for perturb, strength in (("", 0.0), ("time_jitter", 0.1)):
                for seed in seeds:
                    run_dir = f"dnerf/{scene}/{variant}/{perturb}{strength}-s{seed}"
                    runs.append(RunEntry("dnerf", scene, field, lam, seed, "tiny", str(data), run_dir, None, variant,
                                         perturb, strength))  # fmt: skip
                    cfg = preset_config("tiny", data)
                    cfg.field, cfg.seed, cfg.lambda_ = field, seed, (lam if field == "sde" else None)
                    save_yaml(cfg, directory / run_dir / "config.yml")
                    psnrs = psnr_of(scene, variant, perturb, seed)
                    views = [{"name": f"v{i}", "psnr": float(p)} for i, p in enumerate(psnrs)]
                    scores = {"psnr": float(np.mean(psnrs)), "ssim": 0.9, "lpips": None}
                    results = {"final": scores, "best_of": scores, "fps": 10.0, "num_gaussians": 100,
                               "field_parameters": 10, "field_flops_per_gaussian": 10, "train_seconds": 1.0,
                               "peak_memory_mb": 1.0, "peak_memory_kind": "process_peak_rss",
                               "device": "cpu"}  # fmt: skip
                    (directory / run_dir / "results.json").write_text(json.dumps(results))
                    (directory / run_dir / "per_view.json").write_text(json.dumps({"iteration": 1, "views": views}))
    write_manifest(Experiment({"name": "stress-hand"}, str(data), directory, tuple(runs)))
    return directory


def test_the_report_answers_does_noise_help_on_hand_built_runs(tmp_path):
    from liquidgs.experiments.report import write_report

    def psnr_of(scene, variant, perturb, seed):
        # sde-ou gains 1 dB on every view under jitter, nothing (+-0.2 per view) when clean; sde-l0.1 ties
        gain = 1.0 if (variant == "sde-ou" and perturb) else 0.0
        wobble = [0.2, -0.2, 0.1, -0.1] if variant != "cfc" else [0.0] * 4
        return [25.0 + 0.3 * seed + (scene == "lego") - 0.2 * bool(perturb) + gain + w for w in wobble]

    directory = hand_built_stress(tmp_path / "exp", ("hook", "lego"), (0, 1, 2), psnr_of)
    text = write_report(directory).read_text()
    assert (directory / "report" / "stress_time_jitter.png").is_file()
    assert "| sde-ou | 0.1 | +1.000 | [+1.000, +1.000] | 6 (24 views) | **helps** |" in text
    assert "| sde-ou | 0 | +0.000 |" in text and "| sde-l0.1 | 0.1 | +0.000 |" in text
    assert ("time jitter: noise helps: sde-ou at 0.1 (+1.00 dB); it hurts nowhere; 3 of 4 comparisons are ties"
            in text)  # fmt: skip
    assert "sigma = 0.300 dB: the cfc's seed-to-seed PSNR spread, pooled over 4 cells of 12 runs, measured here" in text

    few = hand_built_stress(tmp_path / "few", ("hook",), (0, 1, 2), psnr_of)
    text = write_report(few).read_text()
    assert "| sde-ou | 0.1 | +1.000 | [+1.000, +1.000] | 3 (12 views) | too few runs to call |" in text
    assert "time jitter: too few runs to call: every comparison rests on 3 scene-seed clusters" in text
    assert "noise helps" not in text


# A change of machine (issue 22: AVX-512 for AVX2) moved 4-cluster means by 0.03-0.13 dB: as much
# as a change of seed, because float rounding sends training elsewhere. So the second machine here
# re-draws every run's run-to-run part (the worst case): a run's offset (0.09 dB std, stress-mini's
# seed spread), the OU runs' extra spread, and the views' noise. The effects stay: the size
# stress-mini measured (docs/results/stress.md), constant noise +0.03 dB, OU noise -0.5 dB.
RUN_DB, VIEW_DB = 0.09, 0.05
EFFECTS = {"cfc": (0.0, 0.0), "sde-l0.1": (0.03, 0.0), "sde-ou": (-0.5, 0.2)}


def stress_psnrs(machine: int):
    """per-view PSNRs: scene structure, the variant's effect, and the run-to-run part drawn per machine."""

    def psnr_of(scene, variant, perturb, seed):
        run = np.random.default_rng([sum(map(ord, scene)), sum(map(ord, variant)), len(perturb), seed, machine])
        effect, extra = EFFECTS[variant]
        views = 24.0 + np.linspace(-1, 1, 12) - 0.1 * bool(perturb) + effect
        return views + run.normal(0, RUN_DB) + run.normal(0, extra) + run.normal(0, VIEW_DB, 12)

    return psnr_of


def verdict_column(text: str) -> list[tuple[str, str, str]]:
    rows = re.findall(r"^\| (sde-\S+) \| (\S+) \| \S+ \| [^|]+ \| [^|]+ \| ([^|]+) \|$", text, re.M)
    return [(v, s, verdict.strip()) for v, s, verdict in rows]


@pytest.mark.slow
@pytest.mark.parametrize(("scenes", "seeds"), [(("hook", "lego"), tuple(range(8))), (("hook", "lego"), (0, 1))],
                         ids=["16-clusters", "4-clusters"])  # fmt: skip
def test_verdicts_survive_a_change_of_machine(tmp_path, scenes, seeds):
    from liquidgs.experiments.report import write_report

    texts = [write_report(hand_built_stress(tmp_path / f"m{m}", scenes, seeds, stress_psnrs(m))).read_text()
             for m in (0, 1)]  # fmt: skip
    verdicts = [verdict_column(t) for t in texts]
    assert len(verdicts[0]) == 4 and verdicts[0] == verdicts[1]
    called = {(v, s): verdict for v, s, verdict in verdicts[0]}
    if len(seeds) * len(scenes) >= MIN_CLUSTERS:
        assert called == {("sde-l0.1", "0"): "tie", ("sde-ou", "0"): "**hurts**", ("sde-l0.1", "0.1"): "tie",
                          ("sde-ou", "0.1"): "**hurts**"}  # fmt: skip
        # Without the floor (a verdict wherever the interval excludes 0) the same runs flip: the
        # constant noise's +0.03 dB 'helps' under jitter 0.1 on one machine and ties on the other.
        plain = [[c.difference.verdict for c in compare(collect(tmp_path / f"m{m}"), "time_jitter")] for m in (0, 1)]
        assert plain[0] != plain[1]
    else:
        assert set(called.values()) == {TOO_FEW}


def test_the_stress_24_spec_is_stress_mini_with_24_clusters():
    """docs/experiments/stress-24.yml: stress-mini's grids with seeds 0-11, so every comparison rests
    on 2 scenes x 12 seeds = 24 clusters (the size docs/experiments/verdict_stability.py asks for)."""
    spec = load_spec(str(Path(__file__).resolve().parents[1] / "docs" / "experiments" / "stress-24.yml"))
    mini = BUILTIN_SPECS["stress-mini"]
    assert spec.name == "stress-24"
    assert spec.grids == tuple(dataclasses.replace(g, seeds=tuple(range(12))) for g in mini.grids)
    clusters = sum(len(g.scenes) * len(g.seeds) for g in spec.grids)
    assert clusters == 24 and sum(g.run_count() for g in spec.grids) == 384
