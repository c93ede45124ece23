"""`liquidgs bake`: keyframed motion (bake/motion.py), its distillation within an error budget
(bake/distil.py) on analytic motions, and a baked tiny run read by render, eval, export and the
viewer like a run; bad input is one line, exit 2, nothing written."""

from __future__ import annotations

import json
import math
import shutil
import struct
import types
from pathlib import Path

import numpy as np
import pytest
import torch

from liquidgs.bake.distil import BakeSettings, distil
from liquidgs.bake.motion import QUATERNION, align_quaternion_signs, interpolate, keyframe_times, pack_keyframe
from liquidgs.bake.scene import BakedRun
from liquidgs.bake.tracks import Tracks, from_row_codes, pack, row_codes, unpack
from liquidgs.cameras import Camera, look_at
from liquidgs.eval.metrics import psnr
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.model import Deformed
from liquidgs.train.run import load_run
from tiny_runs import one_line_error, rehash_baked_scene, run_cli, snapshot


@pytest.fixture(autouse=True)
def _one_thread(one_torch_thread):
    yield


def axis_angle_quats(angle: torch.Tensor) -> torch.Tensor:
    """Rotations about z by `angle` [N], wxyz."""
    zeros = torch.zeros_like(angle)
    return torch.stack([torch.cos(angle / 2), zeros, zeros, torch.sin(angle / 2)], dim=-1)


class AnalyticRun:
    """A stand-in for a trained run whose Gaussians follow `path(t) -> means [N,3]`."""

    def __init__(self, path, n: int, size: float = 0.1, spin: float = 1.0):
        self.path = path
        self.n = n
        self.size = size
        self.spin = spin
        self.params = {"opacities": torch.zeros(n)}  # opacity 0.5: every Gaussian is checked

    def at_time(self, time: float) -> Deformed:
        means = self.path(time)
        scales = torch.full((self.n, 3), self.size)
        return Deformed(means, axis_angle_quats(torch.full((self.n,), self.spin * time)), scales, None, None)


def keyframes_of(run: AnalyticRun, count: int) -> torch.Tensor:
    return torch.stack(
        [pack_keyframe(g.means, g.quats, g.scales) for g in map(run.at_time, keyframe_times(count).tolist())]
    )


def test_spline_passes_through_keyframes_and_reproduces_quadratic_motion():
    quadratic = AnalyticRun(lambda t: torch.tensor([[t, t * t - t, 2.0]]), 1)
    keyframes = keyframes_of(quadratic, 9)
    for t in keyframe_times(9).tolist():
        assert torch.allclose(interpolate(keyframes, t), keyframes_of(quadratic, 9)[round(t * 8)], atol=1e-6)
    for t in (0.2, 0.31, 0.5, 0.77):  # interior segments: central-difference tangents are exact for quadratics
        assert torch.allclose(interpolate(keyframes, t)[:, :3], quadratic.path(t), atol=1e-6)
    linear = AnalyticRun(lambda t: torch.tensor([[3 * t, -t, 1.0]]), 1)
    for t in (0.0, 0.05, 0.99, 1.0):  # the end segments' mirrored phantom keyframes are exact for lines
        assert torch.allclose(interpolate(keyframes_of(linear, 5), t)[:, :3], linear.path(t), atol=1e-6)
    assert torch.allclose(interpolate(keyframes, 0.43)[:, QUATERNION].norm(dim=-1), torch.ones(1))


def catmull_rom(keyframes: torch.Tensor, time: float) -> torch.Tensor:
    """motion.interpolate spelled out: the cubic Hermite polynomial with central-difference tangents
    and mirrored phantom keyframes at the ends, then the quaternion renormalised."""
    count = keyframes.shape[0]
    u = min(max(time, 0.0), 1.0) * (count - 1)
    i = min(int(u), count - 2)
    f = u - i
    p1, p2 = keyframes[i].double(), keyframes[i + 1].double()
    p0 = keyframes[i - 1].double() if i > 0 else 2 * p1 - p2
    p3 = keyframes[i + 2].double() if i + 2 < count else 2 * p2 - p1
    state = 0.5 * (2 * p1 + (p2 - p0) * f + (2 * p0 - 5 * p1 + 4 * p2 - p3) * f**2 + (3 * p1 - p0 - 3 * p2 + p3) * f**3)
    state[:, QUATERNION] = torch.nn.functional.normalize(state[:, QUATERNION], dim=-1)
    return state


