"""The compiled CPU rasteriser held against the torch backend (the reference): images, bins, gradients."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from liquidgs.render import cpu_backend
from liquidgs.render.projection import project_gaussians
from liquidgs.render.tiles import bin_gaussians
from liquidgs.render.torch_backend import view_colors
from test_render import PARAMETERS, gradients, random_scene, render

pytestmark = pytest.mark.skipif(
    cpu_backend.unavailable_reason() is not None,
    reason=f"compiled CPU rasteriser unavailable: {cpu_backend.unavailable_reason()}",
)


def images(scene, backend, **kwargs):
    out = render(scene, backend=backend, **kwargs)
    return out.rgb, out.alpha, out.depth


@pytest.mark.parametrize(
    ("seed", "n", "width", "height", "sh_degree", "tile_size"),
    [(0, 150, 23, 17, None, 4), (1, 400, 64, 48, 3, 8), (2, 300, 37, 41, 1, 16), (3, 80, 5, 3, None, 4)],
)
def test_forward_and_gradients_match_the_torch_backend_float64(seed, n, width, height, sh_degree, tile_size):
    scene = random_scene(n, width=width, height=height, seed=seed, dtype=torch.float64, sh_degree=sh_degree)
    background = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    ours = images(scene, "cpu", background=background, tile_size=tile_size)
    reference = images(scene, "torch", background=background)
    assert reference[1].max() > 0.9, "the scene should contain saturated pixels"
    for got, want in zip(ours, reference):
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    ours_grad = gradients(scene, lambda s, bg: images(s, "cpu", background=bg, tile_size=tile_size))
    reference_grad = gradients(scene, lambda s, bg: images(s, "torch", background=bg))
    for key, grad in reference_grad.items():
        assert grad.abs().max() > 0, key
        torch.testing.assert_close(ours_grad[key], grad, rtol=1e-10, atol=1e-10 * grad.abs().max().item(), msg=key)


def test_float32_within_a_stated_tolerance():
    """float32: the kernel's polynomial exp (about 1 ulp) and its summation order differ from torch's."""
    scene = random_scene(2000, width=128, height=96, seed=4, scale_range=(0.01, 0.08))
    ours = images(scene, "cpu")
    reference = images(scene, "torch")
    torch.testing.assert_close(ours[0], reference[0], rtol=0, atol=1e-5)
    torch.testing.assert_close(ours[1], reference[1], rtol=0, atol=1e-5)
    ours_grad = gradients(scene, lambda s, bg: images(s, "cpu", background=bg))
    reference_grad = gradients(scene, lambda s, bg: images(s, "torch", background=bg))
    for key in PARAMETERS:
        scale = reference_grad[key].abs().max().item()
        torch.testing.assert_close(ours_grad[key], reference_grad[key], rtol=1e-3, atol=1e-4 * scale, msg=key)


def test_images_and_gradients_repeat_bit_for_bit_for_any_thread_count():
    """The backward sums each Gaussian's gradient over a fixed number of slices of the tiles, not
    one per thread (before, 1 and 2 threads gave gradients a few ulp apart, and runs drifted)."""
    scene = random_scene(1500, width=64, height=48, seed=7, scale_range=(0.02, 0.2))
    threads = torch.get_num_threads()
    try:
        results = []
        for count in (1, 2, 3):
            torch.set_num_threads(count)
            grads = gradients(scene, lambda s, bg: images(s, "cpu", background=bg, tile_size=8))
            results.append((images(scene, "cpu", tile_size=8), grads))
    finally:
        torch.set_num_threads(threads)
    for got_images, got_grads in results[1:]:
        for got, want in zip(got_images, results[0][0]):
            assert torch.equal(got, want)
        for key, want in results[0][1].items():
            assert torch.equal(got_grads[key], want), key


def test_absgrad_matches_the_torch_backend():
    scene = random_scene(300, width=40, height=30, seed=5, dtype=torch.float64)
    results = {}
    for backend in ("torch", "cpu"):
        leaves = {key: scene[key].clone().requires_grad_(True) for key in PARAMETERS}
        out = render(scene | leaves, backend=backend, absgrad=True)
        (out.rgb * torch.linspace(-1, 1, out.rgb.numel(), dtype=torch.float64).reshape(out.rgb.shape)).sum().backward()
        results[backend] = (out.info["means2d"].grad, out.info["means2d"].absgrad)
    for got, want in zip(results["cpu"], results["torch"]):
        assert want.abs().max() > 0
        torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("tile_size", [4, 8, 12, 16])
@pytest.mark.parametrize("huge", [False, True])
def test_counting_sort_bins_equal_the_torch_bins(tile_size, huge):
    """Also with Gaussians of radii in the millions of pixels (a diverging run's): their boxes are
    the whole image, and the kernel's room for the pairs is bounded by the image, not the radii."""
    scene = random_scene(500, width=61, height=45, seed=6)
    if huge:
        scene["scales"][:20] *= 1e6
    projection = project_gaussians(
        scene["means"], scene["quats"], scene["scales"], scene["opacities"], scene["viewmat"], scene["K"],
        61, 45, 0.01, 1e10, 0.3,
    )  # fmt: skip
    args = (
        projection.means2d, projection.conics, scene["opacities"], projection.radii_xy, projection.depths, 61, 45,
        tile_size,
    )  # fmt: skip
    ours, reference = cpu_backend.bin_gaussians_cpu(*args), bin_gaussians(*args)
    assert reference.n_pairs > 500
    assert not huge or projection.radii_xy.max() > 1_000_000
    for name in ("gaussian_ids", "tile_starts", "tile_counts"):
        assert torch.equal(getattr(ours, name), getattr(reference, name)), name


def hard_projection_scene(seed: int) -> dict:
    """random_scene plus the cases the projection's gradient treats apart: Gaussians behind the
    camera and beyond the far plane, x/z and y/z beyond the Jacobian's limits on every side, a
    quaternion of norm near 1e-13, and flat Gaussians whose blurred 2D covariance stays positive."""
    scene = random_scene(300, width=40, height=30, seed=seed, dtype=torch.float64, sh_degree=3)
    means, quats, scales = scene["means"].clone(), scene["quats"].clone(), scene["scales"].clone()
    rotation, translation = scene["viewmat"][:3, :3], scene["viewmat"][:3, 3]
    camera_points = torch.tensor(
        [[0.0, 0.0, -1.0], [0.1, 0.0, 0.005], [0.0, 0.0, 150.0], [9.0, 0.3, 2.0], [-9.0, 0.2, 2.0],
         [0.1, 7.0, 2.0], [0.2, -7.0, 2.0], [30.0, -30.0, 1.5]],
        dtype=torch.float64,
    )  # fmt: skip
    means[: len(camera_points)] = (camera_points - translation) @ rotation
    quats[10] = quats[10] / quats[10].norm() * 1e-13
    scales[11:20, 2] = 1e-6
    return scene | {"means": means, "quats": quats, "scales": scales}


def test_projection_kernel_matches_the_torch_projection_float64():
    scene = hard_projection_scene(seed=7)
    camera = (scene["viewmat"], scene["K"], 40, 30, 0.01, 100.0, 0.3)
    results = []
    for project in (project_gaussians, cpu_backend.project_gaussians_cpu):
        leaves = [scene[key].clone().requires_grad_(True) for key in ("means", "quats", "scales")]
        projection = project(*leaves, scene["opacities"], *camera)
        outputs = (projection.means2d, projection.conics, projection.depths)
        weights = [torch.linspace(-1, 2, t.numel(), dtype=torch.float64).reshape(t.shape) for t in outputs]
        sum((t * w).sum() for t, w in zip(outputs, weights)).backward()
        results.append((projection, [leaf.grad for leaf in leaves]))
    (reference, reference_grads), (ours, ours_grads) = results
    assert not reference.visible[:3].any() and reference.visible.sum() > 100
    assert torch.equal(ours.visible, reference.visible) and torch.equal(ours.radii_xy, reference.radii_xy)
    for name in ("means2d", "conics", "depths"):
        torch.testing.assert_close(getattr(ours, name), getattr(reference, name), rtol=1e-12, atol=1e-12, msg=name)
    for name, got, want in zip(("means", "quats", "scales"), ours_grads, reference_grads):
        scale = want.abs().max().item()
        assert scale > 0, name
        torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-11 * scale, msg=name)


