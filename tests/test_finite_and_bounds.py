"""Numbers a writer would save broken, sizes that multiply cost, inputs of the wrong shape: each is
refused in one line (exit 2) naming the run, file or setting, with nothing written.

Driven through the CLI in-process (liquidgs.cli.main); the runs are copies of the tiny MLP run,
damaged the way a diverged or broken training would leave them.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from liquidgs.cli import main as cli
from liquidgs.train.run_folder import CHECKPOINT, read_checkpoint, write_checkpoint
from tiny_runs import snapshot


def one_error_line(capsys, code: int, argv: list[str]) -> str:
    """Runs `liquidgs ARGV`; its exit code must be `code` and stderr one line, which is returned."""
    assert cli(argv) == code, argv
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def refused(capsys, argv: list[str], *watched: Path) -> str:
    """`liquidgs ARGV` exits 2 with one line and leaves every watched folder as it was."""
    before = snapshot(*watched)
    line = one_error_line(capsys, 2, argv)
    assert snapshot(*watched) == before, "nothing may be written"
    return line


def copy_run(run: Path, to: Path) -> Path:
    shutil.copytree(run, to, ignore=shutil.ignore_patterns("baked", "export", "renders"))
    return to


def damage_checkpoint(run: Path, change) -> Path:
    """The run's checkpoint with `change(payload)` applied, written as training writes it."""
    payload = read_checkpoint(run / CHECKPOINT)
    change(payload)
    payload.pop("format")
    write_checkpoint(run, payload)
    return run


def nan_field(payload: dict) -> None:
    """A diverged field: one weight of its last layer NaN, so every Gaussian's deltas are."""
    last_weight = [key for key in payload["field"] if key.endswith("weight")][-1]
    payload["field"][last_weight].view(-1)[0] = float("nan")


def inf_scale(payload: dict) -> None:
    payload["params"]["scales"].view(-1)[0] = float("inf")


