"""gsplat 1.5.3's compiled CUDA module, stood in for on the CPU by PyTorch code.

gsplat's Python wrappers (gsplat/cuda/_wrapper.py: fully_fused_projection, spherical_harmonics,
isect_tiles, isect_offset_encode, rasterize_to_pixels and their autograd Functions) reach the
kernels through `from ._backend import _C` at call time. `install(monkeypatch)` puts a module in
sys.modules["gsplat.cuda._backend"] whose `_C` answers the kernel names those wrappers call with
torch code, and raises on any other name, so nothing is ever compiled and every line of gsplat's
Python between liquidgs and the kernels (argument order, contiguity, the autograd Functions, the
background's gradient, `means2d.absgrad`) runs as it does on a GPU.

- Projection: gsplat's own torch projection (`_torch_impl._fully_fused_projection` on
  `_quat_scale_to_covar_preci`'s covariances) for means2d, depths and conics, and the culling of
  the CUDA kernel (ProjectionEWA3DGSFused.cu), which the torch version does not share: depth
  < near or > far, det <= 0, opacity < 1/255, the opacity-aware extent min(3.33, sqrt(2 ln(255 o))),
  radius_clip and the off-image test. The backward recomputes the forward with autograd for the
  Gaussians the kernel's backward does not skip (both radii > 0) and gives the rest zero.
- SH: `_torch_impl._spherical_harmonics`, masked rows skipped (zero gradient) as the kernel does.
- Tile intersection and offsets: `_torch_impl._isect_tiles` (then a stable sort, as CUB's radix
  sort is) and `_isect_offset_encode`.
- rasterize_to_pixels has no usable torch version in gsplat, so it is written here after
  RasterizeToPixels3DGSFwd.cu / Bwd.cu, for any number of channels the kernels are compiled for
  (colours or extra features, KERNEL_CHANNELS): per tile, the tile's Gaussians front to back against its
  pixels (centres at +0.5), alpha = min(0.999, o exp(-sigma)), fragments with sigma < 0 or alpha <
  1/255 skipped, a pixel done (that Gaussian excluded) when the transmittance would fall to 1e-4 or
  below, colours + T * background. Its backward recomputes that with autograd; means2d enters every
  fragment as its own leaf, so the per-pixel gradients are there to sum as the CUDA backward does:
  means2d.grad = sum of them, absgrad = sum of their absolute values.

Rows a CUDA kernel never writes (a culled Gaussian's means2d, depths, conics; a masked SH colour)
are NaN here, where a GPU leaves uninitialised memory, so anything that reads them shows.
`calls` counts the kernels used.
"""

from __future__ import annotations

import math
import sys
import types
from collections import Counter

import torch
from gsplat.cuda._torch_impl import (
    _fully_fused_projection,
    _isect_offset_encode,
    _isect_tiles,
    _persp_proj,
    _quat_scale_to_covar_preci,
    _spherical_harmonics,
    _world_to_cam,
)
from torch import Tensor

ALPHA_THRESHOLD = 1.0 / 255.0  # Common.h
MAX_ALPHA = 0.999
TRANSMITTANCE_STOP = 1e-4  # a pixel is done once T * (1 - alpha) <= this
MAX_EXTENT = 3.33
UNWRITTEN = float("nan")  # what the kernels leave in rows they skip (uninitialised on a GPU)
# The channel counts rasterize_to_pixels' kernels are compiled for (Rasterization.cpp's switch; any
# other is "Unsupported number of channels"): gsplat's Python wrapper pads colours up to one of them.
KERNEL_CHANNELS = (1, 2, 3, 4, 5, 8, 9, 16, 17, 32, 33, 64, 65, 128, 129, 256, 257, 512, 513)

calls: Counter[str] = Counter()


class _Pinhole:
    def __repr__(self) -> str:
        return "CameraModelType.PINHOLE"


PINHOLE = _Pinhole()


class _KeepsFloat64(torch.Tensor):
    """Alphas whose `.float()` keeps float64.

    gsplat's rasteriser kernel is float32-only (it reads float pointers), so its wrapper casts the
    alphas it returns and the (1 - alphas) of the background's gradient to float. A float64 run can
    reach this stand-in only because the test lets it (liquidgs sends float64 elsewhere); there the
    casts would round the mapping under test to float32, so these two keep the dtype instead.
    """

    def float(self, *args, **kwargs):  # noqa: A003 - the name gsplat's wrapper calls
        return self.view_as(self)

    def __rsub__(self, other):
        return torch.Tensor.__rsub__(self, other).as_subclass(_KeepsFloat64)


