"""The motion evidence's defaults (train.config.with_motion_evidence): the optical-flow loss and the
static/dynamic split on for a capture with flow at the scale the run reads, off for D-NeRF, captures
without flow and the paper's specs - their identities as before - and decided once, recorded in
config.yml, so a run made before resumes as it was trained."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from pathlib import Path

import pytest
import torch

from liquidgs.commands.train import resolve_config
from liquidgs.errors import ConfigError
from liquidgs.experiments import BUILTIN_SPECS, expand
from liquidgs.experiments.spec import NERFDS_SCENES
from liquidgs.train.config import config_hash, identity, load_yaml, motion_evidence_note, with_motion_evidence
from liquidgs.train.flow_loss import DEFAULT_WEIGHT
from liquidgs.train.motion_reg import regularisation
from shared_data import use_optional_lpips
from tiny_runs import interrupt_at, run_train, tiny_flags

pytest.importorskip("cv2", reason="optical flow needs opencv-python-headless (the dev extra installs it)")

OFF = ["--flow.weight", "0", "--split.apply", "false"]
"""The settings every run made before these defaults trained with."""


@pytest.fixture(autouse=True)
def optional_lpips(monkeypatch):
    use_optional_lpips(monkeypatch)


def configs(data: Path, *args: str):
    """(the config as given, the same with every setting of before these defaults)."""
    base = ["--data", str(data), "--preset", "tiny", *args]
    return resolve_config(base)[0], resolve_config([*base, *OFF])[0]


def test_a_capture_with_flow_gets_the_flow_loss_and_the_split(flow_capture):
    given, _ = configs(flow_capture)
    assert given.flow.weight is None and given.split.apply is None  # left to the scene
    decided = with_motion_evidence(given)
    assert decided.flow.weight == DEFAULT_WEIGHT == 0.04 and decided.split.apply is True
    on, _ = configs(flow_capture, "--flow.weight", "0.04", "--split.apply", "true")
    assert config_hash(given) == config_hash(decided) == config_hash(on)
    assert decided.flow.tracks is False  # the tracks are asked for, not decided from the scene
    assert identity(given)["flow"] == {"weight": 0.04} and identity(given)["split"]["apply"] is True
    set_off, _ = configs(flow_capture, "--split.apply", "false")  # a value given is kept
    assert with_motion_evidence(set_off).split.apply is False and with_motion_evidence(set_off).flow.weight == 0.04
    tracks = resolve_config(["--data", str(flow_capture), "--preset", "tiny", "--flow.tracks"])[0]
    assert identity(tracks)["flow"] == {"weight": 0.04, "tracks": True} and config_hash(tracks) != config_hash(given)


def test_hexplane_trains_a_capture_with_flow_split_in_place_of_its_neighbour_terms(flow_capture):
    """A spatially local field (registered local_deformation) is split by default like every field, and
    the split takes its neighbour terms' place: their weights, left unset, are decided 0 (on the
    real-clip benchmark the split without them beat the terms without the split by 0.43 dB on the
    subject). A split or a weight given keeps the terms' meaning of before."""
    given, _ = configs(flow_capture, "--field", "hexplane")
    decided = with_motion_evidence(given)
    assert decided.flow.weight == DEFAULT_WEIGHT and decided.split.apply is True
    assert (decided.motion.rigidity, decided.motion.isometry) == (0.0, 0.0)
    assert regularisation(decided.motion, "nerfies", "hexplane") is None  # no term is trained
    assert identity(given)["split"]["apply"] is True
    assert identity(given)["motion"]["rigidity"] == 0.0 == identity(given)["motion"]["isometry"]
    # a run that asked for the split (as the benchmark's specs do) trains the terms over the dynamic
    # Gaussians, as before: another identity than the default's
    told, _ = configs(flow_capture, "--field", "hexplane", "--split.apply", "true", "--flow.weight", "0.04")
    assert with_motion_evidence(told).motion.rigidity is None and config_hash(told) != config_hash(given)
    assert regularisation(with_motion_evidence(told).motion, "nerfies", "hexplane") == (0.5, 0.5, 0.0)
    unsplit = with_motion_evidence(configs(flow_capture, "--field", "hexplane", "--split.apply", "false")[0])
    assert unsplit.split.apply is False and unsplit.motion.rigidity is None  # the terms, no split
    weighted = with_motion_evidence(configs(flow_capture, "--field", "hexplane", "--motion.rigidity", "0.2")[0])
    assert (weighted.motion.rigidity, weighted.motion.isometry) == (0.2, 0.0)  # a weight given is kept
    for field in ("mlp", "cfc"):  # one network over all of space: split, and no neighbour terms to replace
        network = with_motion_evidence(configs(flow_capture, "--field", field)[0])
        assert network.split.apply is True and network.motion == configs(flow_capture, "--field", field)[0].motion