@pytest.mark.parametrize("count", [2, 3, 4, 9])
def test_spline_weights_equal_the_polynomial(count):
    keyframes = torch.randn(count, 50, 10, generator=torch.Generator().manual_seed(count))
    before = keyframes.clone()
    for t in [0.0, 1e-9, 0.1, 0.26, 0.5, 0.62, 0.87, 0.999, 1.0, -0.5, 1.5, *keyframe_times(count).tolist()]:
        assert torch.allclose(interpolate(keyframes, t).double(), catmull_rom(keyframes, t), atol=2e-6), (count, t)
    assert torch.equal(keyframes, before)  # the keyframes are read, never written


def test_quaternion_signs_follow_the_keyframe_before():
    quats = axis_angle_quats(torch.linspace(0, 1, 3))
    keyframes = torch.zeros(3, 1, 10)
    keyframes[:, 0, QUATERNION] = quats * torch.tensor([1.0, -1.0, 1.0])[:, None]
    aligned = align_quaternion_signs(keyframes)
    assert torch.allclose(aligned[:, 0, QUATERNION], quats)
    # Without alignment the spline would swing through the opposite hemisphere half-way.
    halfway = interpolate(aligned, 0.25)[0, QUATERNION]
    assert torch.allclose(halfway, axis_angle_quats(torch.tensor(0.25)), atol=1e-3)