class StandInError(RuntimeError):
    """A call the stand-ins do not cover (never an AssertionError, which the tests' comparisons raise)."""


def _check(condition: bool, what: str) -> None:
    if not condition:
        raise StandInError(f"gsplat CPU stand-in: {what}")


def _contiguous(*tensors: Tensor | None) -> None:
    # The kernels' CHECK_INPUT (minus the CUDA part).
    for tensor in tensors:
        _check(tensor is None or tensor.is_contiguous(), "a kernel input is not contiguous")


# ---------------------------------------------------------------- projection (ProjectionEWA3DGSFused.cu)


def _covariances(quats: Tensor, scales: Tensor) -> Tensor:
    covars, _ = _quat_scale_to_covar_preci(quats, scales, compute_preci=False)
    return covars


def projection_ewa_3dgs_fused_fwd(
    means, covars, quats, scales, opacities, viewmats, Ks, width, height,
    eps2d, near_plane, far_plane, radius_clip, calc_compensations, camera_model,
):  # fmt: skip
    calls["projection_ewa_3dgs_fused_fwd"] += 1
    _check(covars is None and quats is not None and scales is not None, "expects quaternions and scales")
    _check(camera_model is PINHOLE, f"pinhole camera only, got {camera_model!r}")
    _check(not calc_compensations, "no compensations (classic mode)")
    _check(means.dim() == 2 and viewmats.dim() == 3, "no batch dimensions")
    _contiguous(means, quats, scales, opacities, viewmats, Ks)
    covars3d = _covariances(quats, scales)
    _, means2d, depths, conics, _ = _fully_fused_projection(
        means, covars3d, viewmats, Ks, width, height, eps2d=eps2d, near_plane=near_plane, far_plane=far_plane
    )
    # The kernel's culling and radii, in its order.
    means_c, covars_c = _world_to_cam(means, covars3d, viewmats)
    _, cov2d = _persp_proj(means_c, covars_c, Ks, width, height)
    cov_a = cov2d[..., 0, 0] + eps2d
    cov_c = cov2d[..., 1, 1] + eps2d
    det = cov_a * cov_c - cov2d[..., 0, 1] * cov2d[..., 1, 0]
    z = means_c[..., 2]
    culled = (z < near_plane) | (z > far_plane) | ~(det > 0)
    extent = torch.full_like(z, MAX_EXTENT)
    if opacities is not None:
        opacity = opacities.expand_as(z)
        culled |= opacity < ALPHA_THRESHOLD
        bright = torch.clamp_min(opacity, ALPHA_THRESHOLD)
        extent = torch.clamp_max(torch.sqrt(2.0 * torch.log(bright / ALPHA_THRESHOLD)), MAX_EXTENT)
    radius_x = torch.ceil(extent * torch.sqrt(cov_a))
    radius_y = torch.ceil(extent * torch.sqrt(cov_c))
    culled |= (radius_x <= radius_clip) & (radius_y <= radius_clip)
    culled |= (means2d[..., 0] + radius_x <= 0) | (means2d[..., 0] - radius_x >= width)
    culled |= (means2d[..., 1] + radius_y <= 0) | (means2d[..., 1] - radius_y >= height)
    radii = torch.stack([radius_x, radius_y], dim=-1)
    radii = torch.where(culled[..., None], torch.zeros_like(radii), radii).to(torch.int32)
    means2d, depths, conics = (
        torch.where(culled.reshape(culled.shape + (1,) * (t.dim() - culled.dim())), UNWRITTEN, t)
        for t in (means2d, depths, conics)
    )
    return radii, means2d.contiguous(), depths.contiguous(), conics.contiguous(), None


