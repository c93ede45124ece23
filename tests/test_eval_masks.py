"""`liquidgs eval --mask DIR` (scores inside and outside per-view masks) and the aligned second score
of a run that refined its cameras."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from liquidgs.cli import main as cli
from liquidgs.data import generate_synthetic, load_dataset
from liquidgs.data.scene import DataConfig
from liquidgs.eval.masks import masked_scores
from shared_data import use_optional_lpips
from tiny_runs import one_line_error, run_train, tiny_flags


def test_masked_scores_keep_the_regions_apart():
    truth = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(0))
    truth = torch.round(truth * 255) / 255
    render = truth.clone()
    render[:, 8:] = torch.round(((render[:, 8:] + 0.1) % 1) * 255) / 255  # wrong on the right half only
    mask = np.zeros((16, 16), bool)
    mask[:, :6] = True  # inside: the left 6 columns, exact there and >= 2 px from the wrong half
    scores = masked_scores([render], [truth], [mask])
    assert scores["inside"]["psnr"] == pytest.approx(120.0) and scores["outside"]["psnr"] < 25
    assert scores["inside"]["ssim"] > scores["outside"]["ssim"]
    assert scores["inside"]["share"] + scores["outside"]["share"] == pytest.approx(1.0)


@pytest.fixture(autouse=True)
def optional_lpips(monkeypatch):
    use_optional_lpips(monkeypatch)


@pytest.fixture(scope="module")
def refined_run(tmp_path_factory) -> tuple[Path, Path]:
    """A 30-iteration run on the puppet's Nerfies layout (a capture: cameras refined) and its scene."""
    root = tmp_path_factory.mktemp("masks")
    scene = generate_synthetic("puppet", root / "puppet", size=24, frames=16, seed=3) / "nerfies"
    out = root / "run"
    flags = tiny_flags({"iterations": 30, "eval.start": 30, "cameras.align_steps": 5})
    run_train(["--data", str(scene), "--field", "mlp", "--out", str(out), *flags])
    return out, scene


