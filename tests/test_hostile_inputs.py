"""Every command, every numeric or path setting, hostile values: exit 2, one line, nothing written.

Run in-process through liquidgs.cli.main; each case fails during argument, config or data
validation, before any training. The working directory is a temporary folder so that a
default output path would show up as a leftover.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from liquidgs.cli import main as cli
from tiny_runs import run_train, snapshot, tiny_flags

# 10 iterations: these runs are refused before training, or trained only to be read.
TINY = [*tiny_flags({"iterations": 10, "eval.start": 10}), "--eval.lpips-weights", "/nonexistent-lpips-weights"]


@pytest.fixture(scope="module")
def world(tmp_path_factory, puppet_scene) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("hostile")
    scene = puppet_scene
    run = root / "run"
    run_train(["--data", str(scene), "--field", "mlp", "--out", str(run), *TINY])
    a_file = root / "a_file.txt"
    a_file.write_text("not a folder")
    return {"scene": scene, "run": run, "file": a_file, "missing": root / "missing"}


def train_case(*flags: str, message: str = "") -> tuple:
    return (["train", "--data", "{scene}", "--field", "mlp", "--out", "{work}/out", *TINY, *flags], message)


def run_case(command: str, *flags: str, message: str = "") -> tuple:
    return ([command, "--run", "{run}", *flags], message)


CASES = {
    # train: numbers
    "iterations zero": train_case("--iterations", "0", message="iterations must be an integer between 1"),
    "iterations negative": train_case("--iterations", "-5", message="iterations"),
    "iterations huge": train_case("--iterations", "99999999999", message="iterations"),
    "iterations NaN": train_case("--iterations", "nan", message="--iterations"),
    "iterations wrong type": train_case("--iterations", "lots", message="--iterations"),
    "seed negative": train_case("--seed", "-1", message="seed must be an integer >= 0"),
    "seed huge": train_case("--seed", str(2**70), message="seed"),
    "checkpoint-every zero": train_case("--checkpoint-every", "0", message="checkpoint-every"),
    "eval.every zero": train_case("--eval.every", "0", message="eval.every"),
    "eval.fps-frames zero": train_case("--eval.fps-frames", "0", message="eval.fps-frames"),
    "sh-interval zero": train_case("--sh-interval", "0", message="sh-interval"),
    "sh-degree huge": train_case("--sh-degree", "7", message="sh-degree"),
    "densify.interval zero": train_case("--densify.interval", "0", message="densify.interval"),
    "opacity reset zero": train_case("--densify.opacity-reset-interval", "0", message="opacity-reset-interval"),
    "init-points zero": train_case("--init-points", "0", message="init-points"),
    "init-points huge": train_case("--init-points", "1000000000", message="init-points"),
    "init-extent zero": train_case("--init-extent", "0", message="init-extent"),
    "init-extent inf": train_case("--init-extent", "inf", message="init-extent"),
    "ssim-weight NaN": train_case("--ssim-weight", "nan", message="ssim-weight"),
    "ssim-weight 2": train_case("--ssim-weight", "2", message="ssim-weight"),
    "lambda NaN": (["train", "--data", "{scene}", "--field", "sde", "--lambda", "nan", *TINY], "lambda"),
    "lambda negative": (["train", "--data", "{scene}", "--field", "sde", "--lambda", "-1", *TINY], "lambda"),
    "field lr inf": train_case("--optim.field-lr-init", "inf", message="optim.field-lr-init"),
    "adam eps zero": train_case("--optim.adam-eps", "0", message="optim.adam-eps"),
    "reset opacity 1": train_case("--densify.reset-opacity-to", "1", message="reset-opacity-to"),
    "downscale zero": train_case("--downscale", "0", message="downscale"),
    "downscale huge": train_case("--downscale", "100000", message="larger than the images"),
    "field cells zero": train_case("--field-options.mlp-depth", "0", message="mlp_depth"),
    "unknown device": train_case("--device", "tpu9", message="unknown device 'tpu9'"),
    "unknown flag": train_case("--iterationz", "3", message="--iterationz"),
    # train: paths
    "data is a file": (["train", "--data", "{file}", "--out", "{work}/out", *TINY], "is a file, not a dataset folder"),
    "data missing": (["train", "--data", "{missing}", "--out", "{work}/out", *TINY], "dataset folder not found"),
    "out is a file": (["train", "--data", "{scene}", "--out", "{file}", *TINY], "is a file, not a folder"),
    "out under a file": (["train", "--data", "{scene}", "--out", "{file}/run", *TINY], "Not a directory"),
    "resume without out": (["train", "--resume"], "--resume needs --out"),
    "resume a missing run": (["train", "--resume", "--out", "{missing}"], "no run to resume"),
    "resume a file": (["train", "--resume", "--out", "{file}"], "no run to resume"),
    "resume goes back": (["train", "--resume", "--out", "{run}", "--iterations", "5"], "would go back"),
    # eval / render / export
    "eval run missing": (["eval", "--run", "{missing}"], "does not exist"),
    "eval run is a file": (["eval", "--run", "{file}"], "is a file, not a run folder"),
    "eval bad split": run_case("eval", "--split", "nope", message="--split: unknown split 'nope' (choose from"),
    "eval bad device": run_case("eval", "--device", "tpu9", message="unknown device"),
    "render sweep zero": run_case("render", "--sweep-frames", "0", message="--sweep-frames must be between 1"),
    "render orbit zero": run_case("render", "--orbit-frames", "0", message="--orbit-frames"),
    "render orbit huge": run_case("render", "--orbit-frames", "10000000", message="--orbit-frames"),
    "render fps zero": run_case("render", "--fps", "0", message="--fps must be between 1 and 240"),
    "render fps negative": run_case("render", "--fps", "-3", message="--fps"),
    "render fps wrong type": run_case("render", "--fps", "fast", message="--fps"),
    "render orbit-time NaN": run_case("render", "--orbit-time", "nan", message="--orbit-time"),
    "render one MC sample": run_case("render", "--uncertainty-samples", "1", message="--uncertainty-samples"),
    "render sweep camera": run_case("render", "--sweep-camera", "-1", message="--sweep-camera"),
    "render run missing": (["render", "--run", "{missing}"], "does not exist"),
    "export time NaN": run_case("export", "--time", "nan", message="--time nan"),
    "export time inf": run_case("export", "--time", "inf", message="--time inf"),
    "export times collide": run_case("export", "--time", "0.00001", "0.00002", message="would both be written"),
    "export sequence negative": run_case("export", "--sequence", "-1", message="--sequence"),
    "export sequence huge": run_case("export", "--sequence", "1000000000", message="--sequence"),
    "export run is a file": (["export", "--run", "{file}"], "is a file"),
    # data
    "data no subcommand": (["data"], "choose a subcommand"),
    "data bad subcommand": (["data", "fly"], "choose a subcommand"),
    "synth size zero": (["data", "synth", "--scene", "puppet", "--out", "{work}/s", "--size", "0"], "--size"),
    "synth size huge": (["data", "synth", "--scene", "puppet", "--out", "{work}/s", "--size", "99999"], "--size"),
    "synth frames negative": (["data", "synth", "--scene", "puppet", "--out", "{work}/s", "--frames", "-1"], "frames"),
    "synth seed negative": (["data", "synth", "--scene", "puppet", "--out", "{work}/s", "--seed", "-1"], "--seed"),
    "synth out under a file": (["data", "synth", "--scene", "puppet", "--out", "{file}/s", "--size", "8",
                               "--frames", "8"], "Not a directory"),  # fmt: skip
    "check a file": (["data", "check", "{file}"], "is a file, not a dataset folder"),
    "check missing": (["data", "check", "{missing}"], "dataset folder not found"),
    "check downscale zero": (["data", "check", "{scene}", "--downscale", "0"], "downscale"),
    "check bad format": (["data", "check", "{scene}", "--format", "ply"], "--format: unknown format 'ply'"),
    # bench
    "bench raster bad case": (["bench", "raster", "--cases", "big"], "WIDTHxHEIGHT/N"),
    "bench raster zero case": (["bench", "raster", "--cases", "0x0/0"], "between 1 and"),
    "bench raster repeats zero": (["bench", "raster", "--repeats", "0"], "repeats >= 1"),
    "bench raster wrong type": (["bench", "raster", "--repeats", "many"], "--repeats"),
    "bench raster bad device": (["bench", "raster", "--device", "tpu9"], "unknown device"),
    "bench fields sizes zero": (["bench", "fields", "--sizes", "0"], "sizes"),
    "bench fields NaN seconds": (["bench", "fields", "--max-seconds", "nan"], "--max-seconds"),
    "bench fields bad field": (["bench", "fields", "--fields", "nerf"], "unknown field"),
    "bench fields bad device": (["bench", "fields", "--device", "tpu9"], "unknown device"),
    # experiment
    "experiment no action": (["experiment"], "usage: liquidgs experiment"),
    "experiment bad action": (["experiment", "fly"], "unknown experiment action 'fly'"),
    "experiment unknown spec": (["experiment", "run", "nope", "--data-root", "{work}"], "not a built-in spec"),
    "experiment spec is a folder": (["experiment", "run", "{work}", "--data-root", "{work}"], "no such spec file"),
    "experiment data root missing": (["experiment", "run", "mini", "--data-root", "{missing}"], "is not a folder"),
    "experiment data root a file": (["experiment", "run", "mini", "--data-root", "{file}"], "is not a folder"),
    "experiment scene missing": (["experiment", "run", "mini", "--data-root", "{work}"], "'scenes' names"),
    "experiment parallel zero": (["experiment", "run", "mini", "--data-root", "{work}", "--parallel", "0"],
                                 "--parallel must be >= 1"),  # fmt: skip
    "experiment bad executor": (["experiment", "run", "mini", "--data-root", "{work}", "--executor", "slurm"],
                                "--executor"),  # fmt: skip
    "experiment report not one": (["experiment", "report", "{run}"], "not an experiment folder"),
    "experiment report bad eval": (["experiment", "report", "{work}", "--eval", "best"], "--eval"),
    # demo
    "demo iterations zero": (["demo", "--out", "{work}/demo", "--iterations", "0"], "iterations"),
    "demo size zero": (["demo", "--out", "{work}/demo", "--size", "0"], "--size"),
    "demo seed negative": (["demo", "--out", "{work}/demo", "--seed", "-1"], "seed"),
    "demo bad scene": (["demo", "--out", "{work}/demo", "--scene", "teapot"], "unknown synthetic scene"),
}


def assert_one_line_exit_2(argv: list[str], capsys, message: str = "") -> str:
    assert cli(argv) == 2, argv
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert message in err, err
    return err


@pytest.mark.parametrize("case", list(CASES), ids=list(CASES))
def test_hostile_input_is_one_line_exit_2_and_writes_nothing(case, world, tmp_path, capsys, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)  # a default output folder would appear here
    argv, message = CASES[case]
    argv = [a.format(work=work, **world) for a in argv]
    watched = (work, world["run"], world["scene"])
    before = snapshot(*watched)
    assert_one_line_exit_2(argv, capsys, message)
    assert snapshot(*watched) == before, "nothing may be written"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\x89\xff\x00\xfe garbage \x01\x02", "unreadable run config"),
        (None, "setting 'iterations' must be an integer, got 'lots'"),
        (b"- just\n- a list\n", "not a liquidgs run config"),
    ],
    ids=["binary", "iterations lots", "a list"],
)
def test_a_damaged_config_yml_on_resume_and_eval(world, tmp_path, capsys, content, message):
    run = tmp_path / "run"
    shutil.copytree(world["run"], run)
    config = run / "config.yml"
    lots = config.read_bytes().replace(b"iterations: 10", b"iterations: lots")
    config.write_bytes(content if content is not None else lots)
    before = snapshot(run)
    for argv in (["train", "--out", str(run), "--resume"], ["eval", "--run", str(run)]):
        assert_one_line_exit_2(argv, capsys, message)
    assert snapshot(run) == before


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    flag=st.sampled_from(["--iterations", "--checkpoint-every", "--eval.every", "--eval.fps-frames", "--sh-interval",
                          "--densify.interval", "--init-points", "--seed", "--warmup"]),  # fmt: skip
    value=st.one_of(
        st.integers(max_value=-1),
        st.integers(min_value=2**63),
        st.sampled_from(["nan", "inf", "-inf", "1e3", "0x10", "", "1.5", "ten"]),
    ),
)
def test_generated_bad_integer_settings(world, tmp_path, capsys, flag, value):
    out = tmp_path / "generated"
    argv = ["train", "--data", str(world["scene"]), "--out", str(out), *TINY, flag, str(value)]
    assert_one_line_exit_2(argv, capsys)
    assert not out.exists()


@pytest.mark.parametrize("config, setting, positive", [
    ("perturb", "pose_rot_deg", False),
    ("cameras", "rotation_lr", True),
    ("motion", "rigidity", False),
    ("exposure", "max_change", True),
])  # fmt: skip
@pytest.mark.parametrize("value", [True, float("nan"), float("inf"), -1.0, 0.0, "1"])
def test_every_capture_weight_and_rate_refuses_what_is_not_a_number_in_range(config, setting, positive, value):
    """One rule for every such setting (errors.check_number): a bool, nan, inf, a negative number,
    zero where the setting divides or scales, or text is one line naming the setting."""
    from liquidgs.data.perturb import PerturbConfig
    from liquidgs.errors import ConfigError
    from liquidgs.train.camera_opt import CameraRefineConfig
    from liquidgs.train.exposure import ExposureConfig
    from liquidgs.train.motion_reg import MotionRegConfig

    cls = {"perturb": PerturbConfig, "cameras": CameraRefineConfig, "motion": MotionRegConfig,
           "exposure": ExposureConfig}[config]  # fmt: skip
    if value == 0.0 and not positive:
        assert getattr(cls(**{setting: value}), setting) == 0.0  # zero is a valid weight or noise level
        return
    name = f"{config}.{setting if config == 'motion' else setting.replace('_', '-')}"
    with pytest.raises(ConfigError) as refused:
        cls(**{setting: value})
    assert str(refused.value) == f"{name} must be a finite number {'> 0' if positive else '>= 0'}, got {value!r}"
