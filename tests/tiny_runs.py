"""Small training runs and the CLI as the tests drive them: the one tiny-run setting set, and the
helpers that run `liquidgs train` / the CLI and read what they left.

A test that needs a setting other than TINY_RUN's passes it as a change, e.g.
`tiny_flags({"iterations": 10})`; the reason belongs next to that change.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config, train
from liquidgs.settings import to_flags
from liquidgs.train.config import TrainConfig
from liquidgs.train.run_folder import RunResults, file_sha256
from liquidgs.train.trainer import Trainer

# The tiny preset cut to a few seconds: 40 iterations of a few hundred Gaussians, densifying from
# step 5 with an opacity reset at 15 and 30, evaluated at 20 and 40, a checkpoint every 10 steps.
TINY_RUN = {
    "iterations": 40, "warmup": 5, "init_points": 300, "sh_interval": 10,
    "densify.start": 5, "densify.interval": 5, "densify.opacity_reset_interval": 15,
    "eval.start": 20, "eval.every": 20, "eval.fps_frames": 1, "checkpoint_every": 10,
}  # fmt: skip
TINY_PRESET = "tiny"


def tiny_overrides(changes: dict | None = None, drop: tuple[str, ...] = ()) -> dict:
    """TINY_RUN with `changes` and without the settings in `drop`, as an experiment spec's overrides."""
    settings = {**TINY_RUN, **(changes or {})}
    return {key: value for key, value in settings.items() if key not in drop}


def tiny_flags(changes: dict | None = None, drop: tuple[str, ...] = ()) -> list[str]:
    """The same as `liquidgs train` flags (named by liquidgs.settings, their owner), with the preset."""
    return ["--preset", TINY_PRESET, *to_flags(TrainConfig, tiny_overrides(changes, drop))]


def run_train(args: list[str]) -> RunResults:
    """`liquidgs train ARGS` in this process; its results."""
    cfg, run_dir = resolve_config(args)
    return train(cfg, run_dir)


def interrupt_at(step_to_stop: int, args: list[str], monkeypatch) -> None:
    """`liquidgs train ARGS` stopped like Ctrl-C when it reaches step `step_to_stop` (the checkpoints
    before it are kept)."""
    original = Trainer.train_step

    def stop(self, step):
        if step == step_to_stop:
            raise KeyboardInterrupt
        return original(self, step)

    monkeypatch.setattr(Trainer, "train_step", stop)
    with pytest.raises(KeyboardInterrupt):
        run_train(args)
    monkeypatch.setattr(Trainer, "train_step", original)


def run_cli(args: list[str]) -> tuple[int, str, str]:
    """The CLI in this process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli(args)
    return code, out.getvalue(), err.getvalue()


def one_line_error(capsys) -> str:
    """The command's error line: the last on stderr, the only one from liquidgs, no traceback
    (training may have drawn its progress bar before it)."""
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("liquidgs ")]
    assert "Traceback" not in err and len(errors) == 1 and lines[-1] == errors[0], err
    return errors[0]


def snapshot(*folders: Path) -> dict[str, tuple[int, bytes] | None]:
    """Every folder (None) and file (modification time, bytes) under `folders`: equal snapshots
    mean nothing was created, removed or written there."""
    return {
        str(path): (path.stat().st_mtime_ns, path.read_bytes()) if path.is_file() else None
        for folder in folders
        if folder.exists()
        for path in sorted(folder.rglob("*"))
    }


def coloured_bake(run: Path, out: Path) -> Path:
    """The tiny run baked with few keyframes, then made opaque and coloured at random (SH of every
    degree): 40 iterations leave the Gaussians nearly transparent and grey, which gives a player or
    a file format nothing to get wrong."""
    import torch

    from liquidgs.bake.tracks import from_row_codes, row_codes

    few = ["--min-keyframes", "5", "--max-keyframes", "9"]  # players are compared with this bake, not the field
    code, _, err = run_cli(["bake", "--run", str(run), "--out", str(out), *few])
    assert code == 0, err
    scene = out / "scene.pt"
    payload = torch.load(scene, weights_only=True)
    params = payload["params"]
    generator = torch.Generator().manual_seed(0)
    params["opacities"] += 4.0
    params["sh0"] = (torch.rand(params["sh0"].shape, generator=generator) * 3 - 1.5).to(params["sh0"].dtype)
    # The higher SH as the baked format stores them: 8-bit codes of each Gaussian's range.
    sh_rest_shape = from_row_codes(payload["sh_rest"]).shape
    payload["sh_rest"] = row_codes((torch.rand(sh_rest_shape, generator=generator) - 0.5) * 0.4)
    torch.save(payload, scene)
    rehash_baked_scene(out)  # the folder's record of its scene.pt, as a bake of it would write
    return out


def rehash_baked_scene(baked: Path) -> None:
    """Record a hand-edited baked scene.pt in its baked.json, as a bake that wrote it would have."""
    manifest_path = baked / "baked.json"
    manifest = json.loads(manifest_path.read_text())
    manifest["scene_sha256"] = file_sha256(baked / "scene.pt")
    manifest_path.write_text(json.dumps(manifest))
