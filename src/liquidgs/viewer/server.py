"""The browser viewer: a viser server whose background image is rendered here, by `rasterize`.

Each connected browser gets a render thread. It renders whenever the camera or a control
changed: at `moving_side` pixels (longest side) while the camera moves, at `max_side` once
it has rested for REST_SECONDS. The frame rate shown is measured on the frames sent.
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import viser
import viser.transforms as vtf
from matplotlib import colormaps
from PIL import Image

from liquidgs.atomic import WriteRefused
from liquidgs.cameras import Camera
from liquidgs.data.scene import Frame
from liquidgs.media import labelled, to_uint8
from liquidgs.render.camera_path import PathCamera, write_camera_path
from liquidgs.viewer.scenes import PlyScene, RunScene, scene_centre_and_radius

REST_SECONDS = 0.3
# Frames closer than this in time count as a stream (playing, dragging): its rate is shown.
IDLE_SECONDS = 0.5
DEFAULT_MAX_SIDE = 256
JPEG_QUALITY = 90
SNAP_TOLERANCE = 1e-3


def fit_size(aspect: float, side: int) -> tuple[int, int]:
    """(width, height) with the longest side `side` and the given width / height."""
    if aspect >= 1.0:
        return side, max(1, round(side / aspect))
    return max(1, round(side * aspect)), side


def camera_to_world(wxyz, position) -> np.ndarray:
    c2w = np.eye(4)
    c2w[:3, :3] = vtf.SO3(np.asarray(wxyz, dtype=np.float64)).as_matrix()
    c2w[:3, 3] = position
    return c2w


def free_camera(c2w: np.ndarray, fov: float, width: int, height: int) -> Camera:
    """The browser's camera (vertical fov in radians) as a pinhole of width x height."""
    return Camera.from_camera_to_world(c2w, fov, width, height)


def letterbox(frame: Frame, width: int, height: int) -> tuple[Camera, tuple[int, int, int, int]]:
    """The dataset camera fitted, centred, into width x height, and its image's box (x0, y0, w, h).

    Inside the box the view is the dataset camera's own (its intrinsics, scaled), so it can be
    compared with `liquidgs render`'s image of that camera and overlaid with the ground truth.
    """
    camera = frame.camera
    scale = min(width / camera.width, height / camera.height)
    box_w, box_h = round(camera.width * scale), round(camera.height * scale)
    x0, y0 = (width - box_w) // 2, (height - box_h) // 2
    K = camera.K.clone().float()
    K[:2] *= scale
    K[0, 2] += x0
    K[1, 2] += y0
    return Camera(camera.viewmat.float(), K, width, height), (x0, y0, box_w, box_h)


def heat_map(std: torch.Tensor) -> tuple[np.ndarray, float]:
    """Standard deviation [H,W] as an inferno heat map scaled to its largest value."""
    peak = float(std.max()) or 1.0
    rgb = colormaps["inferno"]((std / peak).clamp(0, 1).numpy())[..., :3]
    return (rgb * 255 + 0.5).astype(np.uint8), peak


@dataclass
class FrameStats:
    """Exponential moving average of the time per frame sent: render + encode + send, or the
    interval between frames when they follow each other without a pause."""

    seconds: float = 0.0
    frames: int = 0

    def add(self, seconds: float) -> None:
        self.seconds = seconds if self.frames == 0 else 0.8 * self.seconds + 0.2 * seconds
        self.frames += 1

    @property
    def fps(self) -> float:
        return 1.0 / self.seconds if self.seconds > 0 else 0.0