def projection_ewa_3dgs_fused_bwd(
    means, covars, quats, scales, viewmats, Ks, width, height, eps2d, camera_model, radii, conics,
    compensations, v_means2d, v_depths, v_conics, v_compensations, viewmats_requires_grad,
):  # fmt: skip
    calls["projection_ewa_3dgs_fused_bwd"] += 1
    _check(covars is None and compensations is None and v_compensations is None, "quaternions, scales, classic")
    _check(camera_model is PINHOLE, "pinhole camera only")
    _contiguous(means, quats, scales, viewmats, Ks, radii, v_means2d, v_depths, v_conics)
    v_means, v_quats, v_scales = torch.zeros_like(means), torch.zeros_like(quats), torch.zeros_like(scales)
    v_viewmats = torch.zeros_like(viewmats) if viewmats_requires_grad else None
    for camera in range(viewmats.shape[0]):
        # The backward kernel returns at once unless both radii are positive.
        ids = torch.nonzero((radii[camera] > 0).all(dim=-1)).squeeze(1)
        if ids.numel() == 0:
            continue
        with torch.enable_grad():
            leaves = [means[ids].detach().requires_grad_(), quats[ids].detach().requires_grad_(),
                      scales[ids].detach().requires_grad_()]  # fmt: skip
            viewmat = viewmats[camera : camera + 1].detach().requires_grad_(bool(viewmats_requires_grad))
            _, means2d, depths, conics_again, _ = _fully_fused_projection(
                leaves[0], _covariances(leaves[1], leaves[2]), viewmat, Ks[camera : camera + 1], width, height,
                eps2d=eps2d, near_plane=-float("inf"), far_plane=float("inf"),
            )  # fmt: skip
            inputs = leaves + ([viewmat] if viewmats_requires_grad else [])
            grads = torch.autograd.grad(
                (means2d, depths, conics_again),
                inputs,
                (v_means2d[camera, ids][None], v_depths[camera, ids][None], v_conics[camera, ids][None]),
            )
        v_means.index_add_(0, ids, grads[0])
        v_quats.index_add_(0, ids, grads[1])
        v_scales.index_add_(0, ids, grads[2])
        if viewmats_requires_grad:
            v_viewmats[camera] += grads[3][0]
    return v_means, None, v_quats, v_scales, v_viewmats


# ---------------------------------------------------------------- spherical harmonics (SphericalHarmonicsCUDA.cu)


def spherical_harmonics_fwd(sh_degree, dirs, coeffs, masks):
    calls["spherical_harmonics_fwd"] += 1
    _contiguous(dirs, coeffs, masks)
    colors = _spherical_harmonics(sh_degree, dirs, coeffs)
    if masks is not None:
        colors = torch.where(masks[..., None], colors, UNWRITTEN)
    return colors.contiguous()


def spherical_harmonics_bwd(num_bases, sh_degree, dirs, coeffs, masks, v_colors, compute_v_dirs):
    calls["spherical_harmonics_bwd"] += 1
    _check(num_bases == coeffs.shape[-2], "num_bases is the coefficients' count")
    _contiguous(dirs, coeffs, masks, v_colors)
    rows = masks if masks is not None else torch.ones(dirs.shape[:-1], dtype=torch.bool)
    v_coeffs = torch.zeros_like(coeffs)
    v_dirs = torch.zeros_like(dirs) if compute_v_dirs else None
    with torch.enable_grad():
        dirs_leaf = dirs[rows].detach().requires_grad_()
        coeffs_leaf = coeffs[rows].detach().requires_grad_()
        colors = _spherical_harmonics(sh_degree, dirs_leaf, coeffs_leaf)
        grad_coeffs, grad_dirs = torch.autograd.grad(
            colors, (coeffs_leaf, dirs_leaf), v_colors[rows], allow_unused=True, materialize_grads=True
        )  # degree 0 does not use the directions
    v_coeffs[rows] = grad_coeffs
    if compute_v_dirs:
        v_dirs[rows] = grad_dirs
    return v_coeffs, v_dirs


# ---------------------------------------------------------------- tile intersection (IntersectTile.cu)


def intersect_tile(
    means2d, radii, depths, image_ids, gaussian_ids, n_images, tile_size, tile_width, tile_height, sort, segmented
):
    calls["intersect_tile"] += 1
    _check(image_ids is None and gaussian_ids is None, "not packed")
    _contiguous(means2d, radii, depths)
    tiles_per_gauss, isect_ids, flatten_ids = _isect_tiles(
        means2d, radii, depths, tile_size, tile_width, tile_height, sort=False
    )
    if sort:  # CUB's radix sort is stable: equal keys keep the lower Gaussian id first
        isect_ids, order = torch.sort(isect_ids, stable=True)
        flatten_ids = flatten_ids[order]
    return tiles_per_gauss, isect_ids, flatten_ids


def intersect_offset(isect_ids, n_images, tile_width, tile_height):
    calls["intersect_offset"] += 1
    return _isect_offset_encode(isect_ids, n_images, tile_width, tile_height)


# ---------------------------------------------------------------- rasterize_to_pixels (RasterizeToPixels3DGS*.cu)


