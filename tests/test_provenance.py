"""Files derived from a run know where they came from: eval.json, baked folders and exports record the
run's checkpoint (iteration, content hash) and scene print, and their readers refuse a stale or
foreign one in one line naming the file (run_folder.provenance)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from field_plugins import plugin, use_registry, write_plugin
from liquidgs.bake.formats import read_splatv
from liquidgs.cli import main as cli
from liquidgs.experiments.plan import Experiment, RunEntry, write_manifest
from liquidgs.gaussians import read_ply_comments
from liquidgs.train.run import load_run
from liquidgs.train.run_folder import source_in_comments
from test_field_registry import TOY_PLUGIN
from tiny_runs import one_line_error, rehash_baked_scene, run_train, snapshot, tiny_flags

ONE_FIT = ("--splatv-tolerance", "0.5")
"""splatv exports at one budget, not the export's search: the source record is what is tested."""

# 20 iterations, resumed to 30: enough to make two checkpoints of one run.
SHORT = tiny_flags({"iterations": 20, "eval.start": 20})


@pytest.fixture(autouse=True)
def _one_thread(one_torch_thread):
    yield


def train_short(scene: Path, out: Path, field: str = "mlp", iterations: int = 20) -> Path:
    run_train(["--data", str(scene), "--field", field, *SHORT, "--iterations", str(iterations), "--out", str(out)])
    return out


def train_on(out: Path, iterations: int) -> None:
    """The run in `out` trained on to `iterations` (a resume that extends it)."""
    run_train(["--resume", "--iterations", str(iterations), "--out", str(out)])


@pytest.fixture
def scene(puppet_scene, tmp_path) -> Path:
    """A copy of the puppet this test may replace or remove."""
    return Path(shutil.copytree(puppet_scene, tmp_path / "puppet"))