@pytest.fixture(scope="module")
def broken_runs(tiny_mlp_run, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("broken_runs")
    return {
        "nan field": damage_checkpoint(copy_run(tiny_mlp_run, root / "nan_field"), nan_field),
        "inf scale": damage_checkpoint(copy_run(tiny_mlp_run, root / "inf_scale"), inf_scale),
    }


WRITERS = {
    "bake": ["bake"],
    "export ply": ["export", "--sequence", "3"],
    "export plyseq": ["export", "--format", "plyseq", "--sequence", "3"],
    "export splatv": ["export", "--format", "splatv"],
    "export web": ["export", "--format", "web"],
    "export html": ["export", "--format", "html"],
    "export spz": ["export", "--format", "spz", "--time", "0.5"],
}


@pytest.mark.parametrize("damage", ["nan field", "inf scale"])
@pytest.mark.parametrize("writer", list(WRITERS))
def test_a_non_finite_run_is_refused_by_every_writer(broken_runs, writer, damage, capsys):
    run = broken_runs[damage]
    line = refused(capsys, [*WRITERS[writer], "--run", str(run)], run)
    counted = re.search(
        rf"{re.escape(str(run))}: ([\d,]+) of ([\d,]+) values of .* are NaN or infinite; nothing written", line
    )
    assert counted and 0 < int(counted[1].replace(",", "")) <= int(counted[2].replace(",", "")), line


READERS = {
    "eval": ["eval"],
    "render": ["render", "--sweep-frames", "2", "--orbit-frames", "2"],
    "view": ["view", "--port", "0"],
}


@pytest.mark.parametrize("damage", ["nan field", "inf scale"])
@pytest.mark.parametrize("reader", list(READERS))
def test_a_non_finite_run_is_one_line_to_every_reader_not_a_score(broken_runs, reader, damage, capsys, monkeypatch):
    """eval and render used to end in a traceback from the rasteriser's input check."""
    from liquidgs.viewer import server

    def no_server(*args, **kwargs):
        raise AssertionError("the server started")

    monkeypatch.setattr(server.Viewer, "__init__", no_server)
    run = broken_runs[damage]
    line = refused(capsys, [*READERS[reader], "--run", str(run)], run)
    assert re.search(rf"{re.escape(str(run))}: [\d,]+ of [\d,]+ values of the Gaussians at time .* are NaN", line), line


def test_splatv_of_a_run_without_motion_says_there_is_none_to_keep(puppet_scene, tmp_path, capsys):
    from tiny_runs import run_train, tiny_flags

    run = tmp_path / "static"
    run_train(["--data", str(puppet_scene), "--field", "static", *tiny_flags({"iterations": 10}), "--out", str(run)])
    assert cli(["export", "--run", str(run), "--format", "splatv"]) == 0
    err = capsys.readouterr().err
    assert "splatv: the run has no motion (no Gaussian moves), so there is none to keep" in err, err
    assert (run / "export" / "scene.splatv").is_file()


# ----------------------------------------------------------------------------- bounds

def bounded_settings() -> list[tuple[type, str, int]]:
    """(config class, setting, its bound) for every size setting that multiplies cost."""
    from liquidgs.commands.bake import MAX_KEYFRAMES, BakeArgs
    from liquidgs.commands.export import MAX_SEQUENCE, ExportArgs
    from liquidgs.commands.render import MAX_SAMPLES, RenderArgs
    from liquidgs.fields import config as field_config
    from liquidgs.fields import hexplane
    from liquidgs.train.config import MAX_INIT_POINTS, TrainConfig
    from liquidgs.train.motion_reg import MAX_NEIGHBOURS, MotionRegConfig

    return [
        (MotionRegConfig, "neighbours", MAX_NEIGHBOURS),
        (TrainConfig, "init_points", MAX_INIT_POINTS),
        (BakeArgs, "max_keyframes", MAX_KEYFRAMES),
        (RenderArgs, "uncertainty_samples", MAX_SAMPLES),
        (ExportArgs, "sequence", MAX_SEQUENCE),
        (hexplane.HexPlaneConfig, "multires", hexplane.MAX_LEVELS),
        *[(field_config.FieldOptions, key, hi) for key, (_, hi) in field_config.SIZE_BOUNDS.items()],
        *[(hexplane.HexPlaneConfig, key, hi) for key, (_, hi) in hexplane.SIZE_BOUNDS.items()],
    ]


def test_every_bound_is_stated_in_its_settings_help_and_holds_every_preset_and_spec():
    from liquidgs.bake.benchmark import MAX_REPEATS, build_parser
    from liquidgs.commands.catalog import attribute_docs
    from liquidgs.experiments import BUILTIN_SPECS, load_spec
    from liquidgs.experiments.plan import _field_settings, run_config
    from liquidgs.fields.hexplane import PRESETS, HexPlaneConfig

    for cls, setting, bound in bounded_settings():
        assert f"at most {bound:,}" in attribute_docs(cls)[setting], (cls.__name__, setting)
    repeats = next(a for a in build_parser()._actions if "--repeats" in a.option_strings)
    assert f"at most {MAX_REPEATS}" in repeats.help
    # Every preset and every run of every spec (built in, and those the docs keep) is within them.
    for name in PRESETS:
        HexPlaneConfig.preset(name)
    specs = [*BUILTIN_SPECS.values(), *(load_spec(p) for p in sorted(Path("docs/experiments").rglob("*.yml")))]
    checked = 0
    for spec in specs:
        for grid in spec.grids:
            for variant in grid.field_variants():
                run_config(grid.preset, Path("SCENE"), {**_field_settings(variant), **grid.overrides,
                                                        **variant.overrides}, spec.name)  # fmt: skip
                checked += 1
    assert checked > len(specs)


@pytest.fixture(scope="module")
def world(tiny_mlp_run, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bounds")
    run = copy_run(tiny_mlp_run, root / "run")
    assert cli(["bake", "--run", str(run), "--out", str(root / "baked")]) == 0
    return {"run": run, "baked": root / "baked", "scene": Path(read_config(run)["data"]["path"])}


def read_config(run: Path) -> dict:
    import yaml

    return yaml.safe_load((run / "config.yml").read_text())


TINY = ["--preset", "tiny", "--iterations", "10", "--eval.start", "10"]

OVER_BOUNDS = {
    "motion.neighbours": (["train", "--data", "{scene}", "--out", "{work}/out", *TINY, "--motion.neighbours", "100000"],
                          "motion.neighbours must be at most 128, got 100,000"),
    "mlp width": (["train", "--data", "{scene}", "--out", "{work}/out", *TINY, "--field-options.mlp-width",
                   "100000000"], "field: mlp_width must be at most 4,096, got 100,000,000"),
    "cfc units": (["train", "--data", "{scene}", "--out", "{work}/out", *TINY, "--field", "cfc",
                   "--field-options.backbone-units", "5000"], "field: backbone_units must be at most 4,096, got 5,000"),
    "render samples": (["render", "--run", "{run}", "--out", "{work}/r", "--uncertainty-samples", "5000"],
                       "--uncertainty-samples must be 0 or 2 to 1,024, got 5,000"),
    "export sequence": (["export", "--run", "{run}", "--out", "{work}/e", "--sequence", "100001"],
                        "--sequence must be between 0 and 100,000, got 100,001"),
    "bench bake repeats": (["bench", "bake", "--run", "{run}", "--baked", "{baked}", "--repeats", "1000"],
                           "--repeats between 1 and 100"),
    "bench bake baked as run": (["bench", "bake", "--run", "{baked}", "--baked", "{baked}"],
                                "{baked}: a baked scene, not a run; give --run the run it came from"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(OVER_BOUNDS))
def test_a_setting_past_its_bound_is_one_line_naming_it(case, world, tmp_path, capsys, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    argv, message = OVER_BOUNDS[case]
    argv = [a.format(work=work, **world) for a in argv]
    line = refused(capsys, argv, work, world["run"], world["baked"])
    assert message.format(**world) in line, line


@pytest.mark.parametrize("field", ["mlp", "cfc"])
def test_every_field_size_past_its_bound_is_refused(field):
    from liquidgs.errors import ConfigError
    from liquidgs.fields.config import SIZE_BOUNDS, FieldConfig
    from liquidgs.fields.presets import FAMILY_SIZES

    family = "mlp" if field == "mlp" else "liquid"
    for key in FAMILY_SIZES[family]:
        if key not in SIZE_BOUNDS:
            continue  # the activation: a name, not a size
        highest = SIZE_BOUNDS[key][1]
        FieldConfig(name=field, preset="tiny", **{key: highest})  # the bound itself is allowed
        with pytest.raises(ConfigError, match=f"field: {key} must be at most {highest:,}, got {highest + 1:,}"):
            FieldConfig(name=field, preset="tiny", **{key: highest + 1})


@pytest.mark.parametrize(("override", "message"), [
    ({"resolution": 5000}, "hexplane: resolution must be at most 4,096, got 5,000"),
    ({"time_resolution": 3000}, "hexplane: time_resolution must be at most 2,048, got 3,000"),
    ({"features": 513}, "hexplane: features must be at most 512, got 513"),
    ({"width": 5000}, "hexplane: width must be at most 4,096, got 5,000"),
    ({"multires": (1,) * 33}, "hexplane: levels (multires) must be at most 32, got 33"),
    ({"resolution": 64, "multires": (1, 128)}, "resolution x multires must be at most 4,096 at every level"),
])  # fmt: skip
def test_hexplane_sizes_past_their_bounds_are_refused(override, message):
    from liquidgs.errors import ConfigError
    from liquidgs.fields.hexplane import HexPlaneConfig

    with pytest.raises(ConfigError, match=re.escape(message)):
        HexPlaneConfig.preset("tiny", **override)


# ----------------------------------------------------------------------------- one line, not a traceback

@pytest.fixture(scope="module")
def truncated_run(tiny_mlp_run, tmp_path_factory) -> Path:
    """The tiny run with its checkpoint.pt cut to half its bytes (a disk that filled, a copy cut off)."""
    run = copy_run(tiny_mlp_run, tmp_path_factory.mktemp("truncated") / "run")
    data = (run / CHECKPOINT).read_bytes()
    (run / CHECKPOINT).write_bytes(data[: len(data) // 2])
    return run


TRUNCATED = {
    "eval": ["eval", "--run", "{run}"],
    "render": ["render", "--run", "{run}"],
    "export": ["export", "--run", "{run}"],
    "bake": ["bake", "--run", "{run}"],
    "bench bake": ["bench", "bake", "--run", "{run}", "--baked", "{baked}"],
}


@pytest.mark.parametrize("command", list(TRUNCATED))
def test_a_truncated_checkpoint_is_one_line_and_nothing_written(command, truncated_run, world, tmp_path, capsys,
                                                                monkeypatch):  # fmt: skip
    monkeypatch.chdir(tmp_path)
    argv = [a.format(run=truncated_run, baked=world["baked"]) for a in TRUNCATED[command]]
    line = refused(capsys, argv, truncated_run, world["baked"], tmp_path)
    assert f"{truncated_run / CHECKPOINT}: " in line, line


def test_view_of_a_truncated_checkpoint_is_one_line_before_the_server_starts(truncated_run, capsys, monkeypatch):
    from liquidgs.viewer import server

    def no_server(*args, **kwargs):
        raise AssertionError("the server started")

    monkeypatch.setattr(server.Viewer, "__init__", no_server)
    line = refused(capsys, ["view", "--run", str(truncated_run)], truncated_run)
    assert f"{truncated_run / CHECKPOINT}: " in line, line


def test_export_web_refuses_a_failed_run_as_bake_does(tiny_mlp_run, tmp_path, capsys):
    from liquidgs.train.run_folder import FAILURE, RESULTS

    run = copy_run(tiny_mlp_run, tmp_path / "failed")
    (run / RESULTS).unlink()
    (run / FAILURE).write_text(json.dumps({"error": "diverged"}))
    lines = {}
    for command in (["bake"], ["export", "--format", "web"], ["export", "--format", "html"]):
        lines[" ".join(command)] = refused(capsys, [*command, "--run", str(run)], run)
    for command, line in lines.items():  # the command as typed is what the line names
        assert f"{run}: failed run (why: {run / FAILURE}): checkpoint at iteration" in line, line
        assert line.endswith(f"; {command} needs a finished run"), line


CLIP_FIELDS = {"url": "http://127.0.0.1:9/x.mp4", "size": 1, "sha256": "0" * 64, "licence": "l", "moving": ""}

BAD_TABLES = {
    "clips: a number for the url": ("LIQUIDGS_REAL_CLIPS", {"apple": {"url": 5}}, "real-clips",
                                    "entry 'apple': field 'url' must be a string, got 5"),
    "clips: text for the size": ("LIQUIDGS_REAL_CLIPS", {"apple": {"size": "big"}}, "real-clips",
                                 "entry 'apple': field 'size' must be an integer, got 'big'"),
    "clips: a list for an entry": ("LIQUIDGS_REAL_CLIPS", {"apple": ["x"]}, "real-clips",
                                   "entry 'apple' must be a JSON object of fields, got ['x']"),
    "clips: a missing key": ("LIQUIDGS_REAL_CLIPS", {"new": {k: v for k, v in CLIP_FIELDS.items() if k != "sha256"}},
                             "real-clips", "entry 'new' is not built in, so it needs field 'sha256'"),
    "archives: a number for the url": ("LIQUIDGS_DATA_ARCHIVES", {"dnerf": {"url": 5}}, "dnerf",
                                       "entry 'dnerf': field 'url' must be a string, got 5"),
    "archives: a number for the checksum": ("LIQUIDGS_DATA_ARCHIVES", {"dnerf": {"sha256": 7}}, "dnerf",
                                            "entry 'dnerf': field 'sha256' must be a string or null, got 7"),
    "archives: a list for an entry": ("LIQUIDGS_DATA_ARCHIVES", {"dnerf": [1]}, "dnerf",
                                      "entry 'dnerf' must be a JSON object of fields, got [1]"),
    "archives: a missing key": ("LIQUIDGS_DATA_ARCHIVES", {"new": {"url": "http://127.0.0.1:9/x.zip"}}, "new",
                                "entry 'new' is not built in, so it needs field 'source'"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_TABLES))
def test_a_wrongly_typed_download_table_entry_is_one_line_naming_it(case, tmp_path, capsys, monkeypatch):
    variable, table, dataset, message = BAD_TABLES[case]
    monkeypatch.setenv(variable, json.dumps(table))
    line = refused(capsys, ["data", "download", dataset, str(tmp_path / "out")], tmp_path)
    assert f"{variable}: {message}" in line, line


BAD_RECORDS = {
    "a list": (["[1, 2]"], "line 1 is not a JSON object of record fields, got [1, 2]"),
    "a list for the stage": (['{"stage": ["setup"], "event": "start"}'], "field 'stage': line 1: must be a string"),
    "text for the seconds": (['{"stage": "setup", "event": "start"}',
                              '{"stage": "setup", "event": "end", "status": "passed", "seconds": "ten"}'],
                             "field 'seconds': line 2: must be a number, got 'ten'"),
    "no status": (['{"stage": "setup", "event": "start"}', '{"stage": "setup", "event": "end"}'],
                  "field 'status': line 2: an end record needs a status"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_RECORDS))
def test_acceptance_summary_of_wrongly_typed_records_is_one_line(case, tmp_path, capsys):
    from liquidgs.train.gpu_acceptance import RECORDS

    lines, message = BAD_RECORDS[case]
    (tmp_path / RECORDS).write_text("\n".join(lines) + "\n")
    line = refused(capsys, ["bench", "acceptance", "--out", str(tmp_path), "--summary"], tmp_path)
    assert f"{tmp_path / RECORDS}: {message}" in line, line