def test_each_gaussian_gets_the_keyframes_its_motion_needs():
    def paths(t: float) -> torch.Tensor:
        wave = 0.5 * math.sin(6 * math.pi * t)
        return torch.tensor([[0.3, 0.2, 1.0], [0.8 * t, 0.0, 0.0], [wave, 0.0, 0.0]])  # still, line, three periods

    run = AnalyticRun(paths, 3, spin=0.0)
    distilled = distil(run, BakeSettings(tolerance=0.1, min_keyframes=5, max_keyframes=129))
    report = distilled.report
    assert report["gaussians_over_budget"] == 0 and report["max_relative_error"] <= 0.1
    counts = distilled.tracks.counts.tolist()
    assert counts[:2] == [1, 5] and counts[2] in (17, 33, 65)  # 5: the fewest for a Gaussian that moves
    assert sum(int(c) for c in report["keyframe_counts"].values()) == 3
    # The count before the wave's did not hold the budget: the ladder stopped at the first that does.
    coarser = keyframes_of(run, (counts[2] + 1) // 2)[:, 2:]
    times = keyframe_times(2 * 129 - 1)
    error = max(float((interpolate(coarser, t)[:, :3] - paths(t)[2:]).norm()) for t in times.tolist())
    assert error > 0.75 * 0.1 * run.size
    for t in (0.0, 0.13, 0.5, 0.91):  # the tracks as stored (quantised) stay within the budget
        assert float((distilled.tracks.at_time(t)[:, :3] - paths(t)).norm(dim=-1).max()) <= 0.1 * run.size


def test_motion_beyond_the_budget_is_baked_and_located():
    def jump(t: float) -> torch.Tensor:
        means = torch.zeros(3, 3)
        means[1, 0] = 1.0 if t >= 0.6 else 0.0  # Gaussian 1 teleports at t = 0.6; the others rest
        return means

    distilled = distil(AnalyticRun(jump, 3, spin=0.0), BakeSettings(tolerance=0.1, min_keyframes=3, max_keyframes=17))
    assert distilled.tracks.counts.tolist() == [1, 17, 1]
    over = distilled.over_budget
    assert over and {item["gaussian"] for item in over} == {1}
    assert all(abs(item["time"] - 0.6) < 0.1 for item in over)


@pytest.fixture(scope="module")
def tiny_run(tiny_mlp_run) -> Path:
    return tiny_mlp_run


@pytest.fixture(scope="module")
def baked(tiny_run, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bake") / "baked"
    code, _, err = run_cli(["bake", "--run", str(tiny_run), "--out", str(out), "--device", "cpu"])
    assert code == 0, err
    return out


def test_baked_scene_renders_the_field_without_it(tiny_run, baked):
    manifest = json.loads((baked / "baked.json").read_text())
    field_run, baked_run = load_run(tiny_run, "cpu"), load_run(baked, "cpu")
    assert isinstance(baked_run, BakedRun) and baked_run.field is None
    assert manifest["format"] == "liquidgs-baked/3"
    assert manifest["gaussians"] == field_run.params["means"].shape[0] == baked_run.tracks.gaussians
    assert manifest["bytes_per_gaussian"] == (baked / "scene.pt").stat().st_size / manifest["gaussians"] <= 600
    dataset = load_run_dataset(field_run.config)
    background = torch.tensor(dataset.background)
    for frame in dataset.test:  # test times fall between keyframes
        a = field_run.render(frame.camera, frame.time, background).rgb.clamp(0, 1)
        b = baked_run.render(frame.camera, frame.time, background).rgb.clamp(0, 1)
        assert float(psnr(b, a)) >= 45.0, frame.name


def random_tracks(seed: int) -> tuple[Tracks, torch.Tensor]:
    """Tracks of 1, 3 and 9 keyframes over 7 Gaussians, with some channel groups 16-bit."""
    generator = torch.Generator().manual_seed(seed)
    counts = torch.tensor([1, 9, 3, 9, 1, 3, 9])
    groups = []
    for count in (1, 3, 9):
        index = (counts == count).nonzero().flatten()
        groups.append((index, torch.randn(count, len(index), 10, generator=generator) * 5))
    wide = torch.tensor([0, 1, 2, 7, 0, 4, 0], dtype=torch.uint8)
    return Tracks(counts, groups), wide


def test_tracks_are_stored_in_codes_of_each_gaussians_range():
    tracks, wide = random_tracks(0)
    stored = pack(tracks, wide)
    assert stored["codes8"].dtype == torch.uint8 and stored["codes16"].dtype == torch.int16
    # 16 bits: #1's position (9 keyframes x 3), #2's rotation (3 x 4), all of #3 (9 x 10), #5's scale (3 x 3).
    assert stored["codes16"].numel() == 9 * 3 + 3 * 4 + 9 * 10 + 3 * 3
    assert stored["codes8"].numel() == sum(k * 10 for k in (9, 3, 9, 3, 9)) - stored["codes16"].numel()
    restored = unpack(stored, 7)
    assert restored.counts.tolist() == tracks.counts.tolist()
    for (index, keys), (same, back) in zip(tracks.groups, restored.groups):
        assert torch.equal(index, same)
        span = keys.amax(0) - keys.amin(0)
        bits = torch.stack([(wide[index] >> group) & 1 for group in (0, 0, 0, 1, 1, 1, 1, 2, 2, 2)], dim=-1)
        levels = torch.where(bits == 1, 65535.0, 255.0)
        assert torch.all((back - keys).abs() <= span * (1 + 2**-10) / (2 * levels) + 1e-5 * keys.abs() + 1e-6)
    for t in (0.0, 0.3, 0.77):  # one weighted sum per count equals each Gaussian's own spline
        for index, keys in restored.groups:
            assert torch.allclose(restored.at_time(t)[index], interpolate(keys, t), atol=1e-6)
    sh = torch.randn(7, 15, 3, generator=torch.Generator().manual_seed(1))
    sh[3] = 0.25  # a Gaussian whose coefficients are all one value: span 0
    back = from_row_codes(row_codes(sh))
    span = (sh.amax((1, 2)) - sh.amin((1, 2)))[:, None, None]
    assert torch.all((back - sh).abs() <= span * (1 + 2**-10) / 510 + 1e-3 * sh.abs() + 1e-6)
    truncated = {**stored, "codes8": stored["codes8"][:-1]}
    with pytest.raises(ValueError, match="8-bit codes end before the keyframes"):
        unpack(truncated, 7)


def test_commands_read_a_baked_folder_like_a_run(baked, tmp_path):
    code, _, err = run_cli(["eval", "--run", str(baked), "--device", "cpu"])
    assert code == 0, err
    assert json.loads((baked / "eval.json").read_text())["psnr"] > 10
    code, _, err = run_cli(["export", "--run", str(baked), "--out", str(tmp_path / "export"), "--time", "0.5"])
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "export").iterdir()) == ["canonical.ply", "time_0.5000.ply"]
    frames = ["--sweep-frames", "2", "--orbit-frames", "2"]
    code, _, err = run_cli(["render", "--run", str(baked), "--out", str(tmp_path / "renders"), *frames])
    assert code == 0, err
    assert (tmp_path / "renders" / "sweep.mp4").is_file()

    from liquidgs.viewer.scenes import load_runs

    scene = load_runs([baked])[0]
    assert not scene.has_noise
    assert scene.render(scene.dataset.test[0].camera, 0.3).shape[-1] == 3