def test_a_hexplane_run_made_with_the_earlier_defaults_keeps_its_neighbour_terms(flow_capture):
    """Its config.yml holds the flow weight and split.apply false decided then, and no motion weights:
    loaded again it is not re-decided, so it resumes with the terms it trained with."""
    earlier, _ = configs(flow_capture, "--field", "hexplane", "--flow.weight", "0.02", "--split.apply", "false")
    again = with_motion_evidence(earlier)
    assert again == earlier and regularisation(again.motion, "nerfies", "hexplane") == (0.5, 0.5, 0.0)


def test_a_run_says_what_it_decided_from_the_scene(flow_capture, puppet_scene):
    """The decision is printed as a note: what the run trains with and the flags that turn it off;
    nothing where the scene has no flow or every setting was given."""
    split = "the static/dynamic split (--flow.weight 0 --split.apply false to train without)"
    in_place = split.replace("split (", "split in place of the neighbour terms (")
    for field, says in (("mlp", split), ("hexplane", in_place)):
        says = f"training with the flow loss at 0.04 and {says}"
        given, _ = configs(flow_capture, "--field", field)
        note = motion_evidence_note(given, with_motion_evidence(given))
        assert note == f"the scene has optical flow and motion masks at this scale: {says}", note
    for given in (configs(flow_capture)[1], configs(puppet_scene)[0]):
        assert motion_evidence_note(given, with_motion_evidence(given)) is None


def test_tracks_asked_of_flow_computed_before_them_are_one_line(flow_capture, tmp_path):
    """A scene whose flow.json has no tracks (computed before them): `--flow.tracks` is one line
    naming the command that computes them; with the flow loss off it has no effect, also one line."""
    older = Path(shutil.copytree(flow_capture, tmp_path / "older"))
    record_file = older / "flow" / "1x" / "flow.json"
    record = json.loads(record_file.read_text())
    del record["tracks"], record["track_step"]
    record_file.write_text(json.dumps(record))
    with pytest.raises(ConfigError, match=re.escape(f"holds no tracks (computed before them); compute it again: "
                                                     f"liquidgs data flow {older} --downscale 1")):  # fmt: skip
        run_train(["--data", str(older), "--field", "mlp", *RUN, "--flow.tracks", "--out", str(tmp_path / "r")])
    with pytest.raises(ConfigError, match="--flow.tracks has no effect: --flow.weight is 0, so the optical-flow"):
        resolve_config(["--data", str(older), "--preset", "tiny", "--flow.weight", "0", "--flow.tracks"])
    at_half = ["--data", str(older), "--preset", "tiny", "--downscale", "2", "--flow.tracks"]  # its flow is at 1x
    with pytest.raises(ConfigError, match=re.escape("no optical flow at the training scale (liquidgs data flow)")):
        resolve_config(at_half)


def test_stillness_given_where_the_split_holds_static_gaussians_still_is_one_line(flow_capture):
    """The split trains no stillness term (static Gaussians are held still exactly): a stillness weight
    given beside it would change the run's identity and nothing it trains, so it is refused; without
    the split it is read."""
    stillness = ["--data", str(flow_capture), "--preset", "tiny", "--field", "mlp", "--motion.stillness", "0.3"]
    with pytest.raises(ConfigError, match=re.escape("--motion.stillness has no effect: the static/dynamic split "
                                                    "holds the static Gaussians still (decided from the scene's")):
        resolve_config(stillness)
    with pytest.raises(ConfigError, match=re.escape("still; --split.apply false trains the term instead")):
        resolve_config([*stillness, "--split.apply", "true"])
    assert resolve_config([*stillness, "--split.apply", "false"])[0].motion.stillness == 0.3


def test_dnerf_and_a_capture_without_flow_at_its_scale_keep_their_identity(flow_capture, puppet_scene, tmp_path):
    bare = Path(shutil.copytree(flow_capture, tmp_path / "bare", ignore=shutil.ignore_patterns("flow")))
    at_half = (flow_capture, ("--downscale", "2"))  # its flow is at 1x only
    for data, args in ((puppet_scene, ()), (bare, ()), at_half):
        given, before = configs(data, *args)
        decided = with_motion_evidence(given)
        assert decided.flow.weight == 0.0 and decided.split.apply is False, data
        assert "flow" not in identity(given) and "split" not in identity(given)
        assert config_hash(given) == config_hash(before)
    with pytest.raises(ConfigError, match="--split.vote has no effect: the scene has no optical flow at the training"):
        resolve_config(["--data", str(bare), "--preset", "tiny", "--split.vote", "0.3"])