def half_masks(run: Path, folder: Path) -> Path:
    """A mask per test view: its left half."""
    folder.mkdir()
    for frame in load_run(run, "cpu").scene().test:
        mask = np.zeros((frame.camera.height, frame.camera.width), np.uint8)
        mask[:, : frame.camera.width // 2] = 255
        Image.fromarray(mask).save(folder / f"{frame.name}.png")
    return folder


def one_run_experiment(directory: Path, data: Path, run_dir: str) -> None:
    entry = RunEntry("clips", "puppet", "mlp", 0.0, 0, "tiny", str(data), run_dir, None)
    write_manifest(Experiment({"name": "provenance"}, str(data), directory, (entry,)))


# ----------------------------------------------------------------------------- eval.json
def test_eval_json_records_the_checkpoint_it_scored(scene, tmp_path):
    run = train_short(scene, tmp_path / "run")
    assert cli(["eval", "--run", str(run)]) == 0
    source = json.loads((run / "eval.json").read_text())["source"]
    assert source["iteration"] == 20 and source["run"] == str(run.resolve())
    assert source["checkpoint"] == "checkpoint.pt" and len(source["checkpoint_sha256"]) == 64
    assert source["scene_sha256"] is not None
    assert json.loads((run / "eval_per_view.json").read_text())["source"] == source


def test_the_report_refuses_mask_scores_of_a_checkpoint_the_run_trained_past(scene, tmp_path, capsys):
    """Masks scored at iteration 20, the run then finished at 30: the report used to take the old
    subject score without a word."""
    directory = tmp_path / "exp"
    run = train_short(scene, directory / "clips/puppet/mlp/s0")
    one_run_experiment(directory, scene.parent, "clips/puppet/mlp/s0")
    masks = half_masks(run, tmp_path / "masks")
    assert cli(["eval", "--run", str(run), "--mask", str(masks)]) == 0
    train_on(run, 30)
    capsys.readouterr()
    assert cli(["experiment", "report", str(directory)]) == 2
    assert one_line_error(capsys) == (
        f"liquidgs experiment: error: {run / 'eval.json'}: derived from the checkpoint at iteration 20, but "
        f"{run / 'checkpoint.pt'} has changed since (trained on or replaced); run `liquidgs eval --run {run}` "
        "again (with its --mask)"
    )
    assert not (directory / "report").exists()
    assert cli(["eval", "--run", str(run), "--mask", str(masks)]) == 0  # scored again: the report goes through
    assert cli(["experiment", "report", str(directory)]) == 0
    assert (directory / "report" / "report.md").is_file()


def test_an_eval_json_from_before_sources_is_checked_by_its_iteration(scene, tmp_path, capsys):
    directory = tmp_path / "exp"
    run = train_short(scene, directory / "clips/puppet/mlp/s0")
    one_run_experiment(directory, scene.parent, "clips/puppet/mlp/s0")
    (run / "eval.json").write_text(json.dumps({"iteration": 10, "psnr": 20.0}))
    assert cli(["experiment", "report", str(directory)]) == 2
    assert one_line_error(capsys).endswith(
        f"eval.json: scores iteration 10, but the run finished at iteration 20; run `liquidgs eval --run {run}` "
        "again (with its --mask)"
    )


# ----------------------------------------------------------------------------- baked folders
def test_a_baked_folder_refuses_a_replaced_scene_like_its_run(scene, tmp_path, capsys):
    """eval and render of R/baked used to exit 0 on another scene, calling the scores the final checkpoint's."""
    run = train_short(scene, tmp_path / "run")
    assert cli(["bake", "--run", str(run), "--max-keyframes", "9"]) == 0
    baked = run / "baked"
    assert (baked / "scene.json").read_bytes() == (run / "scene.json").read_bytes()
    transforms = scene / "transforms_test.json"
    record = json.loads(transforms.read_text())
    record["frames"] = record["frames"][:-1]  # another scene at the same place
    transforms.write_text(json.dumps(record))
    before = snapshot(baked)
    for command in ("eval", "render"):
        assert cli([command, "--run", str(baked)]) == 2
        line = one_line_error(capsys)
        assert f"{scene}: not the scene the run in {baked} was trained on (1 file(s) changed" in line, line
    assert snapshot(baked) == before


def test_a_baked_folder_renders_and_exports_without_its_scene(scene, tmp_path, capsys):
    run = train_short(scene, tmp_path / "run")
    baked = tmp_path / "baked"
    assert cli(["bake", "--run", str(run), "--out", str(baked), "--max-keyframes", "9"]) == 0
    test_views = [frame.name for frame in load_run(run, "cpu").scene().test]
    shutil.rmtree(scene)
    assert cli(["render", "--run", str(baked), "--sweep-frames", "2", "--orbit-frames", "2"]) == 0
    assert sorted(p.stem for p in (baked / "renders/test/render").iterdir()) == sorted(test_views)
    assert not (baked / "renders/test/gt").exists()  # no images to copy
    assert cli(["export", "--run", str(baked), "--format", "splatv", *ONE_FIT]) == 0
    _, header = read_splatv(baked / "export/scene.splatv")
    assert [c["img_name"] for c in header["cameras"]][: len(test_views)] == test_views
    assert cli(["export", "--run", str(baked), "--format", "web"]) == 0
    assert cli(["eval", "--run", str(baked)]) == 2  # scores need the images
    assert f"{scene}: not the scene the run in {baked} was trained on" in one_line_error(capsys)


def test_a_baked_folder_is_refused_once_its_run_has_trained_on(scene, tmp_path, capsys):
    run = train_short(scene, tmp_path / "run")
    assert cli(["bake", "--run", str(run), "--max-keyframes", "9"]) == 0
    train_on(run, 30)
    capsys.readouterr()
    assert cli(["render", "--run", str(run / "baked")]) == 2
    assert one_line_error(capsys) == (
        f"liquidgs render: error: {run / 'baked' / 'baked.json'}: derived from the checkpoint at iteration 20, "
        f"but {run / 'checkpoint.pt'} has changed since (trained on or replaced); bake it again "
        f"(liquidgs bake --run {run.resolve()})"
    )


def test_a_moved_baked_folder_stands_alone(scene, tmp_path):
    run = train_short(scene, tmp_path / "run")
    assert cli(["bake", "--run", str(run), "--out", str(tmp_path / "baked"), "--max-keyframes", "9"]) == 0
    shutil.rmtree(run)  # the run deleted: the baked scene is all there is
    assert load_run(tmp_path / "baked", "cpu").iteration == 20


def test_a_plugin_fields_baked_folder_needs_no_plugin(scene, tmp_path, monkeypatch, capsys):
    use_registry(monkeypatch, [plugin("toy-fields", write_plugin(tmp_path, "toy_fields", TOY_PLUGIN, monkeypatch))])
    run = train_short(scene, tmp_path / "run", field="toy")
    assert cli(["bake", "--run", str(run), "--max-keyframes", "9"]) == 0
    use_registry(monkeypatch)  # the plugin uninstalled
    assert cli(["eval", "--run", str(run)]) == 2
    assert "comes from package toy-fields 0.2, which is not installed" in one_line_error(capsys)
    assert cli(["render", "--run", str(run / "baked"), "--sweep-frames", "2", "--orbit-frames", "2"]) == 0
    assert cli(["export", "--run", str(run / "baked"), "--format", "splatv", *ONE_FIT]) == 0
    assert load_run(run / "baked", "cpu").config.field == "toy"


def damage_manifest(baked: Path, change) -> None:
    manifest = json.loads((baked / "baked.json").read_text())
    change(manifest)
    (baked / "baked.json").write_text(json.dumps(manifest))


def damage_scene(baked: Path, change) -> None:
    payload = torch.load(baked / "scene.pt", weights_only=True)
    change(payload)
    torch.save(payload, baked / "scene.pt")
    rehash_baked_scene(baked)


class Pickled:
    """Not a tensor: a scene.pt holding it needs unpickling code, which a baked scene never runs."""


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda b: damage_manifest(b, lambda m: m.pop("sh_degree")), "baked.json: field 'sh_degree' is missing"),
        (lambda b: damage_manifest(b, lambda m: m.update(sh_degree=9)), "baked.json: field 'sh_degree' must be 0..3"),
        (lambda b: damage_manifest(b, lambda m: m.update(format="liquidgs-baked/1")),
         "baked.json: baked by an older liquidgs (liquidgs-baked/1: no source record, scene print or cameras); "
         "bake the run again"),
        (lambda b: damage_scene(b, lambda p: p.update(extra=Pickled())), "scene.pt: unreadable baked scene"),
        (lambda b: damage_scene(b, lambda p: p["tracks"]["low"].view(-1)[:7].fill_(float("nan"))),
         "scene.pt: 7 non-finite values (NaN or infinity); bake the run again"),
        (lambda b: torch.save(torch.load(b / "scene.pt", weights_only=True), b / "scene.pt") or
         (b / "scene.pt").write_bytes((b / "scene.pt").read_bytes()[:-100]),
         "scene.pt: missing, or not the scene.pt baked into this folder (its hash differs)"),
        (lambda b: (b / "cameras.json").unlink(), "cameras.json: missing; bake the run again"),
    ],
)  # fmt: skip
def test_a_hand_damaged_baked_folder_is_one_line(tiny_mlp_run, tmp_path, capsys, damage, message):
    baked = tmp_path / "baked"
    assert cli(["bake", "--run", str(tiny_mlp_run), "--out", str(baked), "--max-keyframes", "9"]) == 0
    damage(baked)
    for command in ("render", "export"):
        assert cli([command, "--run", str(baked)]) == 2
        line = one_line_error(capsys)
        assert line.startswith(f"liquidgs {command}: error: {baked}") and message in line, line
    assert not (baked / "renders").exists() and not (baked / "export").exists()


