"""The torch rasteriser against a dense all-pairs reference built on gsplat's own PyTorch projection."""

from __future__ import annotations

import logging
import math

import pytest
import torch
from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci, _spherical_harmonics

from liquidgs.cameras import focal_from_fov
from liquidgs.render import RenderOutput, cpu_backend, rasterize, tiles
from liquidgs.render.composite import composite_tiles
from liquidgs.render.projection import ALPHA_THRESHOLD, project_gaussians
from liquidgs.render.reference import composite_dense


def look_at(eye: torch.Tensor) -> torch.Tensor:
    """World-to-camera matrix (OpenCV axes) for a camera at `eye` looking at the origin."""
    forward = -eye / eye.norm()
    right = torch.linalg.cross(forward, torch.tensor([0.0, 0.0, 1.0], dtype=eye.dtype))
    right = right / right.norm()
    down = torch.linalg.cross(forward, right)
    cam_to_world = torch.stack([right, down, forward], dim=1)
    viewmat = torch.eye(4, dtype=eye.dtype)
    viewmat[:3, :3] = cam_to_world.T
    viewmat[:3, 3] = -cam_to_world.T @ eye
    return viewmat


def random_scene(
    n: int,
    width: int = 23,
    height: int = 17,
    seed: int = 0,
    dtype: torch.dtype = torch.float32,
    scale_range: tuple[float, float] = (0.05, 0.35),
    sh_degree: int | None = None,
) -> dict:
    generator = torch.Generator().manual_seed(seed)
    directions = torch.randn(n, 3, generator=generator)
    radii = torch.rand(n, 1, generator=generator) ** (1 / 3)
    means = directions / directions.norm(dim=1, keepdim=True) * radii
    opacities = 0.05 + 0.95 * torch.rand(n, generator=generator)
    opacities[: n // 5] = 0.9999  # exercises the 0.999 clamp and the transmittance cut-off
    if sh_degree is None:
        colors = torch.rand(n, 3, generator=generator)
    else:
        colors = 0.3 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=generator)
    focal = focal_from_fov(0.6911, width)
    intrinsics = torch.tensor([[focal, 0.0, 0.43 * width], [0.0, 1.1 * focal, 0.58 * height], [0.0, 0.0, 1.0]])
    scene = {
        "means": means,
        "quats": torch.randn(n, 4, generator=generator),
        "scales": torch.empty(n, 3).uniform_(*scale_range, generator=generator),
        "opacities": opacities,
        "colors": colors,
        "viewmat": look_at(torch.tensor([1.5, -3.0, 2.0])),
        "K": intrinsics,
    }
    return {key: value.to(dtype) for key, value in scene.items()} | {
        "width": width,
        "height": height,
        "sh_degree": sh_degree,
    }


def reference_render(scene: dict, background=None, near_plane=0.01, far_plane=1e10, eps2d=0.3):
    """Every pixel against every Gaussian, projected by gsplat's PyTorch reference implementation."""
    accumulated, alpha = reference_composite(scene, None, near_plane, far_plane, eps2d)
    if background is None:
        background = torch.zeros(3, dtype=alpha.dtype)
    rgb = accumulated[..., :3] + (1.0 - alpha) * background
    return rgb, alpha, accumulated[..., 3:] / alpha.clamp_min(1e-10)