def test_the_paper_specs_train_without_flow_even_where_a_nerfds_scene_has_it(tmp_path):
    root = tmp_path / "root"
    for scene in NERFDS_SCENES:
        (root / "nerfds" / scene / "flow" / "1x").mkdir(parents=True)
        (root / "nerfds" / scene / "dataset.json").write_text("{}")
        (root / "nerfds" / scene / "flow" / "1x" / "flow.json").write_text("{}")  # has_flow looks no further
    runs = expand(BUILTIN_SPECS["paper-nerfds"], root, tmp_path / "e").runs
    assert len(runs) == 3 * len(NERFDS_SCENES)
    for run in runs:
        cfg = run.train_config()
        left = dataclasses.replace(cfg, flow=dataclasses.replace(cfg.flow, weight=None),
                                   split=dataclasses.replace(cfg.split, apply=None))  # fmt: skip
        assert with_motion_evidence(left).flow.weight == DEFAULT_WEIGHT  # the scene has flow...
        assert with_motion_evidence(cfg).flow.weight == 0.0 and with_motion_evidence(cfg).split.apply is False
        assert "flow" not in identity(cfg) and "split" not in identity(cfg)  # ...the spec keeps it off


RUN = tiny_flags({"iterations": 24, "checkpoint_every": 8, "eval.start": 24, "cameras.align_steps": 5})


def test_config_yml_records_the_decision(flow_capture, tmp_path):
    run_train(["--data", str(flow_capture), "--field", "mlp", *RUN, "--iterations", "6", "--eval.start", "6",
               "--out", str(tmp_path / "run")])  # fmt: skip
    stored = load_yaml(tmp_path / "run" / "config.yml")
    assert stored.flow.weight == DEFAULT_WEIGHT and stored.split.apply is True and stored.flow.tracks is False


@pytest.mark.slow
def test_a_run_made_before_the_defaults_resumes_as_it_was_trained(flow_capture, tmp_path, monkeypatch):
    """Its config.yml without `flow` and `split` (written before they existed): it resumes without
    either, on a scene that now has flow, to the last bit of the same run trained whole."""
    flags = ["--data", str(flow_capture), "--field", "mlp", *RUN, *OFF]
    run_train([*flags, "--out", str(tmp_path / "whole")])
    cut = tmp_path / "cut"
    interrupt_at(17, [*flags, "--out", str(cut)], monkeypatch)
    config = cut / "config.yml"
    lines, kept, skipping = config.read_text().splitlines(), [], False
    for line in lines:  # drop the two top-level sections
        if not line.startswith(" "):
            skipping = line in ("flow:", "split:")
        if not skipping:
            kept.append(line)
    assert len(kept) < len(lines)
    config.write_text("\n".join(kept) + "\n")
    run_train(["--out", str(cut), "--resume"])
    a = torch.load(tmp_path / "whole" / "checkpoint.pt", weights_only=True)
    b = torch.load(cut / "checkpoint.pt", weights_only=True)
    for key, value in a["params"].items():
        assert torch.equal(value, b["params"][key]), key
    resumed = load_yaml(config)
    assert resumed.flow.weight == 0.0 and resumed.split.apply is False


@pytest.mark.slow
def test_a_run_trained_at_the_earlier_default_weight_resumes_at_it(flow_capture, tmp_path, monkeypatch):
    """A run whose config.yml holds the flow loss's weight of an earlier default (0.02, decided from the
    scene when it started) resumes at that weight, not at today's DEFAULT_WEIGHT, to the last bit of
    the same run trained whole; its identity stays that weight's."""
    assert DEFAULT_WEIGHT != 0.02
    flags = ["--data", str(flow_capture), "--field", "mlp", *RUN]
    run_train([*flags, "--flow.weight", "0.02", "--out", str(tmp_path / "whole")])
    cut = tmp_path / "cut"
    interrupt_at(17, [*flags, "--flow.weight", "0.02", "--out", str(cut)], monkeypatch)
    recorded = load_yaml(cut / "config.yml")
    assert recorded.flow.weight == 0.02 and recorded.split.apply is True
    run_train(["--out", str(cut), "--resume"])
    a = torch.load(tmp_path / "whole" / "checkpoint.pt", weights_only=True)
    b = torch.load(cut / "checkpoint.pt", weights_only=True)
    for key, value in a["params"].items():
        assert torch.equal(value, b["params"][key]), key
    resumed = load_yaml(cut / "config.yml")
    assert resumed.flow.weight == 0.02 and config_hash(resumed) == config_hash(recorded)
    left = dataclasses.replace(resumed, flow=dataclasses.replace(resumed.flow, weight=None))
    assert with_motion_evidence(left).flow.weight == DEFAULT_WEIGHT  # the same run started today...
    assert config_hash(left) != config_hash(resumed)  # ...is another run, in another folder