# ----------------------------------------------------------------------------- exports
@pytest.mark.slow
def test_every_export_records_its_source(tiny_mlp_run, tmp_path):
    out = tmp_path / "export"
    assert cli(["export", "--run", str(tiny_mlp_run), "--out", str(out), "--time", "0.5", "--sequence", "3"]) == 0
    source = load_run(tiny_mlp_run, "cpu").source()
    for ply in [out / "canonical.ply", out / "time_0.5000.ply", *sorted((out / "sequence").glob("*.ply"))]:
        assert source_in_comments(read_ply_comments(ply)) == source, ply
    assert torch.load(out / "field.pt", weights_only=True)["source"] == source
    assert cli(["export", "--run", str(tiny_mlp_run), "--out", str(out), "--format", "splatv", *ONE_FIT]) == 0
    assert read_splatv(out / "scene.splatv")[1]["source"] == source
    assert cli(["export", "--run", str(tiny_mlp_run), "--out", str(out), "--format", "web"]) == 0
    assert json.loads((out / "web" / "scene.json").read_text())["source"] == source


def test_view_refuses_a_sequence_of_two_runs_and_an_export_its_run_trained_past(scene, tmp_path, capsys):
    from liquidgs.viewer.scenes import PlyScene

    first, second = train_short(scene, tmp_path / "a"), train_short(scene, tmp_path / "b", field="cfc")
    for run in (first, second):
        assert cli(["export", "--run", str(run), "--sequence", "3"]) == 0
    mixed = tmp_path / "mixed"
    shutil.copytree(first / "export/sequence", mixed)
    shutil.copy(second / "export/sequence/frame_0002.ply", mixed / "frame_0002.ply")
    assert cli(["view", "--ply", str(mixed)]) == 2
    assert one_line_error(capsys) == (
        f"liquidgs view: error: {mixed / 'frame_0002.ply'}: from another run or checkpoint than "
        f"{mixed / 'frame_0000.ply'}; a sequence mixes two"
    )
    assert len(PlyScene(first / "export/sequence", torch.zeros(3)).frames) == 3
    train_on(first, 30)
    capsys.readouterr()
    assert cli(["view", "--ply", str(first / "export/sequence")]) == 2
    assert one_line_error(capsys).endswith(
        f"{first / 'checkpoint.pt'} has changed since (trained on or replaced); export it again"
    )