def reference_composite(scene: dict, extra=None, near_plane=0.01, far_plane=1e10, eps2d=0.3):
    """The dense reference's ([H,W,4+C] sums of w * (RGB, depth, extra [N,C])), [H,W,1] alpha)."""
    width, height = scene["width"], scene["height"]
    covars, _ = _quat_scale_to_covar_preci(scene["quats"], scene["scales"], compute_preci=False)
    radii, means2d, depths, conics, _ = _fully_fused_projection(
        scene["means"], covars, scene["viewmat"][None], scene["K"][None], width, height,
        eps2d=eps2d, near_plane=near_plane, far_plane=far_plane,
    )  # fmt: skip
    radii, means2d, depths, conics = radii[0], means2d[0], depths[0], conics[0]
    colors = scene["colors"]
    if scene["sh_degree"] is not None:
        camera_centre = torch.inverse(scene["viewmat"])[:3, 3]
        dirs = scene["means"] - camera_centre
        colors = torch.clamp_min(_spherical_harmonics(scene["sh_degree"], dirs, colors) + 0.5, 0.0)
    features = torch.cat([colors, depths[:, None]] + ([] if extra is None else [extra]), dim=1)
    visible = (radii > 0).all(dim=-1)
    return composite_dense(means2d, conics, scene["opacities"], features, depths, visible, width, height)


def render(scene: dict, **kwargs) -> RenderOutput:
    kwargs.setdefault("backend", "torch")
    return rasterize(
        scene["means"], scene["quats"], scene["scales"], scene["opacities"], scene["colors"],
        scene["viewmat"], scene["K"], scene["width"], scene["height"], sh_degree=scene["sh_degree"], **kwargs,
    )  # fmt: skip


PARAMETERS = ("means", "quats", "scales", "opacities", "colors")


def weighted_loss(rgb, alpha, depth, seed=1):
    generator = torch.Generator().manual_seed(seed)
    weights = [torch.randn(t.shape, generator=generator, dtype=t.dtype) for t in (rgb, alpha, depth)]
    return (rgb * weights[0]).sum() + (alpha * weights[1]).sum() + 0.1 * (depth * weights[2]).sum()


def gradients(scene: dict, render_fn) -> dict:
    leaves = {key: scene[key].clone().requires_grad_(True) for key in PARAMETERS}
    background = torch.tensor([0.2, 0.5, 0.9], dtype=scene["means"].dtype, requires_grad=True)
    rgb, alpha, depth = render_fn(scene | leaves, background)
    weighted_loss(rgb, alpha, depth).backward()
    return {key: leaf.grad for key, leaf in leaves.items()} | {"background": background.grad}


def torch_backend_images(scene, background=None, **kwargs):
    out = render(scene, background=background, **kwargs)
    return out.rgb, out.alpha, out.depth


