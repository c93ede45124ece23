"""A baked scene: a folder that `render`, `eval`, `view` and `export` read like a run, rendered
without evaluating any network.

    config.yml    the source run's configuration, as it was (dataset, background, backend)
    scene.json    the source run's scene print: eval and render refuse a scene that has changed
    cameras.json  the scene's cameras (data.cameras_file): render, view, web and splatv need no scene
    scene.pt      the Gaussians' opacities and SH coefficients (float16; the higher degrees 8-bit
                  codes of each Gaussian's range), and their keyframe tracks
                  (bake/tracks.py: as many keyframes per Gaussian as its motion needs, quantised)
    baked.json    what was baked, from which run (its source record: iteration, checkpoint hash,
                  scene print), scene.pt's hash and the measured error (BAKED_FORMAT); written
                  last, it marks the folder a baked scene

A folder of the format before (liquidgs-baked/2: every Gaussian on the same keyframes, float32,
with the canonical Gaussians) is read as well. A reader refuses, in one line, a folder of an older
format, a scene.pt that is not the one baked,
non-finite values, and a folder whose source run is still where it was but has trained on since.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from liquidgs.bake.motion import CHANNELS, POSITION, QUATERNION, SCALE
from liquidgs.bake.tracks import Tracks, from_row_codes, row_codes, unpack
from liquidgs.cameras import Camera
from liquidgs.data import SceneDataset
from liquidgs.data.cameras_file import CAMERAS_FILE, dataset_from_cameras
from liquidgs.errors import LiquidGSError
from liquidgs.fields.registry import field_names
from liquidgs.gaussians import PARAM_KEYS
from liquidgs.gaussians.model import activate
from liquidgs.settings import load_yaml_file
from liquidgs.train.config import FIELD_PACKAGE, TrainConfig, from_dict
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.model import Deformed, render_frame
from liquidgs.train.run_folder import CONFIG, check_scene_print, check_source, file_sha256, source_record

MANIFEST = "baked.json"
SCENE = "scene.pt"
BAKED_FORMAT = "liquidgs-baked/3"
UNIFORM_FORMAT = "liquidgs-baked/2"
"""Read: every Gaussian on the same keyframes [K, N, 10] in scene.pt's "keyframes", float32."""
OLDER_FORMATS = ("liquidgs-baked/1",)
"""Baked before the folder carried its source, scene print and cameras: refused, to be baked again."""


def is_baked(folder: Path) -> bool:
    return (folder / MANIFEST).is_file()


@dataclass
class BakedRun:
    """The interface of train.run.TrainedRun that readers use, served from keyframes."""

    run_dir: Path
    config: TrainConfig
    params: torch.nn.ParameterDict
    """opacities, sh0, shN as baked; means, quats, scales: the state at time 0 (a baked scene keeps
    no canonical frame: without the field it has no meaning)."""
    tracks: Tracks
    """Per Gaussian keyframes: position, unit quaternion, scale."""
    sh_degree: int
    iteration: int
    manifest: dict
    stored: dict | None
    """scene.pt's payload as stored (stored_scene), for a player that decodes it itself (the web
    export); None for a folder of the format before."""
    field = None
    """No network: readers that need one (field.pt, Monte-Carlo noise) check for None."""
    finished = True
    """bake reads finished runs only."""

    @property
    def progress_label(self) -> str:
        return f"baked scene of {self.manifest['source']['run']} (iteration {self.iteration})"

    @property
    def device(self) -> torch.device:
        return self.params["means"].device

    def source(self) -> dict:
        """The source record of a file derived from this baked scene (its scene.pt)."""
        return source_record(self.run_dir, self.manifest["source"]["config"], self.iteration, self.run_dir / SCENE)

    def scene(self) -> SceneDataset:
        """The scene's cameras: read from the scene folder where it is (checked against the print the
        folder carries), else the cameras the folder carries (no images)."""
        if not self.config.data.path.exists():
            return dataset_from_cameras(
                json.loads((self.run_dir / CAMERAS_FILE).read_text()), self.run_dir / CAMERAS_FILE
            )
        check_scene_print(self.run_dir, self.config.data.path)
        return load_run_dataset(self.config)

    @property
    def keyframes(self) -> torch.Tensor:
        """[K, N, 10]: every Gaussian's track sampled at keyframe_times(K), K the most keyframes of
        any Gaussian (a player that takes one keyframe count plays this)."""
        return self.tracks.uniform()

    @torch.no_grad()
    def at_time(self, time: float) -> Deformed:
        state = self.tracks.at_time(time)
        act = self._activated
        return Deformed(state[:, POSITION], state[:, QUATERNION], state[:, SCALE], act["opacities"], act["colors"])

    @property
    def _activated(self) -> dict[str, torch.Tensor]:
        if not hasattr(self, "_activated_cache"):
            self._activated_cache = activate(self.params)
        return self._activated_cache

    def render(self, camera: Camera, time: float, background, noisy: bool = False):
        if noisy:
            raise LiquidGSError(f"{self.run_dir}: a baked scene has no noise to sample (it holds the field's mean)")
        return render_frame(
            self.at_time(time), camera, sh_degree=self.sh_degree, background=background, backend=self.config.backend
        )


