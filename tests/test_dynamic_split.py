"""Static and dynamic Gaussians (train.dynamic_split): labelled from the motion masks, static ones never
moved, labels carried by densification and resumed bit-exactly."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config
from liquidgs.data import load_dataset
from liquidgs.errors import LiquidGSError
from liquidgs.train.config import config_hash, identity, load_yaml
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.dynamic_split import DYNAMIC, MotionVotes, SplitConfig, surface_depth, where_they_stand
from liquidgs.train.flow_loss import project_with_depth
from liquidgs.train.model import Deformed, render_frame
from liquidgs.train.run import load_run
from liquidgs.train.strategy import D3DGSStrategy, DensifyConfig, _duplicate_unmeasured, _split
from liquidgs.train.trainer import Trainer
from shared_data import use_optional_lpips
from tiny_runs import interrupt_at, run_cli, run_train, tiny_flags

pytest.importorskip("cv2", reason="optical flow needs opencv-python-headless (the dev extra installs it)")


@pytest.fixture(autouse=True)
def optional_lpips(monkeypatch):
    use_optional_lpips(monkeypatch)


def votes_for(scene: Path, cfg: SplitConfig | None = None) -> tuple[MotionVotes, list]:
    cfg_run, _ = resolve_config(["--data", str(scene), "--preset", "tiny"])
    train = load_run_dataset(cfg_run, load_dataset(cfg_run.data)).train
    return MotionVotes(cfg or SplitConfig(apply=True), scene, train, 1.0, torch.device("cpu")), train


def test_a_point_the_masks_hold_in_every_frame_is_dynamic_and_one_they_never_hold_is_static(flow_capture):
    votes, train = votes_for(flow_capture)
    held, elsewhere = torch.tensor([[0.05, 0.02, 0.0]]), torch.tensor([[0.3, -0.25, 0.1]])
    votes.masks[:] = False
    for i, frame in enumerate(train):  # each frame's mask is the one pixel the first point falls in
        col, row = project_with_depth(held.double(), frame.camera)[0].floor().long()[0].tolist()
        votes.masks[i, row, col] = True
    both = where_they_stand(torch.cat([held, elsewhere]))
    assert votes.vote(both).tolist() == [1.0, 0.0]
    assert votes.held(both).tolist() == [True, False]
    behind = torch.tensor([[0.0, 0.0, 1e4]])  # no camera sees it: static
    assert votes.vote(where_they_stand(behind)).tolist() == [0.0]


def test_a_gaussian_hidden_behind_the_moving_subject_is_not_held_by_its_mask(flow_capture):
    # In every frame a wide opaque Gaussian (the subject) stands in front of a small one (the wall
    # behind it) on the camera's axis, and the frame's motion mask holds the subject's pixels.
    votes, train = votes_for(flow_capture, SplitConfig(apply=True, occlusion=0.2))
    votes.masks[:] = False

    def seen_by(index: int):
        camera = train[index].camera
        rotation, translation = camera.viewmat[:3, :3], camera.viewmat[:3, 3]
        centre, axis = -rotation.T @ translation, rotation[2]  # the camera's centre and viewing axis
        subject, wall = centre + 1.0 * axis, centre + 2.0 * axis
        col, row = project_with_depth(subject[None].double(), camera)[0].floor().long()[0].tolist()
        votes.masks[index, row - 2 : row + 3, col - 2 : col + 3] = True
        gaussians = Deformed(
            means=torch.stack([subject, wall]).float(), quats=torch.tensor([[1.0, 0, 0, 0]] * 2),
            scales=torch.tensor([[0.2] * 3, [0.01] * 3]), opacities=torch.tensor([0.99, 0.99]),
            colors=torch.ones(2, 3),
        )  # fmt: skip
        out = render_frame(gaussians, camera, sh_degree=None, background=torch.zeros(3))
        return gaussians.means, surface_depth(out.depth[..., 0], out.alpha[..., 0])

    assert votes.vote(seen_by).tolist() == [1.0, 0.0]  # the wall is never the surface its pixel shows
    centres_alone = [seen_by(i)[0] for i in range(len(train))]
    assert votes.vote(lambda i: (centres_alone[i], None)).tolist() == [1.0, 1.0]  # without the test, it is


def test_the_surface_is_drawn_only_where_the_render_is_opaque():
    depth, alpha = torch.tensor([[2.0, 3.0]]), torch.tensor([[0.5, 0.49]])
    assert surface_depth(depth, alpha).tolist() == [[2.0, float("inf")]]


def test_labels_are_decided_again_from_the_masks_and_the_field_motion(flow_capture):
    votes, _ = votes_for(flow_capture)
    votes.vote = lambda seen_by: torch.tensor([1.0, 0.0, 0.0, 1.0])  # masks hold Gaussians 0 and 3
    labels = torch.tensor([False, True, True, True])
    moves = {1: 0.0, 2: 0.5, 3: 0.0}  # the field leaves 1 (and 3) still and moves 2

    def largest_move(indices):
        return torch.tensor([moves[int(i)] for i in indices])

    new = votes.redecide(where_they_stand(torch.zeros(4, 3)), labels, largest_move)
    # 0: inside, becomes dynamic; 1: outside and still, becomes static; 2 moves; 3 is inside (kept)
    assert new.tolist() == [True, False, True, True]


def test_densification_gives_clones_and_split_children_their_parents_label():
    n = 4
    params = torch.nn.ParameterDict({
        "means": torch.nn.Parameter(torch.randn(n, 3)), "scales": torch.nn.Parameter(torch.full((n, 3), -2.0)),
        "quats": torch.nn.Parameter(torch.tensor([[1.0, 0, 0, 0]] * n)),
        "opacities": torch.nn.Parameter(torch.zeros(n)),
    })  # fmt: skip
    optimizers = {k: torch.optim.Adam([p]) for k, p in params.items()}
    state = D3DGSStrategy(DensifyConfig(), 1.0).initial_state(n, torch.device("cpu"))
    state["count"] += 3
    state[DYNAMIC] = torch.tensor([True, False, True, False])
    _duplicate_unmeasured(params, optimizers, state, torch.tensor([True, True, False, False]))
    assert state[DYNAMIC].tolist() == [True, False, True, False, True, False]
    assert state["count"][n:].tolist() == [0, 0]  # statistics start anew, the label does not
    _split(params, optimizers, state, torch.tensor([False, False, True, True, False, False]), 2, None)
    # the parents 2 (dynamic) and 3 (static) replaced by two children each, all first children first
    assert state[DYNAMIC].tolist() == [True, False, True, False, True, False, True, False]


# The puppet's masks hold its whole swing in most frames: at the default vote (0.05, for slow real
# subjects) every Gaussian of this small scene is dynamic; at 0.5 about half are.
SPLIT_RUN = tiny_flags({"iterations": 30, "checkpoint_every": 10, "eval.start": 30, "cameras.align_steps": 5,
                        "split.apply": True, "split.every": 5, "split.vote": 0.5})  # fmt: skip


@pytest.mark.parametrize("field", ["mlp", "hexplane"])
def test_the_field_never_moves_a_static_gaussian_and_sees_only_the_dynamic_ones(flow_capture, tmp_path, field):
    out = tmp_path / "run"
    results = run_train(["--data", str(flow_capture), "--field", field, *SPLIT_RUN, "--out", str(out)])
    run = load_run(out)
    labels = torch.load(out / "checkpoint.pt", weights_only=True)["strategy"][DYNAMIC]
    assert results.dynamic_gaussians == int(labels.sum()) and 0 < results.dynamic_gaussians < results.num_gaussians
    seen = []
    run.field.register_forward_hook(lambda _m, inputs, _out: seen.append(inputs[0].shape[0]))
    canonical = run.at_time(0.0)  # time 0 moves nothing either way: compare against the parameters
    static = ~labels
    moved = 0.0
    for time in (0.1, 0.5, 0.9):
        at = run.at_time(time)
        assert torch.equal(at.means[static], run.params["means"][static])
        assert torch.equal(at.quats[static], canonical.quats[static])
        moved = max(moved, float((at.means[labels] - run.params["means"][labels]).abs().max()))
    assert moved > 0  # the dynamic ones do move
    assert set(seen) == {results.dynamic_gaussians}


@pytest.mark.slow
@pytest.mark.parametrize("occlusion", [[], ["--split.occlusion", "0.2"]], ids=["centres", "occlusion-test"])
def test_a_split_run_resumes_bit_exactly_labels_included(flow_capture, tmp_path, monkeypatch, occlusion):
    """Cut at step 17 (after the warm-up's decision at 5; labels decided again at 10, 15, ...), resumed:
    the same labels and Gaussians as the run trained whole, with the vote's rendered depths too."""
    flags = ["--data", str(flow_capture), "--field", "mlp", *SPLIT_RUN, *occlusion]
    run_train([*flags, "--out", str(tmp_path / "whole")])
    interrupt_at(17, [*flags, "--out", str(tmp_path / "cut")], monkeypatch)
    run_train([*flags, "--out", str(tmp_path / "cut"), "--resume"])
    a = torch.load(tmp_path / "whole" / "checkpoint.pt", weights_only=True)
    b = torch.load(tmp_path / "cut" / "checkpoint.pt", weights_only=True)
    assert torch.equal(a["strategy"][DYNAMIC], b["strategy"][DYNAMIC])
    for key, value in a["params"].items():
        assert torch.equal(value, b["params"][key]), key


def test_the_labels_are_decided_afresh_with_the_occlusion_test_when_the_warm_up_ends(flow_capture, tmp_path):
    """Before its first step with the field, every label is the occlusion-tested vote over the scene
    the warm-up drew: promotions and demotions alike (nothing has moved yet, so nothing jumps)."""
    cfg, _ = resolve_config(["--data", str(flow_capture), "--field", "mlp", *SPLIT_RUN, "--split.occlusion", "0.2"])
    trainer = Trainer(cfg, tmp_path / "run")
    warmup = trainer.cfg.warmup
    for step in range(1, warmup):
        trainer.train_step(step)
    before = trainer.strategy_state[DYNAMIC].clone()
    decided = trainer.split.held(trainer._seen_by(warmup, moved=False))
    trainer.train_step(warmup)
    after = trainer.strategy_state[DYNAMIC]
    assert torch.equal(after, decided)
    assert (before & ~after).any()  # the centres' vote held some the occlusion test does not


@pytest.mark.slow
def test_a_split_run_made_before_the_occlusion_test_resumes_as_it_was_trained(flow_capture, tmp_path, monkeypatch):
    """Its config.yml has no split.occlusion (written before it existed): it resumes with the centres'
    vote and no decision at the warm-up's end, to the last bit of the same run trained whole, and is
    the run the defaults make today (the test is opt-in); with the test it is another run."""
    flags = ["--data", str(flow_capture), "--field", "mlp", *SPLIT_RUN]
    run_train([*flags, "--out", str(tmp_path / "whole")])
    cut = tmp_path / "cut"
    interrupt_at(17, [*flags, "--out", str(cut)], monkeypatch)
    config = cut / "config.yml"
    lines = config.read_text().splitlines()
    kept = [line for line in lines if line.strip() != "occlusion: null"]
    assert len(kept) == len(lines) - 1
    config.write_text("\n".join(kept) + "\n")
    run_train(["--out", str(cut), "--resume"])
    a = torch.load(tmp_path / "whole" / "checkpoint.pt", weights_only=True)
    b = torch.load(cut / "checkpoint.pt", weights_only=True)
    assert torch.equal(a["strategy"][DYNAMIC], b["strategy"][DYNAMIC])
    for key, value in a["params"].items():
        assert torch.equal(value, b["params"][key]), key
    resumed = load_yaml(config)
    assert resumed.split.occlusion is None and "occlusion" not in identity(resumed)["split"]
    assert config_hash(resolve_config(flags)[0]) == config_hash(resumed)
    assert config_hash(resolve_config([*flags, "--split.occlusion", "0.2"])[0]) != config_hash(resumed)


def test_a_negative_occlusion_tolerance_is_one_line(flow_capture, tmp_path):
    code, _, stderr = run_cli(["train", "--data", str(flow_capture), "--preset", "tiny", "--split.occlusion", "-0.1",
                               "--out", str(tmp_path / "run")])  # fmt: skip
    assert code == 2 and "split.occlusion must be a finite number >= 0, got -0.1" in stderr
    assert stderr.count("\n") == 1 and not (tmp_path / "run").exists()


def test_bench_train_counts_the_gaussians_the_field_moves_in_a_split_run(flow_capture, capsys):
    """What the split saves is in proportion to the dynamic Gaussians: the record says how many."""
    args = ["bench", "train", "--json", "--data", str(flow_capture), "--from-step", "8", "--steps", "2",
            "--split.apply", "true", "--split.vote", "0.5"]  # fmt: skip
    assert cli(args) == 0
    record = json.loads(capsys.readouterr().out)
    assert 0 < record["dynamic_gaussians"]["median"] < record["n_gaussians"]["median"]


def test_the_split_switched_off_leaves_the_identity_of_runs_without_it(flow_capture, puppet_scene, tmp_path):
    base = ["--data", str(flow_capture), "--preset", "tiny"]
    plain, _ = resolve_config([*base, "--split.apply", "false"])
    split, _ = resolve_config([*base, "--split.apply", "true"])
    static, _ = resolve_config([*base, "--field", "static", "--split.apply", "true"])
    static_plain, _ = resolve_config([*base, "--field", "static"])
    assert "split" not in identity(plain) and config_hash(split) != config_hash(plain)
    assert config_hash(static) == config_hash(static_plain)  # the static model has nothing to split
    code, _, stderr = run_cli(["train", *base, "--split.apply", "false", "--split.vote", "0.3",
                               "--out", str(tmp_path / "a")])  # fmt: skip
    assert code == 2 and "--split.vote has no effect: --split.apply is false" in stderr
    code, _, stderr = run_cli(["train", "--data", str(puppet_scene), "--preset", "tiny", "--split.apply", "true",
                               "--out", str(tmp_path / "b")])  # fmt: skip
    assert code == 2 and "decided from a capture's motion masks" in stderr and stderr.count("\n") == 1
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize(("value", "message"), [(0, "hold no pixel"), (255, "hold every pixel")])
def test_masks_that_hold_no_pixel_or_every_pixel_are_one_line(flow_capture, tmp_path, value, message):
    scene = Path(shutil.copytree(flow_capture, tmp_path / "scene"))
    for mask in (scene / "flow" / "1x" / "masks").glob("*.png"):
        shape = np.asarray(Image.open(mask)).shape
        Image.fromarray(np.full(shape, value, np.uint8)).save(mask)
    code, _, stderr = run_cli(["train", "--data", str(scene), *SPLIT_RUN, "--out", str(tmp_path / "run")])
    assert code == 2 and message in stderr and stderr.count("\n") == 1, stderr
    with pytest.raises(LiquidGSError, match=message):
        votes_for(scene)


def test_the_viewer_draws_static_gaussians_blue_and_dynamic_ones_orange(flow_capture, tmp_path):
    from liquidgs.viewer.scenes import SPLIT_COLOURS, RunScene

    out = tmp_path / "run"
    run_train(["--data", str(flow_capture), "--field", "mlp", *SPLIT_RUN, "--out", str(out)])
    scene = RunScene(load_run(out), "split")
    assert scene.has_split
    frame = scene.dataset.train[0]
    image = scene.render_split(frame.camera, frame.time).reshape(-1, 3)
    covered = (image - scene.background).abs().sum(-1) > 0.3
    nearest = torch.cdist(image[covered], SPLIT_COLOURS).argmin(dim=1)
    assert (nearest == 0).sum() > 20 and (nearest == 1).sum() > 20  # both sets on screen


@pytest.mark.slow
def test_a_run_that_trains_from_the_flow_is_refused_once_the_flow_is_computed_otherwise(flow_capture, tmp_path):
    scene = Path(shutil.copytree(flow_capture, tmp_path / "scene"))
    out = tmp_path / "run"
    run_train(["--data", str(scene), "--field", "mlp", *SPLIT_RUN, "--out", str(out)])
    assert run_cli(["eval", "--run", str(out), "--flow-error"])[0] == 0
    scored = json.loads((out / "eval.json").read_text())["flow_error"]
    assert scored["pairs"] > 0 and scored["consistent_px"] >= 0 and scored["cameras"] == "as given"
    record = scene / "flow" / "1x" / "flow.json"
    record.write_text(record.read_text().replace("\"threshold_px\": 1.0", "\"threshold_px\": 2.0"))
    code, _, stderr = run_cli(["eval", "--run", str(out)])
    assert code == 2 and "1 file(s) changed, e.g. flow/1x/flow.json" in stderr, stderr


def test_the_flow_error_of_a_run_on_d_nerf_is_one_line(tiny_mlp_run):
    code, _, stderr = run_cli(["eval", "--run", str(tiny_mlp_run), "--flow-error"])
    assert code == 2 and "is not a capture with optical flow" in stderr and stderr.count("\n") == 1, stderr


@pytest.mark.parametrize(
    ("flag", "value", "message"),
    [("--split.vote", "0", "split.vote must be in (0, 1], got 0.0"),
     ("--split.vote", "1.5", "split.vote must be in (0, 1], got 1.5"),
     ("--split.every", "0", "split.every"),
     ("--split.still", "nan", "split.still")],
)  # fmt: skip
def test_bad_split_settings_are_one_line_before_anything_is_written(flow_capture, tmp_path, flag, value, message):
    out = tmp_path / "run"
    code, _, stderr = run_cli(["train", "--data", str(flow_capture), *SPLIT_RUN, flag, value, "--out", str(out)])
    assert code == 2 and message in stderr and stderr.count("\n") == 1, stderr
    assert not out.exists()