class Viewer:
    """A viser server showing `scenes`; controls are shared by all browsers, cameras are per browser."""

    def __init__(
        self,
        scenes: list[RunScene] | list[PlyScene],
        host: str = "127.0.0.1",
        port: int = 8080,
        max_side: int = DEFAULT_MAX_SIDE,
        camera_path_file: Path | None = None,
    ):
        self.scenes = scenes
        self.runs = [s for s in scenes if isinstance(s, RunScene)]
        self.max_side = max_side
        self.stats = FrameStats()
        self.keyframes: list[PathCamera] = []
        self.version = 0  # bumped by every control change; render threads compare it
        self.frames_sent = 0
        self.last_sent: dict | None = None
        self._stopping = threading.Event()
        self._lock = threading.Lock()
        self._snapped: dict[int, tuple[Frame, np.ndarray]] = {}
        self._camera_ready: dict[int, threading.Event] = {}
        self._path_size: dict[int, tuple[int, int]] = {}
        self._render_threads: list[threading.Thread] = []
        self.cameras = self._dataset_cameras()
        if self.runs:
            up = -torch.stack([f.camera.viewmat[1, :3] for f in self.runs[0].dataset.train]).mean(0)
            self.up = (up / up.norm()).double().numpy()
            default_path = self.runs[0].run.run_dir / "camera_paths" / "camera_path.json"
        else:
            self.up = np.array([0.0, 0.0, 1.0])
            default_path = Path("camera_path.json")
        points = self.runs[0].run.params["means"] if self.runs else scenes[0].frames[0]["means"]
        self.centre, self.radius = scene_centre_and_radius(points.detach().float().cpu())

        # A frame finished just after its browser went away is dropped by viser, which warns; expected here.
        warnings.filterwarnings("ignore", message="Queued a BackgroundImageMessage on a closed connection")
        with contextlib.redirect_stdout(sys.stderr):  # viser's banner; our stdout is the URL (or JSON)
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.gui.configure_theme(control_width="medium", show_share_button=False)
        self.server.gui.main_panel.dock_right()  # beside the picture, not over it (side by side)
        self.server.scene.set_up_direction(tuple(self.up))
        self.server.scene.world_axes.visible = False
        self._build_gui(camera_path_file or default_path)
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(lambda client: self._camera_ready.pop(client.client_id, None))
        self._player = threading.Thread(target=self._playback, name="viewer-playback", daemon=True)
        self._player.start()

    # ----- controls -------------------------------------------------------------------------
    def _build_gui(self, camera_path_file: Path) -> None:
        gui = self.server.gui
        self.fps_text = gui.add_markdown("fps: -")
        with gui.add_folder("Time"):
            self.time_slider = gui.add_slider("time", min=0.0, max=1.0, step=0.001, initial_value=0.0)
            self.play = gui.add_checkbox("play", initial_value=False)
            self.sweep_seconds = gui.add_slider("seconds per sweep", min=1.0, max=30.0, step=0.5, initial_value=5.0)
            self.loop = gui.add_checkbox("loop", initial_value=True)
        with gui.add_folder("View"):
            labels = [s.label for s in self.scenes]
            self.scene_choice = gui.add_dropdown("run", labels, initial_value=labels[0])
            self.side_by_side = gui.add_checkbox("side by side", initial_value=False, disabled=len(self.scenes) < 2)
            top = max(1024, self.max_side)  # --resolution may ask for more than the slider's usual range
            self.resolution = gui.add_slider("resolution", min=32, max=top, step=32, initial_value=self.max_side)
            noisy = any(s.has_noise for s in self.scenes)
            self.uncertainty = gui.add_checkbox("uncertainty (sde)", initial_value=False, disabled=not noisy)
            self.samples = gui.add_slider("MC samples", min=2, max=32, step=1, initial_value=8, disabled=not noisy)
            self.uncertainty_text = gui.add_markdown("")
            split = any(s.has_split for s in self.scenes)
            self.split_view = gui.add_checkbox("static / dynamic", initial_value=False, disabled=not split)
        if self.cameras:
            with gui.add_folder("Cameras"):
                names = list(self.cameras)
                self.camera_choice = gui.add_dropdown("camera", names, initial_value=names[0])
                go = gui.add_button("Go to camera")
                go.on_click(lambda event: self.jump(event.client, self.cameras[self.camera_choice.value]))
                self.ground_truth = gui.add_checkbox("ground truth", initial_value=False)
        with gui.add_folder("Camera path"):
            add = gui.add_button("Add keyframe")
            add.on_click(lambda event: self.add_keyframe(event.client))
            clear = gui.add_button("Clear keyframes")
            clear.on_click(lambda _: self.clear_keyframes())
            self.path_seconds = gui.add_number("seconds", initial_value=4.0, min=0.1, max=3600.0, step=0.1)
            self.path_fps = gui.add_number("fps", initial_value=24, min=1, max=240, step=1)
            self.path_file = gui.add_text("file", initial_value=str(camera_path_file))
            save = gui.add_button("Save camera path")
            save.on_click(lambda event: self.save_camera_path(event.client))
            self.path_text = gui.add_markdown("0 keyframes")
        controls = [self.time_slider, self.scene_choice, self.side_by_side, self.resolution]
        controls += [self.uncertainty, self.samples, self.split_view] + ([self.ground_truth] if self.cameras else [])
        for control in controls:
            control.on_update(lambda _: self._changed())

    def _dataset_cameras(self) -> dict[str, Frame]:
        if not self.runs:
            return {}
        dataset = self.runs[0].dataset
        cameras = {}
        for split, frames in (("test", dataset.test), ("train", dataset.train)):
            for i, frame in enumerate(frames):
                cameras[f"{split} {i}: {frame.name} (t={frame.time:.3f})"] = frame
        return cameras

    def _changed(self) -> None:
        with self._lock:
            self.version += 1

    # ----- camera ---------------------------------------------------------------------------
    def _on_connect(self, client: viser.ClientHandle) -> None:
        ready = threading.Event()
        self._camera_ready[client.client_id] = ready
        client.camera.on_update(lambda _: ready.set())
        thread = threading.Thread(target=self._client_loop, args=(client, ready), name="viewer-render", daemon=True)
        self._render_threads.append(thread)
        thread.start()

    def _set_camera(self, client: viser.ClientHandle, c2w: np.ndarray, look_at: np.ndarray, fov: float) -> None:
        with client.atomic():
            client.camera.fov = fov
            client.camera.position = c2w[:3, 3]
            client.camera.look_at = look_at
            client.camera.up_direction = -c2w[:3, 1]

    def jump(self, client: viser.ClientHandle, frame: Frame) -> None:
        """Put the client's camera at a dataset camera and the time at its frame time."""
        camera = frame.camera
        c2w = camera.camera_to_world()
        distance = max(float(np.dot(self.centre - c2w[:3, 3], c2w[:3, 2])), 1e-3)
        ready = self._camera_ready.get(client.client_id)
        aspect = client.camera.aspect if ready is not None and ready.is_set() else 1.0
        # The vertical field of view that shows the whole image in a canvas of this aspect.
        half_height = 0.5 * max(camera.height, camera.width / aspect) / float(camera.K[1, 1])
        self.play.value = False
        self._snapped[client.client_id] = (frame, c2w)
        self._set_camera(client, c2w, c2w[:3, 3] + distance * c2w[:3, 2], 2.0 * math.atan(half_height))
        self.time_slider.value = frame.time
        self._changed()

    def _snapped_frame(self, client: viser.ClientHandle, c2w: np.ndarray) -> Frame | None:
        snapped = self._snapped.get(client.client_id)
        if snapped is None or not np.allclose(snapped[1], c2w, atol=SNAP_TOLERANCE):
            return None
        return snapped[0]

    def _initial_view(self, client: viser.ClientHandle) -> None:
        if self.cameras:
            test = [f for name, f in self.cameras.items() if name.startswith("test")]
            self.jump(client, (test or list(self.cameras.values()))[0])
            return
        eye = self.centre + 3.0 * self.radius * np.array([1.0, -1.0, 0.6]) / np.linalg.norm([1.0, -1.0, 0.6])
        with client.atomic():
            client.camera.position = eye
            client.camera.look_at = self.centre
            client.camera.up_direction = self.up

    # ----- rendering ------------------------------------------------------------------------
    def _client_loop(self, client: viser.ClientHandle, ready: threading.Event) -> None:
        if not ready.wait(timeout=30.0):
            return
        self._initial_view(client)
        rendered, previous_end = None, None
        while not self._stopping.is_set() and client.client_id in self._camera_ready:
            camera = client.camera
            moving = time.time() - camera.update_timestamp < REST_SECONDS
            side = max(32, self.resolution.value // 2) if moving else int(self.resolution.value)
            state = (tuple(camera.wxyz), tuple(camera.position), camera.fov, camera.aspect, side, self.version)
            if state == rendered:
                if previous_end is not None and time.perf_counter() - previous_end > IDLE_SECONDS:
                    previous_end = None  # the picture rested: the next frame is timed on its own
                time.sleep(0.01)
                continue
            start = time.perf_counter()
            c2w = camera_to_world(camera.wxyz, camera.position)
            width, height = fit_size(camera.aspect, side)
            image, info = self.render_view(client, c2w, camera.fov, width, height)
            try:
                client.scene.set_background_image(image, format="jpeg", jpeg_quality=JPEG_QUALITY)
            except Exception:  # the browser went away while we rendered
                if client.client_id not in self._camera_ready:
                    return
                raise
            end = time.perf_counter()
            self.stats.add(end - (previous_end if previous_end is not None else start))
            rendered, previous_end = state, end
            self._path_size[client.client_id] = (width, height)
            self.frames_sent += 1
            self.last_sent = {"time": self.time_slider.value, "side": side, "moving": moving, **info}
            self.fps_text.content = (
                f"**{self.stats.fps:.1f} fps** at {width}x{height}{' (moving)' if moving else ''}, "
                f"{self.stats.seconds * 1000:.0f} ms/frame"
            )

    def render_view(self, client, c2w: np.ndarray, fov: float, width: int, height: int) -> tuple[np.ndarray, dict]:
        """The picture for one client's camera: the chosen run, side by side runs, or uncertainty."""
        t = float(self.time_slider.value)
        snapped = self._snapped_frame(client, c2w) if client is not None else None
        scene = next(s for s in self.scenes if s.label == self.scene_choice.value)
        info: dict = {"snapped": snapped.name if snapped is not None else None}
        if self.side_by_side.value and len(self.scenes) > 1:
            panel = max(1, width // len(self.scenes))
            camera = free_camera(c2w, fov, panel, height)
            panels = [labelled(to_uint8(s.render(camera, t)), s.label) for s in self.scenes]
            return np.concatenate(panels, axis=1), {**info, "mode": "side by side"}
        if snapped is not None:
            camera, box = letterbox(snapped, width, height)
        else:
            camera, box = free_camera(c2w, fov, width, height), None
        if self.uncertainty.value and scene.has_noise:
            image, peak = heat_map(scene.uncertainty(camera, t, int(self.samples.value)))
            self.uncertainty_text.content = f"heat map: black = 0, yellow = std {peak:.4f} (mean over RGB)"
            return image, {**info, "mode": "uncertainty", "peak_std": peak}
        if self.split_view.value and scene.has_split:  # static blue, dynamic orange
            return to_uint8(scene.render_split(camera, t)), {**info, "mode": "static / dynamic"}
        image = to_uint8(scene.render(camera, t))
        # A baked scene away from its scene folder has its cameras, not their images.
        if snapped is not None and self.cameras and self.ground_truth.value and snapped.image_path.is_file():
            x0, y0, box_w, box_h = box
            truth = Image.fromarray(snapped.image_uint8()).resize((box_w, box_h), Image.BILINEAR)
            image = image.copy()
            image[y0 : y0 + box_h, x0 : x0 + box_w] = np.asarray(truth)
            return image, {**info, "mode": "ground truth"}
        return image, {**info, "mode": "render"}

    def _playback(self) -> None:
        last = time.perf_counter()
        while not self._stopping.wait(1 / 30):
            now = time.perf_counter()
            step, last = (now - last) / float(self.sweep_seconds.value), now
            if not self.play.value:
                continue
            t = self.time_slider.value + step
            if t > 1.0 and not self.loop.value:
                # The slider before the checkbox: whoever sees playback stop sees the sweep's end.
                self.time_slider.value = 1.0
                self.play.value = False
                continue
            self.time_slider.value = t - math.floor(t) if t > 1.0 else t

    # ----- camera paths ---------------------------------------------------------------------
    def add_keyframe(self, client: viser.ClientHandle) -> None:
        camera = client.camera
        c2w = camera_to_world(camera.wxyz, camera.position)
        self.keyframes.append(PathCamera(c2w, math.degrees(camera.fov), float(self.time_slider.value)))
        self.path_text.content = f"{len(self.keyframes)} keyframes"

    def clear_keyframes(self) -> None:
        self.keyframes.clear()
        self.path_text.content = "0 keyframes"

    def save_camera_path(self, client: viser.ClientHandle | None) -> Path | None:
        if not self.keyframes:
            self.path_text.content = "no keyframes to save: add some first"
            return None
        key = client.client_id if client is not None else None
        width, height = self._path_size.get(key, fit_size(1.0, self.max_side))
        path = Path(self.path_file.value).expanduser()
        try:
            written = write_camera_path(
                path, self.keyframes, width, height, float(self.path_fps.value), float(self.path_seconds.value)
            )
        except WriteRefused as err:  # a full disk, a read-only folder: the line names the file
            self.path_text.content = str(err)
            return None
        except OSError as err:
            self.path_text.content = f"could not write {path}: {err.strerror or err}"
            return None
        self.path_text.content = f"{len(self.keyframes)} keyframes saved to `{written}`"
        if self.runs:
            command = f"liquidgs render --run {self.runs[0].run.run_dir} --camera-path {written}"
            self.path_text.content += f"\n\nRender it: `{command}`"
        return written

    # ----- life cycle -----------------------------------------------------------------------
    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'[' + host + ']' if ':' in host else host}:{self.server.get_port()}"

    def stop(self) -> None:
        self._stopping.set()
        for thread in self._render_threads:  # let a frame being rendered finish before the server goes
            thread.join(timeout=10.0)
        with contextlib.redirect_stdout(sys.stderr):
            self.server.stop()