def read_manifest(folder: Path) -> dict:
    """baked.json, with every field a reader uses checked: anything else is one line naming it."""
    path = folder / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise LiquidGSError(f"{path}: unreadable ({err})") from None
    found = manifest.get("format") if isinstance(manifest, dict) else None
    if found in OLDER_FORMATS:
        raise LiquidGSError(
            f"{path}: baked by an older liquidgs ({found}: no source record, scene print or cameras); "
            f"bake the run again ({BAKED_FORMAT})"
        )
    if found not in (BAKED_FORMAT, UNIFORM_FORMAT):
        raise LiquidGSError(f"{path}: format {found!r} is neither {BAKED_FORMAT!r} nor {UNIFORM_FORMAT!r}")
    for key, kind in (("sh_degree", int), ("iteration", int), ("field", str), ("source", dict), ("scene_sha256", str)):
        if not isinstance(manifest.get(key), kind) or isinstance(manifest.get(key), bool):
            raise LiquidGSError(
                f"{path}: field '{key}' is missing or not {'an integer' if kind is int else kind.__name__}"
            )
    if not 0 <= manifest["sh_degree"] <= 3:
        raise LiquidGSError(f"{path}: field 'sh_degree' must be 0..3, got {manifest['sh_degree']}")
    return manifest


def load_baked_config(path: Path) -> TrainConfig:
    """config.yml of a baked folder. A baked scene needs no field, so one whose field's package is no
    longer installed still reads: its config is read as a static run's, with the field's name kept."""
    raw = load_yaml_file(path, "run config")
    if not isinstance(raw, dict) or "data" not in raw:
        raise LiquidGSError(f"{path}: not a liquidgs run config (no 'data')")
    name = raw.get("field")
    raw.pop(FIELD_PACKAGE, None)
    if isinstance(name, str) and name not in field_names():
        raw = {**raw, "field": "static", "field_options": {}, "lambda_": None}
    cfg = from_dict(raw, path)
    if isinstance(name, str):
        cfg.field = name  # the label readers print; a baked scene never builds its field
    return cfg


