"""Experiment specs, grid expansion and the runner (local subprocesses and Ray)."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from liquidgs.cli import main as cli_main
from liquidgs.data import generate_synthetic
from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.experiments import BUILTIN_SPECS, expand, load_spec, read_manifest, spec_from_dict, write_manifest
from liquidgs.experiments.report import write_report
from liquidgs.experiments.runner import run_experiment
from liquidgs.experiments.spec import DNERF_SCENES, NERFDS_SCENES
from liquidgs.train.config import load_yaml
from shared_data import DNERF_ROOT, require_shared
from tiny_runs import run_cli, tiny_overrides

# A run of a few seconds: 32 px, a few hundred Gaussians, an evaluation at the end only; two
# frames timed, which a test finds in the run's config.yml.
FAST = tiny_overrides({"iterations": 16, "checkpoint_every": 8, "eval.start": 16, "eval.fps_frames": 2})


@pytest.fixture(scope="module")
def data_root(tmp_path_factory) -> Path:
    """Two built-in scenes in the D-NeRF layout, as <root>/<scene>."""
    root = tmp_path_factory.mktemp("scenes")
    for scene in ("puppet", "spinner"):
        generated = generate_synthetic(scene, root / f".gen-{scene}", size=32, frames=12, seed=3)
        shutil.move(str(generated / "dnerf"), str(root / scene))
        shutil.rmtree(generated)
    return root


def small_spec(name="grid", **extra) -> dict:
    return {
        "name": name,
        "preset": "tiny",
        "scenes": ["puppet", "spinner"],
        "fields": ["mlp", "sde"],
        "lambdas": [0.05],
        "seeds": [0],
        "overrides": FAST,
        **extra,
    }


def write_spec(path: Path, spec: dict) -> Path:
    path.write_text(yaml.safe_dump(spec))
    return path


# ----------------------------------------------------------------------------- specs
def test_builtin_specs_match_the_paper_grids():
    dnerf = BUILTIN_SPECS["paper-dnerf"].grids[0]
    assert len(dnerf.scenes) == 8 and dnerf.fields == ("mlp", "cfc", "sde") and dnerf.seeds == (0,)
    assert dnerf.preset == "dnerf" and dnerf.lambdas == (0.05,) and "downscale" not in dnerf.overrides
    assert BUILTIN_SPECS["paper-dnerf-3seeds"].grids[0].seeds == (0, 1, 2)
    assert len(BUILTIN_SPECS["paper-nerfds"].grids[0].scenes) == 7
    assert BUILTIN_SPECS["paper-nerfds-3seeds"].grids[0].seeds == (0, 1, 2)
    noise = BUILTIN_SPECS["noise-study"]
    assert {g.dataset for g in noise.grids} == {"dnerf", "nerfds"}
    assert all(g.fields == ("sde",) and g.lambdas == (0.0, 0.05, 0.1, 0.2) for g in noise.grids)
    seeds = BUILTIN_SPECS["seeds"].grids[0]
    assert seeds.scenes == ("hellwarrior",) and seeds.lambdas == (0.0,) and seeds.seeds == (0, 1, 2)
    # LPIPS as the D-3DGS metrics code computes it ([0,1] inputs, not normalised), in every paper spec.
    for name in ("paper-dnerf", "paper-dnerf-3seeds", "paper-nerfds", "paper-nerfds-3seeds", "noise-study", "seeds"):
        assert all(g.overrides["eval.lpips_normalize"] is False for g in BUILTIN_SPECS[name].grids), name


def test_paper_tables_and_noise_study_lambda_0_05_are_the_same_runs(tmp_path):
    """Same configuration, same run folder: paper-dnerf's SDE-LNN runs are noise-study's lambda 0.05 row."""
    root = tmp_path / "data"
    for dataset, scenes in (("dnerf", DNERF_SCENES), ("nerfds", NERFDS_SCENES)):
        for scene in scenes:
            (root / dataset / scene).mkdir(parents=True)
    noise = expand(BUILTIN_SPECS["noise-study"], root, tmp_path / "exp" / "noise-study")
    for dataset in ("dnerf", "nerfds"):
        paper = expand(BUILTIN_SPECS[f"paper-{dataset}"], root / dataset, tmp_path / "exp" / f"paper-{dataset}")
        paper_sde = {r.run_dir for r in paper.runs if r.field == "sde"}
        noise_005 = {r.run_dir for r in noise.runs if r.dataset == dataset and r.lambda_ == 0.05}
        assert len(paper_sde) == len(paper.runs) // 3 and paper_sde == noise_005
        spread = expand(BUILTIN_SPECS[f"paper-{dataset}-3seeds"], root / dataset, tmp_path / "exp" / "s")
        assert {r.run_dir for r in paper.runs} < {r.run_dir for r in spread.runs}  # seed 0 shared too


def test_noise_studys_lambda_0_row_is_the_cfc_runs_trained_once(tmp_path, capsys):
    """The SDE at lambda 0 is the CfC bit for bit: noise-study plans its lambda 0 row as paper-dnerf's and
    paper-nerfds' CfC runs, so with those finished its dry run has 15 runs fewer to train."""
    root = tmp_path / "data"
    for dataset, scenes in (("dnerf", DNERF_SCENES), ("nerfds", NERFDS_SCENES)):
        for scene in scenes:
            (root / dataset / scene).mkdir(parents=True)
    noise = expand(BUILTIN_SPECS["noise-study"], root, tmp_path / "exp" / "noise-study")
    zero = [r for r in noise.runs if r.lambda_ == 0]
    assert len(zero) == 15 and all(r.field == "sde" and r.trained_field == "cfc" for r in zero)
    for dataset in ("dnerf", "nerfds"):
        paper = expand(BUILTIN_SPECS[f"paper-{dataset}"], root / dataset, tmp_path / "exp" / f"paper-{dataset}")
        cfc = [r for r in paper.runs if r.field == "cfc"]
        assert {r.run_dir for r in cfc} == {r.run_dir for r in zero if r.dataset == dataset}
        for run in cfc:  # finished, as far as sharing is concerned
            run.folder(paper.directory).mkdir(parents=True)
            (run.folder(paper.directory) / "results.json").write_text("{}")
    out_dir = tmp_path / "exp" / "noise-study"
    args = ["experiment", "run", "noise-study", "--data-root", str(root), "--out", str(out_dir)]
    assert cli_main([*args, "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "60 runs (0 done, 15 finished in another experiment, to be shared)" in out
    assert "GPU-time estimate for the 45 runs to train" in out


@pytest.mark.slow
def test_an_sde_row_at_lambda_0_beside_the_cfc_row_is_trained_once(data_root, tmp_path, capsys):
    spec = write_spec(tmp_path / "s.yml", small_spec("twins", scenes=["puppet"], fields=["cfc", "sde"],
                                                     lambdas=[0.0, 0.05]))  # fmt: skip
    args = ["experiment", "run", str(spec), "--data-root", str(data_root), "--out", str(tmp_path / "e")]
    assert cli_main([*args, "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "3 runs (0 done, 1 the same run as another row (SDE at lambda 0 = CfC), trained once)" in out
    assert "GPU-time estimate for the 2 runs to train" in out
    assert "twin    the same run as tiny-puppet-cfc-s0 (trained once)" in out
    # run: one training for the two rows, each row with its outcome, the report reading both
    pair = expand(spec_from_dict(small_spec("pair", scenes=["puppet"], fields=["cfc", "sde"], lambdas=[0.0]), "t"),
                  data_root, tmp_path / "pair")  # fmt: skip
    write_manifest(pair)
    outcomes = {o.name: o for o in run_experiment(pair, parallel=1)}
    assert [o.status for o in outcomes.values()] == ["done", "done"]
    assert outcomes["tiny-puppet-sde-l0-s0"].message == "the same run as tiny-puppet-cfc-s0: trained once"
    assert len(list((tmp_path / "pair").rglob("results.json"))) == 1
    assert "2 of 2 planned runs finished" in write_report(tmp_path / "pair").read_text()
    # a setting only the sde field takes keeps lambda 0 an sde run of its own
    ou = spec_from_dict(small_spec("ou", scenes=["puppet"], fields=["sde"], lambdas=[0.0],
                                   overrides={**FAST, "field_options.noise": "ou"}), "t")  # fmt: skip
    [run] = expand(ou, data_root, tmp_path / "ou").runs
    assert run.trained_field == "sde" and "/sde/" in run.run_dir


@pytest.mark.slow
def test_a_run_finished_in_a_sibling_experiment_is_shared_not_retrained(data_root, tmp_path, capsys):
    experiments = tmp_path / "experiments"
    first = expand(spec_from_dict(small_spec("first", scenes=["puppet"]), "t"), data_root, experiments / "first")
    write_manifest(first)
    assert all(o.status == "done" for o in run_experiment(first, parallel=2))
    second_spec = small_spec("second", scenes=["puppet"], lambdas=[0.05, 0.1])
    spec_path = write_spec(tmp_path / "second.yml", second_spec)
    args = ["experiment", "run", str(spec_path), "--data-root", str(data_root), "--out", str(experiments / "second")]
    assert cli_main([*args, "--dry-run"]) == 0
    listing = capsys.readouterr().out
    assert "3 runs (0 done, 2 finished in another experiment, to be shared)" in listing
    assert listing.count(" shared ") == 2 and not (experiments / "second").exists()  # the dry run wrote nothing
    assert cli_main(args) == 0
    err = capsys.readouterr().err
    assert "done 1, skipped 2 (finished before)" in err and err.count("finished in first/") == 2
    second = read_manifest(experiments / "second")
    for run in second.runs:
        folder = run.folder(second.directory)
        assert folder.is_symlink() == (run.lambda_ != 0.1) and (folder / "results.json").is_file()
    report = write_report(experiments / "second").read_text()
    assert "3 finished runs" in report, report[:600]  # the two shared runs are read with the new one
    mini = BUILTIN_SPECS["mini"].grids[0]
    assert mini.preset == "tiny" and mini.overrides["downscale"] == 8 and len(mini.scenes) == 4


def test_yaml_spec_is_read_with_defaults(tmp_path):
    raw = {"name": "g", "preset": "tiny", "scenes": "hook", "fields": ["mlp"]}
    spec = load_spec(write_spec(tmp_path / "s.yml", raw))
    grid = spec.grids[0]
    assert spec.name == "g" and grid.scenes == ("hook",) and grid.seeds == (0,) and grid.lambdas == (0.05,)
    assert grid.dataset == "tiny"


def test_nested_overrides_are_flattened_and_grids_inherit_top_level_keys():
    spec = spec_from_dict(
        {
            "name": "two",
            "fields": ["sde"],
            "lambdas": [0.0, 0.1],
            "overrides": {"eval": {"every": 50}, "field-options": {"noise": "ou"}},
            "grids": [
                {"dataset": "dnerf", "preset": "tiny", "scenes": ["a"]},
                {"dataset": "nerfds", "preset": "nerfds", "scenes": ["b"], "seeds": [1, 2]},
            ],
        },
        "two.yml",
    )
    assert [g.dataset for g in spec.grids] == ["dnerf", "nerfds"]
    assert spec.grids[0].overrides == {"eval.every": 50, "field_options.noise": "ou"}
    assert spec.grids[1].seeds == (1, 2) and spec.grids[1].lambdas == (0.0, 0.1)


@pytest.mark.parametrize(
    ("raw", "expected"),
    [
        ([1, 2], "is a mapping"),
        ({"preset": "tiny", "scenes": ["a"], "fields": ["mlp"]}, "'name'"),
        ({"name": "x", "scenes": ["a"], "fields": ["mlp"]}, "missing key 'preset'"),
        ({"name": "x", "preset": "huge", "scenes": ["a"], "fields": ["mlp"]}, "'preset' is 'huge'"),
        ({"name": "x", "preset": "tiny", "scenes": ["a"], "fields": ["mlp", "nerf"]}, "unknown field 'nerf'"),
        ({"name": "x", "preset": "tiny", "scenes": [], "fields": ["mlp"]}, "'scenes' is empty"),
        ({"name": "x", "preset": "tiny", "scenes": ["a"], "fields": ["sde"], "lambdas": [-0.1]}, "'lambdas'"),
        ({"name": "x", "preset": "tiny", "scenes": ["a"], "fields": ["sde"], "lambdas": ["lots"]}, "'lambdas'"),
        ({"name": "x", "preset": "tiny", "scenes": ["a"], "fields": ["mlp"], "seeds": [-1]}, "'seeds'"),
        ({"name": "x", "preset": "tiny", "scenes": ["a"], "fields": ["mlp"], "seeds": [0.5]}, "'seeds'"),
        ({"name": "x", "preset": "tiny", "scenes": ["a"], "fields": ["mlp"], "overrides": [1]}, "'overrides'"),
        ({"name": "x", "preset": "tiny", "scenes": ["a"], "fields": ["mlp"], "sceens": ["b"]}, "unknown key 'sceens'"),
        ({"name": "../x", "preset": "tiny", "scenes": ["a"], "fields": ["mlp"]}, "'name'"),
        ({"name": "x", "grids": []}, "'grids'"),
        ({"name": "x", "grids": [{"preset": "tiny", "scenes": ["a"], "fields": ["mlp"], "seed": 1}]}, "grids[0]"),
    ],
)
def test_bad_specs_fail_with_one_line_naming_the_key(raw, expected):
    with pytest.raises(ConfigError) as err:
        spec_from_dict(raw, "bad.yml")
    message = str(err.value)
    assert expected in message and message.startswith("bad.yml") and "\n" not in message


def test_spec_file_errors(tmp_path):
    with pytest.raises(ConfigError, match="no such spec file, and not a built-in spec"):
        load_spec(tmp_path / "missing.yml")
    garbage = tmp_path / "garbage.yml"
    garbage.write_bytes(b"\xff\xfe\x00 : : [")
    with pytest.raises(ConfigError, match="garbage.yml: unreadable spec"):
        load_spec(garbage)


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        ({"iterations": "lots"}, "overrides.iterations"),
        ({"eval.bogus": 3}, "overrides.eval.bogus"),
        ({"iterations": 0}, "overrides.iterations=0: .*iterations must be an integer between 1"),
        ({"preset_typo": 1}, "overrides.preset_typo"),
    ],
)
def test_bad_overrides_fail_before_anything_runs(data_root, tmp_path, overrides, key):
    spec = spec_from_dict(small_spec(overrides=overrides), "s.yml")
    with pytest.raises(ConfigError, match=key):
        expand(spec, data_root, tmp_path / "exp")
    assert not (tmp_path / "exp").exists()


def test_a_missing_scene_is_named(data_root, tmp_path):
    spec = spec_from_dict(small_spec(scenes=["puppet", "trex"]), "s.yml")
    with pytest.raises(ConfigError, match="'scenes' names 'trex'"):
        expand(spec, data_root, tmp_path / "exp")


# ----------------------------------------------------------------------------- expansion
def test_grid_expansion_counts_and_folders(data_root, tmp_path):
    spec = spec_from_dict(small_spec(fields=["mlp", "cfc", "sde"], lambdas=[0.0, 0.1], seeds=[0, 1]), "s.yml")
    experiment = expand(spec, data_root, tmp_path / "exp")
    # 2 scenes x (mlp + cfc + sde at 2 lambdas) x 2 seeds
    assert len(experiment.runs) == 2 * 4 * 2
    folders = [r.run_dir for r in experiment.runs]
    # sde at lambda 0 is the CfC bit for bit: its rows are the cfc rows' folders (plan.cfc_twin)
    assert len(set(folders)) == 2 * 3 * 2
    twins = {r.run_dir for r in experiment.runs if r.field == "sde" and r.lambda_ == 0}
    assert twins == {r.run_dir for r in experiment.runs if r.field == "cfc"}
    again = expand(spec, data_root, tmp_path / "exp")
    assert [r.run_dir for r in again.runs] == folders
    sde = [r for r in experiment.runs if r.field == "sde"]
    assert sorted({r.lambda_ for r in sde}) == [0.0, 0.1]
    assert all(r.lambda_ == 0.0 for r in experiment.runs if r.field != "sde")
    first = experiment.runs[0]
    assert first.run_dir.startswith("tiny/puppet/mlp/") and first.train_config().iterations == FAST["iterations"]
    write_manifest(experiment)
    assert read_manifest(tmp_path / "exp").runs == experiment.runs


@pytest.mark.slow  # a training process of its own
def test_the_run_folder_holds_the_config_the_spec_asked_for(data_root, tmp_path):
    spec = spec_from_dict(small_spec(scenes=["puppet"], fields=["sde"], lambdas=[0.1]), "s.yml")
    experiment = expand(spec, data_root, tmp_path / "exp")
    assert run_experiment(experiment)[0].status == "done"
    cfg = load_yaml(experiment.runs[0].folder(experiment.directory) / "config.yml")
    assert cfg.field == "sde" and cfg.lambda_ == 0.1 and cfg.iterations == 16 and cfg.eval.fps_frames == 2
    assert cfg.init_points == 300 and cfg.preset == "tiny"


def test_manifest_errors(tmp_path):
    with pytest.raises(LiquidGSError, match="not an experiment folder"):
        read_manifest(tmp_path)
    (tmp_path / "experiment.json").write_text("{broken")
    with pytest.raises(LiquidGSError, match="experiment.json: unreadable experiment manifest"):
        read_manifest(tmp_path)


# ----------------------------------------------------------------------------- the command
def test_dry_run_lists_runs_and_writes_nothing(data_root, tmp_path):
    spec = write_spec(tmp_path / "s.yml", small_spec())
    code, out, _ = run_cli(
        ["experiment", "run", str(spec), "--data-root", str(data_root), "--out", str(tmp_path / "e"), "--dry-run"]
    )
    assert code == 0 and "4 runs (0 done)" in out and out.count("to run") == 4
    assert not (tmp_path / "e").exists()


def test_bad_spec_on_the_command_line_is_one_line(data_root, tmp_path):
    spec = write_spec(tmp_path / "s.yml", small_spec(fields=["mlp", "nope"]))
    code, _, err = run_cli(["experiment", "run", str(spec), "--data-root", str(data_root)])
    assert code == 2 and err.strip().count("\n") == 0 and "unknown field 'nope'" in err


@pytest.mark.slow
def test_run_skip_done_and_keep_going_after_a_failure(data_root, tmp_path):
    broken_root = tmp_path / "data"
    shutil.copytree(data_root, broken_root)
    (broken_root / "spinner" / "transforms_train.json").write_text("{not json")
    # The broken scene first and one run at a time: the run after the failure still trains.
    spec = write_spec(tmp_path / "s.yml", small_spec(scenes=["spinner", "puppet"], fields=["mlp"]))
    argv = ["experiment", "run", str(spec), "--data-root", str(broken_root), "--out", str(tmp_path / "e"),
            "--parallel", "1"]  # fmt: skip

    code, _, err = run_cli(argv)
    assert code == 1
    assert "done 1, skipped 0 (finished before), failed 1" in err
    # Into a log, a plain line per finished run names it and its outcome.
    outcomes = re.findall(r"^\S+: (\d)/2 runs  (done|failed): (\S+)  elapsed \d+:\d\d:\d\d  ETA ", err, re.M)
    assert outcomes == [("1", "failed", "tiny-spinner-mlp-s0"), ("2", "done", "tiny-puppet-mlp-s0")], err
    assert "transforms_train.json" in err
    experiment = read_manifest(tmp_path / "e")
    done = {r.scene for r in experiment.runs if r.is_done(experiment.directory)}
    assert done == {"puppet"}

    # Mend the data: the second run trains only what failed, and skips what is done.
    shutil.copy(data_root / "spinner" / "transforms_train.json", broken_root / "spinner" / "transforms_train.json")
    code, _, err = run_cli(argv)
    assert code == 0 and "done 1, skipped 1 (finished before), failed 0" in err
    for run in experiment.runs:
        log = (tmp_path / "e" / "logs" / f"{run.name}.log").read_text()
        assert log.count("$ ") == (2 if run.scene == "spinner" else 1)
    # A third run trains nothing.
    code, _, err = run_cli(argv)
    assert code == 0 and "done 0, skipped 2" in err


@pytest.mark.slow
def test_an_interrupted_grid_resumes_and_trains_every_run_once(data_root, tmp_path):
    spec = small_spec(  # two runs: one finished, the next in flight when the driver is killed
        fields=["mlp"], overrides=tiny_overrides({"iterations": 60, "checkpoint_every": 5, "eval.start": 60})
    )
    spec_file = write_spec(tmp_path / "s.yml", spec)
    out = tmp_path / "e"
    command = [sys.executable, "-m", "liquidgs.cli", "experiment", "run", str(spec_file),
               "--data-root", str(data_root), "--out", str(out)]  # fmt: skip
    driver = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 120
    try:
        while time.time() < deadline and not list(out.glob("*/*/*/*/results.json")):
            assert driver.poll() is None, "the experiment ended before it could be interrupted"
            time.sleep(0.05)
    finally:
        os.killpg(driver.pid, signal.SIGKILL)  # the driver and the training it started
        driver.wait()
    finished_first = {p.parent for p in out.glob("*/*/*/*/results.json")}
    assert len(finished_first) >= 1

    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    experiment = read_manifest(out)
    assert all(r.is_done(out) for r in experiment.runs)
    assert f"skipped {len(finished_first)} (finished before)" in result.stderr
    for run in experiment.runs:
        log = (out / "logs" / f"{run.name}.log").read_text()
        launches = log.count("$ ")
        if run.folder(out) in finished_first:
            assert launches == 1  # not trained twice
        results = json.loads((run.folder(out) / "results.json").read_text())
        assert results["final"]["iteration"] == 60
    interrupted = [r for r in experiment.runs if "--resume" in (out / "logs" / f"{r.name}.log").read_text()]
    assert len(interrupted) <= 1  # at most the run that was in flight was resumed
    report = write_report(out).read_text()
    n = len(experiment.runs)
    assert f"{n} of {n} planned runs finished" in report and "None: every planned run finished." in report


def test_parallel_must_be_positive(data_root, tmp_path):
    experiment = expand(spec_from_dict(small_spec(), "s.yml"), data_root, tmp_path / "e")
    with pytest.raises(ConfigError, match="--parallel must be >= 1"):
        run_experiment(experiment, parallel=-1)
    with pytest.raises(ConfigError, match="unknown executor"):
        run_experiment(experiment, executor="slurm")


# ----------------------------------------------------------------------------- Ray
@pytest.mark.slow
def test_ray_executor_runs_every_run_once_and_survives_a_killed_worker(data_root, tmp_path):
    spec = small_spec(
        fields=["mlp"], overrides=tiny_overrides({"iterations": 100, "checkpoint_every": 10, "eval.start": 100})
    )
    experiment = expand(spec_from_dict(spec, "s.yml"), data_root, tmp_path / "e")
    write_manifest(experiment)
    victim = experiment.runs[0].folder(experiment.directory)

    import threading

    killed = []
    experiment_over = threading.Event()

    def kill_worker_after_first_checkpoint():
        # No deadline of its own: on a loaded machine Ray and the first checkpoint can take minutes;
        # the window (checkpoint at step 10, results after step 100) stays open until the run ends.
        while not killed and not experiment_over.is_set():
            if (victim / "checkpoint.pt").is_file() and not (victim / "results.json").is_file():
                for proc in Path("/proc").iterdir():
                    try:
                        cmdline = (proc / "cmdline").read_bytes().split(b"\0")
                    except OSError:
                        continue
                    if str(victim).encode() in cmdline and b"train" in cmdline:
                        ppid = int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
                        os.kill(ppid, signal.SIGKILL)  # the Ray worker running the task
                        killed.append(ppid)
                        return
            time.sleep(0.02)

    watcher = threading.Thread(target=kill_worker_after_first_checkpoint)
    watcher.start()
    try:
        outcomes = run_experiment(experiment, executor="ray", parallel=2)
    finally:
        experiment_over.set()
        watcher.join()
    assert killed, "the test never caught the run between its first checkpoint and its end"
    assert sorted(o.name for o in outcomes) == sorted(r.name for r in experiment.runs)
    assert all(o.status == "done" for o in outcomes), [o.message for o in outcomes]
    log = (tmp_path / "e" / "logs" / f"{experiment.runs[0].name}.log").read_text()
    launches = [line for line in log.splitlines() if line.startswith("$ ")]
    assert len(launches) == 2 and launches[1].endswith("--resume")  # the retry resumed the checkpoint
    assert json.loads((victim / "results.json").read_text())["final"]["iteration"] == 100


def test_ray_missing_is_one_clear_line(monkeypatch, data_root, tmp_path):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    experiment = expand(spec_from_dict(small_spec(), "s.yml"), data_root, tmp_path / "e")
    with pytest.raises(ConfigError, match=re.escape("pip install ray (or, in the clone, pip install -e '.[ray]')")):
        run_experiment(experiment, executor="ray")


def test_mini_spec_expands_on_the_shared_scenes(tmp_path):
    experiment = expand(load_spec("mini"), require_shared(DNERF_ROOT), tmp_path / "mini")
    assert len(experiment.runs) == 16 and {r.field for r in experiment.runs} == {"mlp", "cfc", "sde", "hexplane"}
    assert {r.scene for r in experiment.runs} == {"bouncingballs", "hellwarrior", "lego", "standup"}


def test_families_are_margins_with_every_family_and_share_its_runs(tmp_path):
    root = require_shared(DNERF_ROOT).parent
    margins = expand(load_spec("margins"), root, tmp_path / "margins")
    families = expand(load_spec("families"), root, tmp_path / "families")
    assert len(families.runs) == 90 and {r.field for r in families.runs} == {"static", "mlp", "cfc", "sde", "hexplane"}
    # The D-NeRF runs are margins' (a built-in scene is generated in each experiment's own folder).
    shared = {r.run_dir for r in margins.runs if r.dataset == "dnerf"}
    assert len(shared) == 36 and shared < {r.run_dir for r in families.runs}