def test_a_folder_of_the_format_before_reads_and_any_other_is_one_line(baked, tmp_path, capsys):
    from liquidgs.cli import main as cli
    from liquidgs.gaussians import PARAM_KEYS

    run = load_run(baked, "cpu")
    before = tmp_path / "before"
    shutil.copytree(baked, before)
    keyframes = run.keyframes  # every Gaussian on one keyframe count, float32, as liquidgs-baked/2 held them
    torch.save({"params": {k: run.params[k].detach() for k in PARAM_KEYS}, "keyframes": keyframes}, before / "scene.pt")
    manifest = json.loads((before / "baked.json").read_text())
    (before / "baked.json").write_text(json.dumps({**manifest, "format": "liquidgs-baked/2"}))
    rehash_baked_scene(before)
    read = load_run(before, "cpu")
    for t in (0.0, 0.41, 1.0):
        assert torch.allclose(read.at_time(t).means, interpolate(keyframes, t)[:, :3])
    assert cli(["export", "--run", str(before), "--out", str(tmp_path / "x"), "--time", "0.5"]) == 0
    (before / "baked.json").write_text(json.dumps({**manifest, "format": "liquidgs-baked/9"}))
    rehash_baked_scene(before)
    assert cli(["render", "--run", str(before)]) == 2
    line = one_line_error(capsys)
    assert "baked.json: format 'liquidgs-baked/9' is neither 'liquidgs-baked/3' nor 'liquidgs-baked/2'" in line