@pytest.mark.parametrize(("seed", "n", "sh_degree"), [(0, 60, None), (1, 150, None), (2, 80, 3), (3, 40, 1)])
def test_forward_matches_dense_reference_float32(seed, n, sh_degree):
    scene = random_scene(n, seed=seed, sh_degree=sh_degree)
    background = torch.tensor([0.1, 0.7, 0.3])
    out = render(scene, background=background)
    reference = reference_render(scene, background=background)
    assert out.alpha.max() > 0.9, "the scene should contain saturated pixels"
    torch.testing.assert_close(out.rgb, reference[0], rtol=0, atol=1e-5)
    torch.testing.assert_close(out.alpha, reference[1], rtol=0, atol=1e-5)
    # Depth is a ratio of two float32 sums (depth-weighted over alpha): where alpha is small it keeps
    # the sums' rounding, which follows torch's vector width (AVX2 vs AVX-512: 1.35e-5 relative seen).
    torch.testing.assert_close(out.depth, reference[2], rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize(("seed", "sh_degree"), [(4, None), (5, 2)])
def test_gradients_match_dense_reference_float64(seed, sh_degree):
    scene = random_scene(70, seed=seed, dtype=torch.float64, sh_degree=sh_degree)
    ours = gradients(scene, lambda s, bg: torch_backend_images(s, bg))
    reference = gradients(scene, lambda s, bg: reference_render(s, bg))
    for key, grad in reference.items():
        assert grad.abs().max() > 0, key
        torch.testing.assert_close(ours[key], grad, rtol=1e-9, atol=1e-9 * grad.abs().max().item(), msg=key)


def test_gradcheck_tiny_scene():
    scene = random_scene(4, width=7, height=6, seed=6, dtype=torch.float64, scale_range=(0.2, 0.4))
    scene["opacities"] = torch.tensor([0.3, 0.6, 0.5, 0.8], dtype=torch.float64)

    def images(means, quats, scales, opacities, colors):
        out = render(scene | dict(zip(PARAMETERS, (means, quats, scales, opacities, colors))))
        return out.rgb, out.alpha, out.depth

    inputs = tuple(scene[key].clone().requires_grad_(True) for key in PARAMETERS)
    assert torch.autograd.gradcheck(images, inputs, eps=1e-7, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("tile_size", [1, 3, 16])
def test_tile_size_and_chunking_do_not_change_the_image(tile_size):
    scene = random_scene(120, seed=7)
    default = render(scene)
    other = render(scene, tile_size=tile_size, chunk_elements=2000)
    torch.testing.assert_close(other.rgb, default.rgb, rtol=0, atol=1e-6)
    torch.testing.assert_close(other.alpha, default.alpha, rtol=0, atol=1e-6)


def test_info_contents():
    scene = random_scene(50, seed=8)
    out = render(scene)
    info = out.info
    n = scene["means"].shape[0]
    assert out.rgb.shape == (17, 23, 3) and out.alpha.shape == (17, 23, 1) and out.depth.shape == (17, 23, 1)
    assert info["means2d"].shape == (n, 2) and info["depths"].shape == (n,)
    assert info["radii"].shape == (n,) and info["radii"].dtype == torch.int32
    assert info["radii_xy"].shape == (n, 2)
    assert torch.equal(info["visible"], info["radii"] > 0)
    assert (info["width"], info["height"], info["backend"]) == (23, 17, "torch")


def test_projection_matches_gsplat_reference():
    scene = random_scene(200, seed=9)
    out = render(scene)
    covars, _ = _quat_scale_to_covar_preci(scene["quats"], scene["scales"], compute_preci=False)
    radii, means2d, depths, conics, _ = _fully_fused_projection(
        scene["means"], covars, scene["viewmat"][None], scene["K"][None], 23, 17
    )
    visible = out.info["visible"]
    torch.testing.assert_close(out.info["means2d"][visible], means2d[0][visible], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(out.info["conics"][visible], conics[0][visible], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(out.info["depths"], depths[0])
    # gsplat 1.5.3's kernels tighten the 3.33-sigma box by opacity, so radii never exceed the reference's.
    assert (out.info["radii_xy"][visible] <= radii[0][visible]).all()
    assert ((out.info["radii_xy"] > 0).all(-1) <= (radii[0] > 0).all(-1)).all()


def test_culled_gaussians_leave_the_image_unchanged():
    scene = random_scene(30, seed=10)
    near = 0.01
    camera_to_world = torch.inverse(scene["viewmat"])

    def world_point(camera_point):
        return camera_to_world[:3, :3] @ torch.tensor(camera_point) + camera_to_world[:3, 3]

    extra_means = torch.stack(
        [
            world_point([0.0, 0.0, -1.0]),  # behind the camera
            world_point([0.0, 0.0, near]),  # on the near plane
            world_point([0.0, 0.0, 0.0]),  # at the camera centre
            world_point([50.0, 0.0, 4.0]),  # far off-screen
            world_point([0.0, 0.0, 4.0]),  # in view but fully transparent
        ]
    )
    extended = dict(scene)
    extended["means"] = torch.cat([scene["means"], extra_means])
    extended["quats"] = torch.cat([scene["quats"], torch.tensor([[1.0, 0, 0, 0]] * 5)])
    extended["scales"] = torch.cat([scene["scales"], torch.full((5, 3), 0.3)])
    extended["opacities"] = torch.cat([scene["opacities"], torch.tensor([1.0, 1.0, 1.0, 1.0, 0.0])])
    extended["colors"] = torch.cat([scene["colors"], torch.ones(5, 3)])
    extended = {key: value.clone().requires_grad_(True) if key in PARAMETERS else value
                for key, value in extended.items()}  # fmt: skip
    base = render(scene)
    out = render(extended)
    assert (out.info["radii"][-5:] == 0).all() and not out.info["visible"][-5:].any()
    torch.testing.assert_close(out.rgb, base.rgb, rtol=0, atol=0)
    out.rgb.sum().backward()
    for key in PARAMETERS:
        grad = extended[key].grad
        assert torch.isfinite(grad).all(), key
        assert (grad[-5:] == 0).all(), key


def test_just_in_front_of_the_near_plane_is_kept():
    scene = random_scene(1, seed=11)
    camera_to_world = torch.inverse(scene["viewmat"])
    scene["means"] = (camera_to_world[:3, :3] @ torch.tensor([0.0, 0.0, 0.5]) + camera_to_world[:3, 3])[None]
    # The depth as the projection computes it: the round trip through the inverse lands near 0.5, an
    # ulp or so off depending on the CPU's vector width, so the planes are placed on the depth itself.
    viewmat = scene["viewmat"]
    depth = (scene["means"] @ viewmat[:3, :3].T + viewmat[:3, 3])[0, 2]
    just_beyond = torch.nextafter(depth, torch.tensor(math.inf)).item()
    just_before = torch.nextafter(depth, torch.tensor(-math.inf)).item()
    assert render(scene, near_plane=just_before).info["visible"].item()
    assert render(scene, near_plane=depth.item()).info["visible"].item()  # depth == near: kept, as gsplat's kernel does
    assert not render(scene, near_plane=just_beyond).info["visible"].item()
    assert render(scene, far_plane=depth.item()).info["visible"].item()  # depth == far: kept too
    assert not render(scene, far_plane=just_before).info["visible"].item()


def test_degenerate_scales():
    scene = random_scene(20, seed=12, dtype=torch.float64)
    scene["scales"][:5] = 0.0
    scene["scales"][5:8] = 1e-12
    out = render(scene)
    # The eps2d blur keeps vanishing Gaussians as sub-pixel dots, exactly as gsplat does.
    assert out.info["visible"][:8].any()
    torch.testing.assert_close(out.rgb, reference_render(scene)[0], rtol=0, atol=1e-9)
    leaves = {key: scene[key].clone().requires_grad_(True) for key in PARAMETERS}
    render(scene | leaves).rgb.sum().backward()
    assert all(torch.isfinite(leaf.grad).all() for leaf in leaves.values())
    # Without the blur a zero-scale Gaussian's 2D covariance is singular: culled.
    unblurred = render(scene, eps2d=0.0)
    assert (unblurred.info["radii"][:5] == 0).all() and unblurred.info["visible"][8:].any()


def test_empty_scene_renders_background():
    shapes = {"means": (3,), "quats": (4,), "scales": (3,), "opacities": (), "colors": (3,)}
    empty = {key: torch.zeros((0, *shape)) for key, shape in shapes.items()}
    scene = random_scene(1) | empty
    background = torch.tensor([0.25, 0.5, 0.75])
    out = render(scene, background=background)
    assert torch.equal(out.rgb, background.expand(17, 23, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all()
    assert out.info["means2d"].shape == (0, 2) and out.info["radii"].shape == (0,)


def test_single_pixel_image():
    scene = random_scene(25, width=1, height=1, seed=13, scale_range=(0.3, 0.6))
    out = render(scene)
    reference = reference_render(scene)
    assert out.rgb.shape == (1, 1, 3) and out.alpha.item() > 0
    torch.testing.assert_close(out.rgb, reference[0], rtol=0, atol=1e-5)
    torch.testing.assert_close(out.depth, reference[2], rtol=1e-5, atol=1e-5)


def test_non_square_image_with_offset_principal_point():
    scene = random_scene(90, width=41, height=9, seed=14)
    scene["K"][0, 2], scene["K"][1, 2] = 30.0, 2.0
    out = render(scene)
    torch.testing.assert_close(out.rgb, reference_render(scene)[0], rtol=0, atol=1e-5)


def test_pixel_centres_follow_gsplat():
    # A single round Gaussian centred on a pixel centre: that pixel gets the peak alpha.
    scene = random_scene(1, width=8, height=8)
    scene["viewmat"] = torch.eye(4)
    scene["K"] = torch.tensor([[10.0, 0.0, 3.5], [0.0, 10.0, 5.5], [0.0, 0.0, 1.0]])
    scene["means"] = torch.tensor([[0.0, 0.0, 2.0]])
    scene["quats"] = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
    scene["scales"] = torch.full((1, 3), 0.1)
    scene["opacities"] = torch.tensor([0.5])
    out = render(scene)
    peak = (out.alpha[..., 0] == out.alpha.max()).nonzero()
    assert peak.tolist() == [[5, 3]]
    torch.testing.assert_close(out.alpha[5, 3, 0], torch.tensor(0.5))


def test_absgrad_is_the_sum_of_per_pixel_absolute_gradients():
    scene = random_scene(25, width=12, height=10, seed=15, dtype=torch.float64)
    means = scene["means"].clone().requires_grad_(True)
    out = render(scene | {"means": means}, absgrad=True)
    loss_weights = torch.randn(out.rgb.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    (out.rgb * loss_weights).sum().backward()
    means2d = out.info["means2d"]
    assert means2d.grad is not None and means2d.absgrad.shape == (25, 2)
    assert (means2d.absgrad >= 0).all()
    assert (means2d.absgrad >= means2d.grad.abs() - 1e-12).all()
    assert (means2d.absgrad > means2d.grad.abs() + 1e-6).any(), "pixels should disagree in sign somewhere"

    # Reference: a separate copy of means2d per pixel, so autograd yields per-pixel gradients.
    info = out.info
    ids = torch.nonzero(info["visible"]).squeeze(1)
    per_pixel = info["means2d"].detach()[ids].expand(120, -1, -1).clone().requires_grad_(True)
    features = torch.cat([scene["colors"][ids], info["depths"].detach()[ids, None]], dim=1)
    rows, cols = torch.meshgrid(torch.arange(10.0), torch.arange(12.0), indexing="ij")
    pixels = torch.stack([cols, rows], dim=-1).reshape(-1, 2).to(torch.float64) + 0.5
    total = 0.0
    for index in range(120):
        accumulated, _ = composite_dense(
            per_pixel[index] - pixels[index] + 0.5, info["conics"].detach()[ids], scene["opacities"][ids],
            features, info["depths"].detach()[ids], torch.ones(len(ids), dtype=torch.bool), 1, 1,
        )  # fmt: skip
        total = total + (accumulated[0, 0, :3] * loss_weights.reshape(-1, 3)[index]).sum()
    total.backward()
    expected = per_pixel.grad.abs().sum(dim=0)
    torch.testing.assert_close(means2d.absgrad[ids], expected, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(means2d.grad[ids], per_pixel.grad.sum(dim=0), rtol=1e-9, atol=1e-12)


def test_auto_backend_on_cpu_uses_the_compiled_kernel_or_torch_and_logs_once(caplog):
    scene = random_scene(5)
    with caplog.at_level(logging.INFO, logger="liquidgs.render.rasterize"):
        first = render(scene, backend="auto")
        render(scene, backend="auto")
    expected = "cpu" if cpu_backend.unavailable_reason() is None else "torch"
    assert first.info["backend"] == expected
    assert sum(f"backend='auto' uses {expected}" in record.message for record in caplog.records) <= 1


def test_gsplat_backend_on_cpu_raises():
    with pytest.raises(ValueError, match="backend='gsplat' is unavailable"):
        render(random_scene(5), backend="gsplat")


def test_float64_end_to_end_keeps_dtype():
    scene = random_scene(10, dtype=torch.float64)
    out = render(scene)
    assert out.rgb.dtype == out.alpha.dtype == out.depth.dtype == torch.float64
    assert math.isfinite(out.rgb.sum().item())


CUDA_TOLERANCES = {  # gsplat's own tests, CUDA kernels vs its PyTorch reference (specs/gsplat.md)
    "means": (1e-2, 6e-2),
    "quats": (2e-1, 2e-2),
    "scales": (5e-1, 2e-1),
    "opacities": (8e-3, 6e-3),
    "colors": (1e-3, 1e-3),
    "background": (1e-3, 1e-3),
}


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs an NVIDIA GPU")
@pytest.mark.parametrize(("seed", "sh_degree"), [(20, None), (21, 3)])
def test_torch_backend_matches_gsplat_on_cuda(seed, sh_degree):
    scene = random_scene(400, width=96, height=72, seed=seed, scale_range=(0.02, 0.15), sh_degree=sh_degree)
    scene = {key: value.cuda() if isinstance(value, torch.Tensor) else value for key, value in scene.items()}

    def backend_gradients(backend):
        leaves = {key: scene[key].clone().requires_grad_(True) for key in PARAMETERS}
        background = torch.tensor([0.2, 0.5, 0.9], device="cuda", requires_grad=True)
        out = render(scene | leaves, background=background, backend=backend, absgrad=True)
        loss = weighted_loss(out.rgb.cpu(), out.alpha.cpu(), out.depth.cpu())
        loss.backward()
        grads = {key: leaf.grad for key, leaf in leaves.items()} | {"background": background.grad}
        return out, grads

    ours, our_grads = backend_gradients("torch")
    theirs, their_grads = backend_gradients("gsplat")
    assert theirs.info["backend"] == "gsplat"
    assert torch.equal(ours.info["visible"], theirs.info["visible"])
    assert (ours.info["radii_xy"] - theirs.info["radii_xy"]).abs().max() <= 1
    visible = ours.info["visible"]
    torch.testing.assert_close(ours.info["means2d"][visible], theirs.info["means2d"][visible], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(ours.info["conics"][visible], theirs.info["conics"][visible], rtol=1e-4, atol=1e-4)
    for image in ("rgb", "alpha"):
        torch.testing.assert_close(getattr(ours, image), getattr(theirs, image), rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(ours.depth, theirs.depth, rtol=1e-3, atol=1e-3)
    torch.testing.assert_close(ours.info["means2d"].grad, theirs.info["means2d"].grad, rtol=5e-3, atol=5e-3)
    assert (theirs.info["means2d"].absgrad >= theirs.info["means2d"].grad.abs() - 1e-6).all()
    torch.testing.assert_close(ours.info["means2d"].absgrad, theirs.info["means2d"].absgrad, rtol=5e-3, atol=5e-3)
    for key, (rtol, atol) in CUDA_TOLERANCES.items():
        torch.testing.assert_close(our_grads[key], their_grads[key], rtol=rtol, atol=atol, msg=key)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs an NVIDIA GPU")
def test_torch_backend_runs_on_cuda_like_on_cpu():
    scene = random_scene(150, seed=22)
    on_gpu = {key: value.cuda() if isinstance(value, torch.Tensor) else value for key, value in scene.items()}
    torch.testing.assert_close(render(on_gpu).rgb.cpu(), render(scene).rgb, rtol=1e-5, atol=1e-5)


def box_and_footprint_bins(scene: dict, tile_size: int, monkeypatch) -> tuple:
    """The scene's projection, its bins as the torch backend makes them, and the bins of the whole
    bounding boxes (the footprint test switched off: every column of every row)."""
    projection = project_gaussians(
        scene["means"], scene["quats"], scene["scales"], scene["opacities"], scene["viewmat"], scene["K"],
        scene["width"], scene["height"], 0.01, 1e10, 0.3,
    )  # fmt: skip
    args = (projection.means2d, projection.conics, scene["opacities"], projection.radii_xy, projection.depths,
            scene["width"], scene["height"], tile_size)  # fmt: skip
    footprint = tiles.bin_gaussians(*args)
    with monkeypatch.context() as patch:
        patch.setattr(tiles, "footprint_columns", lambda m, *_: (m[:, 0] - math.inf, m[:, 0] + math.inf))
        box = tiles.bin_gaussians(*args)
    return projection, footprint, box


@pytest.mark.parametrize("tile_size", [4, 8, 12, 16])
def test_the_footprint_test_drops_only_tiles_where_nothing_is_drawn(tile_size, monkeypatch):
    """Tiles of a Gaussian's box that its ellipse of alpha >= 1/255 misses are left out of its bins:
    a fifth or more of the pairs here at tile size 4 (35-45% on trained scenes), and no pixel of a dropped tile is one
    the Gaussian would have drawn (alpha from the conic in float64, as the composite computes it)."""
    scene = random_scene(400, width=61, height=45, seed=11, scale_range=(0.005, 0.3))
    shuffle = torch.randperm(400, generator=torch.Generator().manual_seed(1))
    scene["opacities"] = torch.linspace(0.005, 1.0, 400)[shuffle]
    projection, footprint, box = box_and_footprint_bins(scene, tile_size, monkeypatch)
    assert 0 < footprint.n_pairs < (0.8 if tile_size == 4 else 0.95) * box.n_pairs  # 4: the default tiles
    kept, dropped = 0, 0
    for tile in range(box.n_tiles):
        in_box, in_bins = (b.gaussian_ids[b.tile_starts[tile] :][: b.tile_counts[tile]] for b in (box, footprint))
        left_out = in_box[~torch.isin(in_box, in_bins)]
        assert torch.equal(in_box[torch.isin(in_box, in_bins)], in_bins)  # same order, front to back
        x0, y0 = (tile % box.tiles_x) * tile_size, (tile // box.tiles_x) * tile_size
        ys, xs = torch.meshgrid(torch.arange(y0, min(y0 + tile_size, scene["height"])) + 0.5,
                                torch.arange(x0, min(x0 + tile_size, scene["width"])) + 0.5, indexing="ij")  # fmt: skip
        for gaussian in left_out.tolist():
            a, b, c = projection.conics[gaussian].double()
            dx = projection.means2d[gaussian, 0].double() - xs.double()
            dy = projection.means2d[gaussian, 1].double() - ys.double()
            alpha = scene["opacities"][gaussian].double() * torch.exp(-(0.5 * (a * dx**2 + c * dy**2) + b * dx * dy))
            assert alpha.max() < ALPHA_THRESHOLD, (tile, gaussian)
        kept, dropped = kept + in_bins.numel(), dropped + left_out.numel()
    assert (kept, dropped) == (footprint.n_pairs, box.n_pairs - footprint.n_pairs)


@pytest.mark.parametrize("backend", ["torch", "cpu"])
def test_footprint_bins_composite_the_image_of_the_whole_boxes(backend, monkeypatch):
    if backend == "cpu" and cpu_backend.unavailable_reason() is not None:
        pytest.skip(f"compiled CPU rasteriser unavailable: {cpu_backend.unavailable_reason()}")
    composite = cpu_backend.composite_tiles_cpu if backend == "cpu" else composite_tiles
    scene = random_scene(600, width=64, height=48, seed=12, scale_range=(0.005, 0.2))
    projection, footprint, box = box_and_footprint_bins(scene, 4, monkeypatch)
    assert footprint.n_pairs < 0.8 * box.n_pairs
    features = torch.cat([scene["colors"], projection.depths[:, None]], dim=1)
    common = (projection.means2d, projection.conics, scene["opacities"], features)
    image, alpha = composite(*common, footprint, 64, 48)
    assert alpha.max() > 0.9
    for got, want in zip((image, alpha), composite(*common, box, 64, 48)):
        if backend == "cpu":  # the kernel skips a fragment under the threshold: nothing to round differently
            assert torch.equal(got, want)
        else:  # the torch backend's products over padded tiles of other lengths round apart by an ulp
            torch.testing.assert_close(got, want, rtol=0, atol=2.5e-7)