def _write_masks(folder: Path, scene: Path, size: tuple[int, int] | None = None, skip: int = 0) -> list[str]:
    folder.mkdir()
    views = load_dataset(DataConfig(path=scene)).test
    for view in views[skip:]:
        width, height = size or (view.camera.width, view.camera.height)
        mask = np.zeros((height, width), np.uint8)
        mask[:, : width // 3] = 255
        Image.fromarray(mask).save(folder / f"{view.name}.png")
    return [view.name for view in views]


def test_eval_scores_given_aligned_and_masked_apart(refined_run, tmp_path, capsys):
    run, scene = refined_run
    _write_masks(tmp_path / "masks", scene)
    assert cli(["eval", "--run", str(run), "--mask", str(tmp_path / "masks")]) == 0
    record = json.loads((run / "eval.json").read_text())
    results = json.loads((run / "results.json").read_text())
    assert record["cameras"] == "as given" and record["psnr"] == pytest.approx(results["final"]["psnr"], abs=1e-6)
    protocol = record["aligned"]["cameras"]  # a capture: its pose and its exposure
    assert protocol.startswith("each test view aligned to the frozen scene") and "rotation and translation" in protocol
    assert "gain and offset" in protocol
    assert record["aligned"]["psnr"] == pytest.approx(results["final_aligned"]["psnr"], abs=1e-6)
    masked = record["masked"]
    assert masked["cameras"] == "as given"
    assert masked["inside"]["share"] == pytest.approx(8 / 24) and masked["outside"]["share"] == pytest.approx(16 / 24)
    assert all(masked[r]["psnr"] > 5 and 0 < masked[r]["ssim"] <= 1 for r in ("inside", "outside"))
    # The refined run is scored inside the masks a second time, from the aligned test cameras, labelled.
    aligned = record["masked_aligned"]
    assert aligned["cameras"] == record["aligned"]["cameras"] and aligned["masks"] == masked["masks"]
    assert aligned["inside"]["share"] == masked["inside"]["share"]
    assert all(aligned[r]["psnr"] > 5 and aligned[r]["psnr"] != masked[r]["psnr"] for r in ("inside", "outside"))
    out = capsys.readouterr().out
    assert "test cameras aligned to the scene: PSNR" in out and "inside the masks (33.3% of pixels)" in out
    assert "inside the masks (33.3% of pixels), test cameras aligned: PSNR" in out


@pytest.mark.parametrize("fault", ["size", "count"])
def test_a_wrong_mask_is_one_line_naming_its_file(refined_run, tmp_path, capsys, fault):
    run, scene = refined_run
    (run / "eval.json").unlink(missing_ok=True)
    names = _write_masks(tmp_path / "masks", scene, size=(20, 24) if fault == "size" else None,
                         skip=1 if fault == "count" else 0)  # fmt: skip
    capsys.readouterr()
    assert cli(["eval", "--run", str(run), "--mask", str(tmp_path / "masks")]) == 2
    line = one_line_error(capsys)
    assert f"{tmp_path / 'masks' / names[0]}.png" in line
    assert ("mask is 20x24, view" in line) if fault == "size" else ("no mask for view" in line)
    assert not (run / "eval.json").exists()


def _mask_images(folder: Path, scene: Path, draw) -> list[str]:
    """One mask per test view, `draw(index, height, width)` giving its image array."""
    folder.mkdir()
    views = load_dataset(DataConfig(path=scene)).test
    for i, view in enumerate(views):
        Image.fromarray(draw(i, view.camera.height, view.camera.width)).save(folder / f"{view.name}.png")
    return [view.name for view in views]


def _left_third(height: int, width: int) -> np.ndarray:
    mask = np.zeros((height, width), np.uint8)
    mask[:, : width // 3] = 255
    return mask


def test_one_empty_view_is_legal_but_a_set_empty_in_every_view_is_one_line_naming_the_folder(refined_run, tmp_path,
                                                                                              capsys):  # fmt: skip
    """The subject may leave the frame: that view adds nothing inside, the others' pixels are pooled. A
    set with no pixel inside in any view (or none outside) leaves a region nothing to score: refused."""
    run, scene = refined_run
    _mask_images(tmp_path / "one", scene, lambda i, h, w: np.zeros((h, w), np.uint8) if i == 0 else _left_third(h, w))
    assert cli(["eval", "--run", str(run), "--mask", str(tmp_path / "one")]) == 0
    masked = json.loads((run / "eval.json").read_text())["masked"]
    views = len(load_dataset(DataConfig(path=scene)).test)
    assert masked["inside"]["share"] == pytest.approx((views - 1) / views * 8 / 24)
    assert masked["inside"]["psnr"] > 5 and masked["outside"]["psnr"] > 5
    for value, words in ((0, "every mask is empty (no nonzero pixel in any view): nothing inside to score"),
                         (255, "every mask covers its whole view: nothing outside to score")):  # fmt: skip
        (run / "eval.json").unlink(missing_ok=True)
        folder = tmp_path / f"all-{value}"
        _mask_images(folder, scene, lambda i, h, w, value=value: np.full((h, w), value, np.uint8))
        capsys.readouterr()
        assert cli(["eval", "--run", str(run), "--mask", str(folder)]) == 2
        assert one_line_error(capsys) == f"liquidgs eval: error: {folder}: --mask: {words}"
        assert not (run / "eval.json").exists()


def test_a_mask_in_alpha_alone_is_read_from_alpha(refined_run, tmp_path):
    """An RGBA mask whose colour is flat white and whose alpha holds the subject: the alpha is the mask,
    scored as the same mask in grey."""
    run, scene = refined_run
    _mask_images(tmp_path / "grey", scene, lambda i, h, w: _left_third(h, w))
    assert cli(["eval", "--run", str(run), "--mask", str(tmp_path / "grey")]) == 0
    grey = json.loads((run / "eval.json").read_text())["masked"]

    def alpha_only(i, h, w):
        rgba = np.full((h, w, 4), 255, np.uint8)
        rgba[..., 3] = _left_third(h, w)
        return rgba

    _mask_images(tmp_path / "alpha", scene, alpha_only)
    assert cli(["eval", "--run", str(run), "--mask", str(tmp_path / "alpha")]) == 0
    alpha = json.loads((run / "eval.json").read_text())["masked"]
    assert {r: alpha[r] for r in ("inside", "outside")} == {r: grey[r] for r in ("inside", "outside")}


def test_a_mask_whose_colour_and_alpha_disagree_is_one_line_naming_its_file(refined_run, tmp_path, capsys):
    run, scene = refined_run
    (run / "eval.json").unlink(missing_ok=True)

    def disagreeing(i, h, w):
        rgba = np.zeros((h, w, 4), np.uint8)
        rgba[..., :3] = _left_third(h, w)[..., None]  # the left third in colour
        rgba[:, -w // 3 :, 3] = 255  # the right third in alpha
        return rgba

    names = _mask_images(tmp_path / "masks", scene, disagreeing)
    capsys.readouterr()
    assert cli(["eval", "--run", str(run), "--mask", str(tmp_path / "masks")]) == 2
    assert one_line_error(capsys) == (f"liquidgs eval: error: {tmp_path / 'masks' / names[0]}.png: --mask: its grey "
                                      "level and its alpha channel mark different pixels (keep the mask in one of "
                                      "them, the other one flat)")  # fmt: skip
    assert not (run / "eval.json").exists()