@pytest.mark.parametrize("sh_degree", [0, 1, 2, 3])
def test_sh_colour_kernel_matches_the_torch_colours_float64(sh_degree):
    """16 coefficients at every degree (the unused ones get zero gradient); some colours clamp at 0."""
    scene = hard_projection_scene(seed=8)
    results = []
    for colours in (view_colors, cpu_backend.view_colors_cpu):
        means = scene["means"].clone().requires_grad_(True)
        coeffs = (3 * scene["colors"]).requires_grad_(True)
        rgb = colours(coeffs, sh_degree, means, scene["viewmat"])
        (rgb * torch.linspace(-1, 2, rgb.numel(), dtype=torch.float64).reshape(rgb.shape)).sum().backward()
        means_grad = torch.zeros_like(means) if means.grad is None else means.grad
        results.append((rgb, means_grad, coeffs.grad))
    assert (results[0][0] == 0).any() and (results[0][0] > 0).any()
    for name, got, want in zip(("rgb", "means", "coeffs"), results[1], results[0]):
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-13, msg=name)


def test_a_camera_that_needs_a_gradient_gets_it_through_the_torch_projection():
    scene = random_scene(200, width=40, height=30, seed=9, dtype=torch.float64, sh_degree=2)
    grads = {}
    for backend in ("torch", "cpu"):
        viewmat = scene["viewmat"].clone().requires_grad_(True)
        out = render(scene | {"viewmat": viewmat}, backend=backend)
        out.rgb.sum().backward()
        grads[backend] = viewmat.grad
    assert grads["torch"].abs().max() > 0
    torch.testing.assert_close(grads["cpu"], grads["torch"], rtol=1e-10, atol=1e-12)