def _composite(
    means2d, conics, colors, opacities, backgrounds, width, height, tile_size, tile_offsets, flatten_ids,
    fragment_means=None,
):  # fmt: skip
    """Front-to-back compositing per tile: (render_colors, render_alphas, last_ids).

    With fragment_means (a list), every Gaussian's mean enters every tile's pixels as its own leaf
    [P, 2], appended as (flattened id, leaf), so the per-pixel gradients can be summed by the caller.
    """
    image_dims = tile_offsets.shape[:-2]
    n_images = math.prod(image_dims)
    tiles_y, tiles_x = tile_offsets.shape[-2:]
    channels = colors.shape[-1]
    flat_means = means2d.reshape(-1, 2)
    flat_conics = conics.reshape(-1, 3)
    flat_colors = colors.reshape(-1, channels)
    flat_opacities = opacities.reshape(-1)
    starts = tile_offsets.reshape(-1).tolist()
    ends = starts[1:] + [flatten_ids.numel()]  # the last tile of the last image runs to n_isects
    ids = flatten_ids.tolist()
    backgrounds = None if backgrounds is None else backgrounds.reshape(n_images, channels)
    pixel_ids, pixel_colors, pixel_transmittances, pixel_last_ids = [], [], [], []
    for tile in range(n_images * tiles_y * tiles_x):
        image, ty, tx = tile // (tiles_y * tiles_x), (tile // tiles_x) % tiles_y, tile % tiles_x
        rows = torch.arange(ty * tile_size, min((ty + 1) * tile_size, height))
        cols = torch.arange(tx * tile_size, min((tx + 1) * tile_size, width))
        pixel_y, pixel_x = (t.reshape(-1) for t in torch.meshgrid(rows, cols, indexing="ij"))
        px, py = pixel_x.to(means2d.dtype) + 0.5, pixel_y.to(means2d.dtype) + 0.5
        n_pixels = px.numel()
        transmittance = means2d.new_ones(n_pixels)
        done = torch.zeros(n_pixels, dtype=torch.bool)
        accumulated = means2d.new_zeros(n_pixels, channels)
        last = torch.zeros(n_pixels, dtype=torch.int32)
        for index in range(starts[tile], ends[tile]):
            g = ids[index]
            if fragment_means is None:
                xy = flat_means[g].expand(n_pixels, 2)
            else:
                xy = flat_means[g].detach().expand(n_pixels, 2).clone().requires_grad_()
                fragment_means.append((g, xy))
            conic = flat_conics[g]
            dx, dy = xy[:, 0] - px, xy[:, 1] - py
            sigma = 0.5 * (conic[0] * dx * dx + conic[2] * dy * dy) + conic[1] * dx * dy
            alpha = torch.clamp_max(flat_opacities[g] * torch.exp(-sigma), MAX_ALPHA)
            skipped = done | (sigma < 0) | (alpha < ALPHA_THRESHOLD)
            next_transmittance = transmittance * (1.0 - alpha)
            finishing = ~skipped & (next_transmittance <= TRANSMITTANCE_STOP)
            taken = ~skipped & ~finishing
            weight = torch.where(taken, alpha * transmittance, torch.zeros_like(alpha))
            accumulated = accumulated + weight[:, None] * flat_colors[g]
            transmittance = torch.where(taken, next_transmittance, transmittance)
            done = done | finishing
            last = torch.where(taken, torch.full_like(last, index), last)
        if backgrounds is not None:
            accumulated = accumulated + transmittance[:, None] * backgrounds[image]
        pixel_ids.append((image * height + pixel_y) * width + pixel_x)
        pixel_colors.append(accumulated)
        pixel_transmittances.append(transmittance)
        pixel_last_ids.append(last)
    order = torch.argsort(torch.cat(pixel_ids))
    _check(order.numel() == n_images * height * width, "the tiles cover every pixel once")
    render_colors = torch.cat(pixel_colors)[order]
    render_alphas = 1.0 - torch.cat(pixel_transmittances)[order]
    last_ids = torch.cat(pixel_last_ids)[order]
    return (
        render_colors.reshape(image_dims + (height, width, channels)),
        render_alphas.reshape(image_dims + (height, width, 1)),
        last_ids.reshape(image_dims + (height, width)),
    )