def unfinished_copy(run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "unfinished"
    shutil.copytree(run, copy)
    (copy / "results.json").unlink()  # results.json is a run's only done marker
    return copy


@pytest.mark.parametrize(
    "case, expected",
    [
        ("missing", "does not exist"),
        ("not_a_run", "not a liquidgs run folder"),
        ("unfinished", "bake needs a finished run"),
        ("baked", "a baked scene, not a run"),
        ("taken", "already exists"),
        ("tolerance", "--tolerance must be in (0, 1)"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(case, expected, tiny_run, baked, tmp_path, capsys):
    from liquidgs.cli import main as cli

    out = tmp_path / "out"
    run, extra = tiny_run, []
    if case == "missing":
        run = tmp_path / "nowhere"
    elif case == "not_a_run":
        run = tmp_path / "folder"
        run.mkdir()
        (run / "notes.txt").write_text("hello")
    elif case == "unfinished":
        run = unfinished_copy(tiny_run, tmp_path)
    elif case == "baked":
        run = baked
    elif case == "taken":
        out.mkdir()
        (out / "keep.txt").write_text("mine")
    elif case == "tolerance":
        extra = ["--tolerance", "0"]
    before = snapshot(tmp_path, tiny_run)
    assert cli(["bake", "--run", str(run), "--out", str(out), "--device", "cpu", *extra]) == 2
    assert expected in one_line_error(capsys)
    assert snapshot(tmp_path, tiny_run) == before


def test_a_failure_while_writing_leaves_no_folder(tiny_run, tmp_path, monkeypatch):
    def full_disk(*_args, **_kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(torch, "save", full_disk)
    few = ["--min-keyframes", "3", "--max-keyframes", "3"]
    code, _, err = run_cli(["bake", "--run", str(tiny_run), "--out", str(tmp_path / "baked"), *few])
    assert code == 2 and "no space left" in err
    assert list(tmp_path.iterdir()) == []


def test_bench_bake_prints_fidelity_and_speed(tiny_run, baked, tmp_path, capsys):
    from liquidgs.cli import main as cli

    output = tmp_path / "bench.jsonl"
    assert (
        cli(["bench", "bake", "--run", str(tiny_run), "--baked", str(baked), "--repeats", "1", "--output", str(output)])
        == 0
    )
    record = json.loads(capsys.readouterr().out)
    assert record == json.loads(output.read_text())
    assert record["baked_vs_field_psnr"] > 40 and abs(record["test_psnr_change"]) < 0.1
    assert record["field_ms_per_frame"] > 0 and record["baked_ms_per_frame"] > 0
    assert record["cpu_speedup"] == pytest.approx(record["field_cpu_ms_per_frame"] / record["baked_cpu_ms_per_frame"])
    parts = record["field_deformation_cpu_ms"], record["keyframe_interpolation_cpu_ms"], record["rasteriser_cpu_ms"]
    assert min(parts) > 0
    assert record["speedup_bound"] == pytest.approx((parts[0] + parts[2]) / parts[2])
    assert record["bytes_per_gaussian"] == (baked / "scene.pt").stat().st_size / record["gaussians"]
    assert cli(["bench", "bake", "--run", str(tiny_run), "--baked", str(tiny_run)]) == 2
    assert "not a baked scene" in one_line_error(capsys)


def test_plyseq_is_a_zip_of_standard_plys_at_evenly_spaced_times(baked, tmp_path):
    import zipfile

    from liquidgs.gaussians import read_ply

    out = tmp_path / "export"
    code, _, err = run_cli(["export", "--run", str(baked), "--out", str(out), "--format", "plyseq", "--sequence", "3"])
    assert code == 0, err
    with zipfile.ZipFile(out / "sequence.zip") as archive:
        assert archive.namelist() == ["frame_0000.ply", "frame_0001.ply", "frame_0002.ply"]
        archive.extractall(tmp_path / "frames")
    run = load_run(baked, "cpu")
    for i, time in enumerate((0.0, 0.5, 1.0)):
        frame = read_ply(tmp_path / "frames" / f"frame_{i:04d}.ply")
        expected = run.at_time(time)
        assert torch.allclose(frame["means"], expected.means, atol=1e-6)
        assert torch.allclose(torch.exp(frame["scales"]), expected.scales.abs(), rtol=1e-5)
        assert torch.equal(frame["sh0"], run.params["sh0"])


def half(word: int, high: bool) -> float:
    """One float16 of a packHalf2x16 word: the first value in the low 16 bits."""
    bits = (word >> 16) if high else (word & 0xFFFF)
    return float(np.array([bits], dtype="<u2").view("<f2")[0])


def test_splatv_file_follows_the_layout_splatv_players_read(baked, tmp_path):
    """Decoded word by word from the format's description (bake/formats.py docstring), not with the
    writer's record type."""
    from liquidgs.bake.formats import SPLATV_CAMERA_WIDTH
    from liquidgs.bake.pieces import fit_within_bytes

    out = tmp_path / "export"
    code, _, err = run_cli(["export", "--run", str(baked), "--out", str(out), "--format", "splatv"])
    assert code == 0, err
    data = (out / "scene.splatv").read_bytes()
    magic, length = struct.unpack_from("<II", data, 0)
    assert magic == 0x674B
    (chunk,) = json.loads(data[8 : 8 + length])
    assert chunk["type"] == "splat" and chunk["texwidth"] == 4096
    run = load_run(baked, "cpu")
    dataset = run.scene()
    frames = [*dataset.test, *dataset.train]
    first = frames[0].camera  # resized for a player's window, the field of view kept
    assert chunk["cameras"][0]["width"] == SPLATV_CAMERA_WIDTH
    assert chunk["cameras"][0]["fx"] == pytest.approx(float(first.K[0, 0]) * SPLATV_CAMERA_WIDTH / first.width)
    words = np.frombuffer(data[8 + length :], dtype="<u4")
    assert words.size * 4 == chunk["size"] == chunk["texwidth"] * chunk["texheight"] * 16
    background = torch.tensor(dataset.background, dtype=torch.float32)
    model = fit_within_bytes(run, frames, dataset.train, background).model  # the export's default
    n = model.position.shape[0]
    records = words.reshape(-1, 16)
    assert not records[n:].any()  # the last row's unused slots are zero
    for i in (0, n // 2, n - 1):
        w = [int(x) for x in records[i]]
        position = np.array(records[i, :3]).view("<f4")
        rotation = [half(w[3], False), half(w[3], True), half(w[4], False), half(w[4], True)]
        scale = [half(w[5], False), half(w[5], True), half(w[6], False)]
        r, g, b, a = (w[7] >> s & 0xFF for s in (0, 8, 16, 24))
        motion = [half(w[8 + k // 2], k % 2 == 1) for k in range(9)]
        omega = [half(w[13], False), half(w[13], True), half(w[14], False), half(w[14], True)]
        centre, width = half(w[15], False), half(w[15], True)
        assert np.allclose([centre, width], model.temporal[i].numpy(), rtol=1e-3)
        assert np.allclose(position, model.position[i].numpy())
        assert np.allclose(rotation, model.rotation[i].numpy(), atol=2e-3)
        assert np.allclose(scale, model.scale[i].numpy(), rtol=2e-3)
        assert abs(a / 255 - float(model.opacity[i])) <= 0.5 / 255 + 1e-6
        assert abs(r / 255 - float(model.rgb[i, 0])) <= 0.5 / 255 + 1e-6 and g <= 255 and b <= 255
        for t in (0.1, 0.8):  # the position and rotation the player computes at time t
            dt = t - centre
            m = np.array(motion)
            p = position + m[0:3] * dt + m[3:6] * dt**2 + m[6:9] * dt**3
            assert np.allclose(p, model.at_time(t).means[i].numpy(), atol=1e-3)
            q = np.array(rotation) + np.array(omega) * dt
            assert np.allclose(q / np.linalg.norm(q), model.at_time(t).quats[i].numpy(), atol=3e-3)
            window = math.exp(-((dt / width) ** 2))
            shown = window * a / 255 if window >= 0.02 else 0.0  # the players skip a window under 0.02
            assert shown == pytest.approx(float(model.at_time(t).opacities[i]), abs=1 / 255)


def splatv_records(data: bytes) -> int:
    """The records of a .splatv file whose temporal scale is set (the last row's unused slots are zero)."""
    (length,) = struct.unpack_from("<I", data, 4)
    words = np.frombuffer(data[8 + length :], dtype="<u4").reshape(-1, 16)
    return int((words[:, 15] >> 16 != 0).sum())


@pytest.mark.slow
def test_splatv_budget_flags_reach_the_fit(baked, tmp_path):
    """--splatv-tolerance and --splatv-pieces are the fit's budget, weighted by the pixel shares: a
    tighter one writes the records the fit gives for it, more than the default's."""
    from liquidgs.bake.pieces import fit_splatv, pixel_weights

    records = {}
    for name, flags in (("default", []), ("tight", ["--splatv-tolerance", "0.12", "--splatv-pieces", "12"])):
        out = tmp_path / name
        code, _, err = run_cli(["export", "--run", str(baked), "--out", str(out), "--format", "splatv", *flags])
        assert code == 0, err
        records[name] = splatv_records((out / "scene.splatv").read_bytes())
    run = load_run(baked, "cpu")
    dataset = run.scene()
    frames = [*dataset.test, *dataset.train]
    weights = pixel_weights(run, frames, torch.tensor(dataset.background, dtype=torch.float32))
    tight = fit_splatv(run, [f.camera for f in frames], 0.12, 12, weights).report["records"]
    assert records["tight"] == tight > records["default"]


class FlatRun:
    """Two flat Gaussians in front of a camera: the first opaque and wide, the second small and
    behind it, so it makes almost none of the picture. A run's interface as pixel_weights reads it."""

    def __init__(self):
        self.params = {"opacities": torch.tensor([8.0, 8.0])}
        self.config = types.SimpleNamespace(backend="torch")

    def at_time(self, time: float) -> Deformed:
        means = torch.tensor([[0.0, 0.0, 0.0], [0.05, 0.0, 1.0]])
        scales = torch.tensor([[0.6, 0.6, 0.01], [0.1, 0.1, 0.01]])
        colours = torch.zeros(2, 1, 3)
        return Deformed(means, axis_angle_quats(torch.zeros(2)), scales, torch.sigmoid(self.params["opacities"]),
                        colours)  # fmt: skip


def test_pixel_weights_are_each_gaussians_compositing_weight():
    """Summed over the Gaussians, a view's weights are its picture's alpha; a Gaussian hidden behind
    an opaque one makes almost none of it."""
    from liquidgs.bake.pieces import pixel_weights
    from liquidgs.render import rasterize

    run, view = FlatRun(), look_at(torch.tensor([0.0, 0.0, -3.0]), torch.zeros(3), torch.tensor([0.0, -1.0, 0.0]))
    camera = Camera.from_fov(view, math.radians(40), 48, 48)
    frames = [types.SimpleNamespace(camera=camera, time=t) for t in (0.0, 0.5)]
    with torch.no_grad():  # as bench bake calls it
        weights = pixel_weights(run, frames, torch.zeros(3))
    assert weights.shape == (2, 2) and torch.allclose(weights[0], weights[1])  # nothing moves
    shares = weights.sum(0)
    g = run.at_time(0.0)
    alpha = rasterize(g.means, g.quats, g.scales, g.opacities, g.colors, camera.viewmat, camera.K, 48, 48,
                      sh_degree=0, background=torch.zeros(3), backend="torch").alpha  # fmt: skip
    assert float(shares.sum()) == pytest.approx(2 * float(alpha.sum()), rel=1e-4)
    assert float(shares[0]) > 0.99 * float(shares.sum()) and float(shares[1]) < 1e-3 * float(shares[0])


def test_the_colour_is_weighted_by_how_much_of_each_view_a_gaussian_makes():
    """A Gaussian whose colour depends on the view (SH degree 1), seen from two sides: weighted by
    views where it makes all of one and none of the other, its colour is that view's; unweighted,
    or seen by neither, the mean of the two."""
    from liquidgs.bake.pieces import seen_colour
    from liquidgs.sh import eval_sh

    run = types.SimpleNamespace(sh_degree=1, params={"sh0": torch.zeros(1, 1, 3), "shN": torch.zeros(1, 3, 3)})
    run.params["shN"][0, 2] = torch.tensor([0.8, 0.0, -0.8])  # the x-direction coefficient
    sides = [torch.tensor([x, 0.0, -3.0]) for x in (-3.0, 3.0)]
    cameras = [Camera.from_fov(look_at(side, torch.zeros(3), torch.tensor([0.0, -1.0, 0.0])), 1.0, 8, 8)
               for side in sides]  # fmt: skip
    origin = torch.zeros(1, 3, dtype=torch.float64)
    sh = torch.cat([run.params["sh0"], run.params["shN"]], dim=1).double()
    each = [(eval_sh(1, sh, origin - side.double()) + 0.5).clamp(0, 1) for side in sides]
    assert not torch.allclose(each[0], each[1], atol=0.05)
    weighted = seen_colour(run, origin, cameras, torch.tensor([[5.0], [0.0]], dtype=torch.float64))
    assert torch.allclose(weighted, each[0])
    for weights in (None, torch.zeros(2, 1, dtype=torch.float64)):
        assert torch.allclose(seen_colour(run, origin, cameras, weights), (each[0] + each[1]) / 2)


def test_a_gaussian_that_makes_little_of_the_picture_takes_fewer_pieces():
    """The weighted budget: two Gaussians on the same swing, one making a thousandth of the pixels
    the other makes; the large one is held to the tolerance, the small one's budget is about 30 times
    looser, so it needs fewer pieces."""
    from liquidgs.bake.pieces import IMPORTANCE_QUANTILE, fit_splatv, weighted_budget

    swing = AnalyticRun(lambda t: torch.tensor([[0.5 * math.sin(4 * math.pi * t), 0.0, 0.0]] * 2), 2, spin=0.0)
    swing.params.update(sh0=torch.zeros(2, 1, 3), shN=torch.zeros(2, 0, 3))
    swing.sh_degree = 0
    shares = torch.tensor([1000.0, 1.0])
    budget = weighted_budget(0.1, shares, 2)
    reference = 1 + IMPORTANCE_QUANTILE * 999  # the shares' quantile, linearly interpolated
    assert budget[0] == pytest.approx(0.1) and budget[1] == pytest.approx(0.1 * math.sqrt(reference))
    plain = fit_splatv(swing, tolerance=0.1)
    weighted = fit_splatv(swing, tolerance=0.1, weights=shares[None])  # one view's weights
    (held,) = (int(p) for p in plain.report["pieces"])  # the same motion: one count for both
    assert sorted(int(p) for p in weighted.report["pieces"])[1:] == [held]  # the large one as before
    assert len(weighted.report["pieces"]) == 2 and weighted.report["records"] < plain.report["records"]
    assert weighted.report["gaussians_over_budget"] == 0 and weighted.report["weighted"] is True
    assert plain.report["weighted"] is False and plain.report["motion_kept_by_share"] is None
    # the large Gaussian, held to the tolerance, keeps more of its motion than the two do together
    assert weighted.report["motion_kept_by_share"] > weighted.motion_kept


@pytest.mark.slow
def test_the_export_keeps_the_closest_budget_within_four_records_a_gaussian(baked):
    """fit_within_bytes: for each window the loose budgets and the tightest within 4 records per
    Gaussian (bisected), each scored on train views; the one kept is within and the best scored."""
    from liquidgs.bake.pieces import AUTO_WINDOWS, LOOSE_TOLERANCES, MOST_RECORDS, fit_within_bytes

    run = load_run(baked, "cpu")
    dataset = run.scene()
    fitted = fit_within_bytes(run, [*dataset.test, *dataset.train], dataset.train,
                              torch.tensor(dataset.background, dtype=torch.float32))  # fmt: skip
    n = run.params["means"].shape[0]
    assert {t["window"] for t in fitted.report["tried"]} == set(AUTO_WINDOWS)
    for width in AUTO_WINDOWS:
        tried = [t for t in fitted.report["tried"] if t["window"] == width]
        assert [t["tolerance"] for t in tried[:2]] == list(LOOSE_TOLERANCES)
        within = [t for t in tried if t["records"] <= MOST_RECORDS * n]
        over = [t for t in tried if t["records"] > MOST_RECORDS * n]
        assert all(t["train_views_db"] is None for t in over)
        if within:  # the tightest within was scored, and every tighter one tried was over
            tightest = min(within, key=lambda t: t["tolerance"])
            assert tightest["train_views_db"] is not None
            assert all(t["tolerance"] < tightest["tolerance"] for t in over)
    scored = [t for t in fitted.report["tried"] if t["train_views_db"] is not None]
    best = max(scored, key=lambda t: t["train_views_db"])
    assert (fitted.report["window"], fitted.report["tolerance"]) == (best["window"], best["tolerance"])
    assert fitted.report["records"] == best["records"] <= 4 * n


def test_splatv_fit_keeps_motion_its_model_can_hold():
    from liquidgs.bake.pieces import fit_splatv

    cubic = AnalyticRun(lambda t: torch.tensor([[t**3 - t, 0.5 * t * t, 1.0], [0.0, 0.0, 0.0]]), 2)
    cubic.params["sh0"] = torch.zeros(2, 1, 3)
    fitted = fit_splatv(cubic)
    assert fitted.motion_kept == pytest.approx(1.0, abs=1e-9) and fitted.report["pieces"] == {"1": 2}
    for t in (0.0, 0.37, 1.0):
        assert torch.allclose(fitted.model.at_time(t).means, cubic.path(t), atol=1e-5)
        assert torch.allclose(fitted.model.at_time(t).quats, axis_angle_quats(torch.full((2,), t)), atol=1e-2)
    wave = AnalyticRun(lambda t: torch.tensor([[0.5 * math.sin(4 * math.pi * t), 0.0, 0.0]]), 1, spin=0.0)
    wave.params.update(sh0=torch.zeros(1, 1, 3), shN=torch.zeros(1, 0, 3))
    wave.sh_degree = 0
    assert fit_splatv(wave, most=1).motion_kept < 0.5  # two periods: beyond one cubic
    pieces = fit_splatv(wave)
    assert pieces.motion_kept > 0.99 and pieces.report["gaussians_over_budget"] == 0
    (count,) = (int(p) for p in pieces.report["pieces"])
    assert count > 1 and pieces.model.position.shape[0] == count
    # Wherever a piece shows, it is where the wave is: within the budget of the Gaussian's size.
    for t in torch.linspace(0, 1, 41).tolist():
        g = pieces.model.at_time(t)
        shows = g.opacities > 0.1 * g.opacities.max()
        assert float((g.means[shows] - wave.path(t)).norm(dim=-1).max()) <= 0.5 * wave.size / 0.1


@pytest.mark.parametrize(
    "flags, expected",
    [
        (["--format", "plyseq"], "--format plyseq needs --sequence N"),
        (["--format", "splatv", "--time", "0.5"], "--time writes single PLYs"),
        (["--format", "gif"], "unknown format 'gif'"),
        (["--format", "splatv", "--splatv-tolerance", "0"], "--splatv-tolerance must be a positive number, got 0.0"),
        (["--format", "splatv", "--splatv-tolerance", "nan"], "--splatv-tolerance must be a positive number"),
        (["--format", "splatv", "--splatv-pieces", "34"], "--splatv-pieces must be between 1 and 33, got 34"),
        (["--format", "web", "--splatv-tolerance", "0.2"], "splatv fit: no effect with --format web"),
    ],
)
def test_export_format_bad_input_is_one_line(flags, expected, baked, tmp_path, capsys):
    from liquidgs.cli import main as cli

    assert cli(["export", "--run", str(baked), "--out", str(tmp_path / "x"), *flags]) == 2
    assert expected in one_line_error(capsys)
    assert not (tmp_path / "x").exists()


def test_viewer_plays_a_baked_folder(baked, capsys):
    from liquidgs.cli import main as cli

    assert cli(["view", "--run", str(baked), "--port", "0", "--benchmark", "2", "--resolution", "64"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["scene"] == "1: mlp, baked (baked)" and record["rest"]["fps"] > 0