def test_auto_uses_the_compiled_kernel_on_cpu():
    out = render(random_scene(20), backend="auto")
    assert out.info["backend"] == "cpu" and out.info["tile_size"] == 4


def test_tile_sizes_the_kernel_cannot_take_are_refused():
    with pytest.raises(ValueError, match="tile sizes 4, 8, ..., 32"):
        render(random_scene(20), backend="cpu", tile_size=6)


def run_python(code: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=os.environ | env, check=False, timeout=120
    )


RENDER_TWICE = """
import torch
from liquidgs.render import rasterize
from liquidgs.render.benchmark import dnerf_like_scene
s = dnerf_like_scene(50, 16, 16, torch.device("cpu"))
for _ in range(2):
    out = rasterize(s["means"], s["quats"], s["scales"], s["opacities"], s["colors"], s["viewmat"], s["K"], 16, 16)
print(out.info["backend"])
"""


@pytest.mark.parametrize(
    ("env", "reason"),
    [
        ({"LIQUIDGS_CPU_KERNEL": "0"}, "LIQUIDGS_CPU_KERNEL=0"),
        ({"CXX": "/nonexistent/c++"}, "cannot run /nonexistent/c++"),
        ({"CXX": "false"}, "false failed on cpu_composite.cpp"),
    ],
)
def test_without_the_kernel_auto_falls_back_to_torch_with_one_line(tmp_path, env, reason):
    result = run_python(RENDER_TWICE, LIQUIDGS_CACHE_DIR=str(tmp_path / "cache"), **env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "torch"
    lines = [line for line in result.stderr.splitlines() if "compiled CPU rasteriser" in line]
    assert len(lines) == 1, result.stderr
    assert reason in lines[0] and lines[0].endswith("using the torch backend")


@pytest.mark.slow  # compiles the kernels from scratch
def test_the_kernel_is_built_once_into_the_cache(tmp_path):
    cache = tmp_path / "cache"
    for _ in range(2):
        result = run_python(RENDER_TWICE, LIQUIDGS_CACHE_DIR=str(cache))
        assert result.returncode == 0 and result.stdout.strip() == "cpu", result.stderr
        assert result.stderr == ""
    built = list(cache.glob("cpu_render-*.so"))
    assert len(built) == 1
    assert not [p for p in cache.iterdir() if p not in built], "no temporary left behind"


@pytest.mark.slow
def test_the_kernel_takes_its_constants_from_the_torch_backend(monkeypatch, tmp_path):
    """The kernel holds no copy of the blend's constants: built with other values for them (as a
    change of composite.py / projection.py would give it), it follows the torch backend there."""
    from liquidgs.render import composite, projection

    scene = random_scene(300, width=40, height=32, seed=5, dtype=torch.float64)
    default = images(scene, "cpu")
    monkeypatch.setattr(composite, "MAX_ALPHA", 0.6)
    monkeypatch.setattr(projection, "FRUSTUM_MARGIN", 0.05)
    monkeypatch.setattr(projection, "MAX_EXTENT_SIGMAS", 2.5)
    changed = dict(cpu_backend.DEFINES) | {
        "LIQUIDGS_MAX_ALPHA": 0.6, "LIQUIDGS_FRUSTUM_MARGIN": 0.05, "LIQUIDGS_MAX_EXTENT_SIGMAS": 2.5
    }
    monkeypatch.setattr(cpu_backend, "DEFINES", tuple(changed.items()))
    monkeypatch.setenv("LIQUIDGS_CACHE_DIR", str(tmp_path))  # this variant is built here, not in the user's cache
    ours, reference = images(scene, "cpu"), images(scene, "torch")
    assert not torch.equal(ours[0], default[0]), "the new constants should change the image"
    for got, want in zip(ours, reference):
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