def rasterize_to_pixels_3dgs_fwd(
    means2d, conics, colors, opacities, backgrounds, masks, width, height, tile_size, tile_offsets, flatten_ids
):
    calls["rasterize_to_pixels_3dgs_fwd"] += 1
    _check(masks is None, "no tile masks")
    _check(means2d.dim() == 3, "not packed")
    _check(colors.shape[-1] in KERNEL_CHANNELS, f"Unsupported number of channels: {colors.shape[-1]}")
    _contiguous(means2d, conics, colors, opacities, backgrounds, tile_offsets, flatten_ids)
    render_colors, render_alphas, last_ids = _composite(
        means2d, conics, colors, opacities, backgrounds, width, height, tile_size, tile_offsets, flatten_ids
    )
    if render_alphas.dtype != torch.float32:
        render_alphas = render_alphas.as_subclass(_KeepsFloat64)
    return render_colors, render_alphas, last_ids


def rasterize_to_pixels_3dgs_bwd(
    means2d, conics, colors, opacities, backgrounds, masks, width, height, tile_size, tile_offsets, flatten_ids,
    render_alphas, last_ids, v_render_colors, v_render_alphas, absgrad,
):  # fmt: skip
    calls["rasterize_to_pixels_3dgs_bwd"] += 1
    _check(masks is None, "no tile masks")
    _check(colors.shape[-1] in KERNEL_CHANNELS, f"Unsupported number of channels: {colors.shape[-1]}")
    _contiguous(means2d, conics, colors, opacities, backgrounds, tile_offsets, flatten_ids, v_render_colors)
    fragments: list[tuple[int, Tensor]] = []
    with torch.enable_grad():
        leaves = [t.detach().requires_grad_() for t in (conics, colors, opacities)]
        render_colors, alphas, again_last_ids = _composite(
            means2d.detach(), *leaves, None if backgrounds is None else backgrounds.detach(),
            width, height, tile_size, tile_offsets, flatten_ids, fragment_means=fragments,
        )  # fmt: skip
        _check(torch.equal(again_last_ids, last_ids), "the backward recomputes the forward's fragments")
        loss = (render_colors * v_render_colors).sum() + (alphas * v_render_alphas.to(alphas.dtype)).sum()
        inputs = leaves + [leaf for _, leaf in fragments]
        grads = torch.autograd.grad(loss, inputs, allow_unused=True, materialize_grads=True)
    v_conics, v_colors, v_opacities = grads[:3]
    flat_grad = torch.zeros_like(means2d).reshape(-1, 2)
    flat_absgrad = torch.zeros_like(flat_grad)
    for (g, _), per_pixel in zip(fragments, grads[3:]):
        flat_grad[g] += per_pixel.sum(dim=0)
        flat_absgrad[g] += per_pixel.abs().sum(dim=0)
    v_means2d = flat_grad.reshape(means2d.shape)
    v_means2d_abs = flat_absgrad.reshape(means2d.shape) if absgrad else None
    return v_means2d_abs, v_means2d, v_conics, v_colors, v_opacities


# ---------------------------------------------------------------- the module


KERNELS = {
    function.__name__: function
    for function in (
        projection_ewa_3dgs_fused_fwd,
        projection_ewa_3dgs_fused_bwd,
        spherical_harmonics_fwd,
        spherical_harmonics_bwd,
        intersect_tile,
        intersect_offset,
        rasterize_to_pixels_3dgs_fwd,
        rasterize_to_pixels_3dgs_bwd,
    )
}


class StandInKernels:
    """gsplat's `_C` on the CPU: the kernels above, and an error for every other name."""

    # gsplat's _make_lazy_cuda_obj("CameraModelType.PINHOLE") does getattr(_C, part) for each
    # dotted part, so the pinhole enum is looked up as _C.PINHOLE.
    PINHOLE = PINHOLE
    CameraModelType = types.SimpleNamespace(PINHOLE=PINHOLE)

    def __getattr__(self, name: str):
        if name in KERNELS:
            return KERNELS[name]
        raise StandInError(f"gsplat CUDA kernel {name!r} called; it has no CPU stand-in (nothing is compiled)")


def install(monkeypatch) -> Counter[str]:
    """Make gsplat's wrappers call the stand-ins for the rest of the test; returns the call counter."""
    module = types.ModuleType("gsplat.cuda._backend")
    module.__doc__ = "CPU stand-in for gsplat's compiled module (tests/gsplat_cpu_kernels.py)"
    module._C = StandInKernels()
    monkeypatch.setitem(sys.modules, "gsplat.cuda._backend", module)
    calls.clear()
    return calls