def load_baked(folder: str | Path, device: str | torch.device = "cpu") -> BakedRun:
    folder = Path(folder)
    manifest = read_manifest(folder)
    scene_path = folder / SCENE
    if not scene_path.is_file() or file_sha256(scene_path) != manifest["scene_sha256"]:
        raise LiquidGSError(f"{scene_path}: missing, or not the scene.pt baked into this folder (its hash differs)")
    source = manifest["source"]
    check_source(folder / MANIFEST, source, again=f"bake it again (liquidgs bake --run {source.get('run')})")
    if not (folder / CAMERAS_FILE).is_file():
        raise LiquidGSError(f"{folder / CAMERAS_FILE}: missing; bake the run again")
    cfg = load_baked_config(folder / CONFIG)
    try:
        payload = torch.load(scene_path, map_location="cpu", weights_only=True)
        params, tracks, bad = scene_payload(payload, manifest["format"])
    except Exception as err:  # noqa: BLE001 - any unpickling or layout failure is a damaged or unsafe file
        first = (str(err).strip().splitlines() or [""])[0][:200]
        raise LiquidGSError(f"{scene_path}: unreadable baked scene ({type(err).__name__}: {first})") from None
    if bad:
        raise LiquidGSError(f"{scene_path}: {bad} non-finite values (NaN or infinity); bake the run again")
    tracks = Tracks(tracks.counts.to(device), [(i.to(device), k.to(device)) for i, k in tracks.groups])
    state = tracks.at_time(0.0)
    if manifest["format"] == BAKED_FORMAT:
        scales = torch.log(state[:, SCALE].abs().clamp_min(1e-12))
        params.update(means=state[:, POSITION], quats=state[:, QUATERNION], scales=scales)
    params = torch.nn.ParameterDict(
        {k: torch.nn.Parameter(params[k].float().to(device), requires_grad=False) for k in PARAM_KEYS}
    )
    stored = payload if manifest["format"] == BAKED_FORMAT else None
    return BakedRun(folder, cfg, params, tracks, manifest["sh_degree"], manifest["iteration"], manifest, stored)


def scene_payload(payload: dict, found: str) -> tuple[dict[str, torch.Tensor], Tracks, int]:
    """scene.pt's Gaussians, tracks and how many of its stored numbers are NaN or infinite;
    ValueError or KeyError where its layout is not the format's."""
    if found == UNIFORM_FORMAT:
        params = {k: payload["params"][k].float() for k in PARAM_KEYS}
        keyframes = payload["keyframes"].float()
        n = params["means"].shape[0]
        if keyframes.ndim != 3 or keyframes.shape[1:] != (n, CHANNELS) or keyframes.shape[0] < 1:
            raise ValueError(f"keyframes {tuple(keyframes.shape)} do not fit {n} Gaussians")
        return params, Tracks.from_keyframes(keyframes), non_finite([*params.values(), keyframes])
    params = {k: payload["params"][k].float() for k in STORED_PARAMS}
    params["shN"] = from_row_codes(payload["sh_rest"])
    n = params["opacities"].shape[0]
    if any(value.shape[0] != n for value in params.values()):
        raise ValueError(f"opacities and SH coefficients of {n} Gaussians disagree in number")
    stored = payload["tracks"]
    return params, unpack(stored, n), non_finite([*params.values(), stored["low"], stored["span"]])


def stored_scene(params, stored_tracks: dict[str, torch.Tensor]) -> dict:
    """scene.pt's payload: the Gaussians' STORED_PARAMS in float16, their higher SH coefficients as
    8-bit codes of each Gaussian's range, and their tracks as tracks.pack() stores them."""
    return {
        "params": {k: params[k].detach().cpu().to(torch.float16).contiguous() for k in STORED_PARAMS},
        "sh_rest": row_codes(params["shN"]),
        "tracks": stored_tracks,
    }


def non_finite(tensors: list[torch.Tensor]) -> int:
    return sum(int((~torch.isfinite(t.float())).sum()) for t in tensors)


STORED_PARAMS = ("opacities", "sh0")
"""What a baked scene keeps of the run's parameters in float16; the higher SH coefficients (shN)
are 8-bit codes of each Gaussian's range (tracks.row_codes: on the demo's HexPlane run and the cat
clip's CfC run no test view moved by 0.1 dB), its tracks hold the rest."""
