"""rasterize(backend="gsplat") run on the CPU and held against the torch backend.

gsplat's compiled module is replaced by tests/gsplat_cpu_kernels.py (its own PyTorch projection,
SH, tile intersection and offsets, plus a torch rasterize_to_pixels written after the CUDA kernel),
so liquidgs' gsplat backend and gsplat's Python wrappers run unchanged: what this proves is the
mapping of liquidgs' parameters onto gsplat's (activations, quaternion order, view matrix, K, SH
degree, background, absgrad). Then the mapping is broken on purpose, one way at a time, and each
break must fail the same comparison.
"""

from __future__ import annotations

import types

import gsplat
import pytest
import torch

import gsplat_cpu_kernels as kernels
from liquidgs.render import cpu_backend, gsplat_backend, rasterize
from liquidgs.render.contract import MAX_EXTRA_FEATURES

WIDTH, HEIGHT = 32, 24
PARAMETERS = ("means", "quats", "scales", "opacities", "colors")
SH_COEFFICIENTS = 16  # all four degrees' worth at every degree, so a degree off by one still runs
TOLERANCES = {torch.float64: 1e-10, torch.float32: 1e-4}  # relative to each tensor's largest entry
KERNELS = set(kernels.KERNELS)


@pytest.fixture
def stand_in(monkeypatch, one_torch_thread):
    """gsplat's kernels on the CPU; liquidgs told they run (on a GPU it probes them)."""
    calls = kernels.install(monkeypatch)
    monkeypatch.setattr(gsplat_backend, "unavailable_reason", lambda means: None)
    return calls


def rotation(w: float, x: float, y: float, z: float) -> torch.Tensor:
    w, x, y, z = torch.nn.functional.normalize(torch.tensor([w, x, y, z], dtype=torch.float64), dim=0).tolist()
    return torch.tensor(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ],
        dtype=torch.float64,
    )


# An off-centre pinhole with fx != fy, on a camera turned and moved off the world's axes.
K = torch.tensor([[27.0, 0.0, 13.7], [0.0, 31.5, 10.2], [0.0, 0.0, 1.0]], dtype=torch.float64)
CAMERA_TO_WORLD = torch.eye(4, dtype=torch.float64)
CAMERA_TO_WORLD[:3, :3] = rotation(0.9, 0.2, -0.3, 0.25)
CAMERA_TO_WORLD[:3, 3] = torch.tensor([0.4, -0.7, 1.3], dtype=torch.float64)
VIEWMAT = torch.linalg.inv(CAMERA_TO_WORLD)

# Camera-space (x / z, y / z, z, opacity) of the Gaussians placed on purpose; the image spans
# x / z in [-0.51, 0.68] and y / z in [-0.32, 0.44].
PLACED = [
    (0.0, 0.0, -1.0, 0.8),  # behind the camera
    (1.5, 0.5, -0.2, 0.8),  # behind the camera, close
    (0.0, 0.0, 0.0, 0.8),  # at the camera centre
    (0.2, 0.0, 0.005, 0.8),  # between the camera and the near plane
    (13.0, 0.0, 3.0, 0.9),  # far off screen to the right
    (0.0, -10.0, 3.0, 0.9),  # far off screen above
    (-0.55, 0.1, 3.0, 0.9),  # centre just left of the image, its footprint reaching in
    (0.1, 0.46, 3.5, 0.9),  # centre just below the image, its footprint reaching in
    (0.05, 0.05, 2.9, 0.0035),  # nearly transparent, under 1/255: culled
    (-0.2, 0.1, 3.1, 0.0040),  # nearly transparent, just over 1/255: a footprint of a few pixels
    (0.3, -0.1, 3.3, 0.0045),
    (0.15, 0.2, 2.2, 0.01),
    (0.08, 0.05, 2.5, 0.9999),  # three nearly opaque ones in a row: the 0.999 clamp, and pixels
    (0.1, 0.06, 2.6, 0.9999),  # whose transmittance falls under 1e-4 (the third one excluded)
    (0.09, 0.04, 2.7, 0.9999),
]


def make_scene(dtype: torch.dtype, sh_degree: int | None, n_random: int = 36, seed: int = 0) -> dict:
    generator = torch.Generator().manual_seed(seed)
    z = 2.0 + 4.0 * torch.rand(n_random, generator=generator, dtype=torch.float64)
    x = -0.6 + 1.35 * torch.rand(n_random, generator=generator, dtype=torch.float64)
    y = -0.4 + 0.9 * torch.rand(n_random, generator=generator, dtype=torch.float64)
    opacity = 0.05 + 0.9 * torch.rand(n_random, generator=generator, dtype=torch.float64)
    placed = torch.tensor(PLACED, dtype=torch.float64)
    x, y, z, opacity = (torch.cat([a, placed[:, i]]) for i, a in enumerate((x, y, z, opacity)))
    # x / z and y / z given; a Gaussian at the camera centre (z = 0) sits on the axis
    camera_points = torch.stack([x * z.abs().clamp_min(1e-3), y * z.abs().clamp_min(1e-3), z], dim=1)
    means = camera_points @ CAMERA_TO_WORLD[:3, :3].T + CAMERA_TO_WORLD[:3, 3]
    n = means.shape[0]
    if sh_degree is None:
        colors = torch.rand(n, 3, generator=generator, dtype=torch.float64)
    else:
        colors = 0.3 * torch.randn(n, SH_COEFFICIENTS, 3, generator=generator, dtype=torch.float64)
        colors[:, 0] += 0.6
    scene = {
        "means": means,
        "quats": torch.randn(n, 4, generator=generator, dtype=torch.float64),
        "scales": 0.05 + 0.25 * torch.rand(n, 3, generator=generator, dtype=torch.float64),
        "opacities": opacity,
        "colors": colors,
        "viewmat": VIEWMAT,
        "K": K,
        "background": torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64),
    }
    return {key: value.to(dtype) for key, value in scene.items()} | {"sh_degree": sh_degree}


def render(scene: dict, backend: str, **kwargs):
    """Render with gradients of a weighted loss on rgb, alpha, depth and the scene's extra features,
    if it has them: (output, gradients)."""
    names = (*PARAMETERS, "background") + (("features",) if "features" in scene else ())
    leaves = {key: scene[key].clone().requires_grad_(True) for key in names}
    out = rasterize(
        leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"], leaves["colors"],
        scene["viewmat"], scene["K"], WIDTH, HEIGHT, sh_degree=scene["sh_degree"], features=leaves.get("features"),
        background=leaves["background"], backend=backend, absgrad=True, **kwargs,
    )  # fmt: skip
    generator = torch.Generator().manual_seed(1)
    images = [out.rgb, out.alpha, out.depth] + ([] if out.features is None else [out.features])
    weights = [torch.randn(image.shape, generator=generator, dtype=torch.float64) for image in images]
    loss = sum(scale * (image * weight.to(image.dtype)).sum()
               for scale, image, weight in zip((1.0, 1.0, 0.1, 0.3), images, weights))  # fmt: skip
    loss.backward()
    means2d = out.info["means2d"]
    grads = {key: leaf.grad for key, leaf in leaves.items()}
    grads |= {"means2d.grad": means2d.grad, "means2d.absgrad": getattr(means2d, "absgrad", None)}
    return out, grads


def plain(tensor):
    return None if tensor is None else tensor.detach().as_subclass(torch.Tensor)


def assert_close(actual, expected, rtol: float, name: str) -> None:
    assert actual is not None, f"{name}: missing"
    actual, expected = plain(actual), plain(expected)
    assert actual.dtype == expected.dtype, f"{name}: {actual.dtype} != {expected.dtype}"
    scale = expected.abs().max().item() if expected.numel() else 0.0
    torch.testing.assert_close(actual, expected, rtol=rtol, atol=rtol * max(scale, 1e-30), msg=name)


def assert_same_render(ours, our_grads, theirs, their_grads, rtol: float) -> None:
    assert theirs.info["backend"] == "gsplat"
    assert torch.equal(theirs.info["visible"], ours.info["visible"]), "visible Gaussians differ"
    assert torch.equal(theirs.info["radii_xy"], ours.info["radii_xy"]), "radii differ"
    for name in ("rgb", "alpha", "depth"):
        assert_close(getattr(theirs, name), getattr(ours, name), rtol, name)
    assert (theirs.features is None) == (ours.features is None), "features"
    if ours.features is not None:
        assert_close(theirs.features, ours.features, rtol, "features")
    for name, expected in our_grads.items():
        assert_close(their_grads[name], expected, rtol, f"gradient of {name}")


REFERENCES: dict[tuple, tuple] = {}


def torch_reference(dtype, sh_degree):
    key = (dtype, sh_degree)
    if key not in REFERENCES:
        REFERENCES[key] = render(make_scene(dtype, sh_degree), "torch")
    return REFERENCES[key]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("sh_degree", [None, 0, 1, 2, 3], ids=["rgb", "sh0", "sh1", "sh2", "sh3"])
def test_gsplat_backend_matches_torch_backend(stand_in, dtype, sh_degree):
    scene = make_scene(dtype, sh_degree)
    ours, our_grads = torch_reference(dtype, sh_degree)
    theirs, their_grads = render(scene, "gsplat")
    assert set(stand_in) == KERNELS - ({"spherical_harmonics_fwd", "spherical_harmonics_bwd"} if sh_degree is None
                                       else set()), "every kernel went through its stand-in"  # fmt: skip
    assert_same_render(ours, our_grads, theirs, their_grads, TOLERANCES[dtype])

    # The scene has what it is meant to have.
    visible = ours.info["visible"]
    n_random = len(visible) - len(PLACED)
    assert visible[:n_random].sum() >= n_random - 4
    assert visible[n_random:].tolist() == [False] * 6 + [True, True, False, True, True, True, True, True, True]
    assert 0.999 - 1e-6 < ours.alpha.max() < 1.0 and (ours.alpha < 0.5).any()
    # Culled rows: NaN in gsplat's outputs here (uninitialised memory on a GPU), never read.
    depths, means2d = theirs.info["depths"], theirs.info["means2d"]
    assert torch.isnan(depths[~visible]).all() and torch.isnan(means2d.detach()[~visible]).all()
    assert (means2d.grad[~visible] == 0).all() and (means2d.absgrad[~visible] == 0).all()
    for name, grad in their_grads.items():
        assert torch.isfinite(grad).all(), name
        assert grad.abs().max() > 0, f"gradient of {name} is zero: the comparison would prove nothing"
    # absgrad sums |per-pixel gradient|, so it bounds |grad| and differs from it.
    assert (means2d.absgrad >= means2d.grad.abs() * (1 - 1e-6)).all()
    assert (means2d.absgrad > means2d.grad.abs() * 1.01).any()


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("n_features", [1, 2, MAX_EXTRA_FEATURES])
def test_extra_features_through_gsplat_match_the_torch_backend(stand_in, dtype, n_features):
    """RGB + depth + 1, 2 or 4 extra channels: 5 and 8 go to gsplat's kernels as they are, 6 padded to 8
    by its wrapper (and the padding cut off again); gradients to the features and through the weights."""
    scene = make_scene(dtype, 1)
    generator = torch.Generator().manual_seed(2)
    scene["features"] = torch.randn(scene["means"].shape[0], n_features, generator=generator).to(dtype)
    ours, our_grads = render(scene, "torch")
    theirs, their_grads = render(scene, "gsplat")
    assert theirs.features.shape == (HEIGHT, WIDTH, n_features)
    assert ours.features.abs().max() > 0.5 and our_grads["features"].abs().max() > 0
    assert_same_render(ours, our_grads, theirs, their_grads, TOLERANCES[dtype])


def test_the_stand_in_refuses_a_channel_count_gsplat_has_no_kernel_for(stand_in):
    scene = make_scene(torch.float32, None)
    n = scene["means"].shape[0]
    means2d, conics = torch.zeros(1, n, 2), torch.zeros(1, n, 3)
    offsets, ids = torch.zeros(1, 2, 2, dtype=torch.int32), torch.zeros(0, dtype=torch.int32)
    with pytest.raises(kernels.StandInError, match="Unsupported number of channels: 6"):
        kernels.rasterize_to_pixels_3dgs_fwd(
            means2d, conics, torch.zeros(1, n, 6), torch.ones(1, n), None, None, WIDTH, HEIGHT, 16, offsets, ids
        )


# ---------------------------------------------------------------- the mapping, broken on purpose


def wrap(monkeypatch, name, change):
    """Make liquidgs' gsplat backend pass changed arguments to gsplat.<name> (it imports at call time)."""
    original = getattr(gsplat, name)

    def changed(*args, **kwargs):
        args, kwargs = list(args), dict(kwargs)
        change(args, kwargs)
        return original(*args, **kwargs)

    monkeypatch.setattr(gsplat, name, changed)


def quaternions_xyzw(monkeypatch):
    wrap(monkeypatch, "fully_fused_projection", lambda a, k: a.__setitem__(2, a[2][:, [1, 2, 3, 0]]))


def log_scales(monkeypatch):
    wrap(monkeypatch, "fully_fused_projection", lambda a, k: a.__setitem__(3, a[3].log()))


def opacity_logits(monkeypatch):
    wrap(monkeypatch, "fully_fused_projection", lambda a, k: k.__setitem__("opacities", k["opacities"].logit()))
    wrap(monkeypatch, "rasterize_to_pixels", lambda a, k: a.__setitem__(3, a[3].logit()))


def camera_to_world_viewmat(monkeypatch):
    wrap(monkeypatch, "fully_fused_projection", lambda a, k: a.__setitem__(4, torch.linalg.inv(a[4])))


def transposed_k(monkeypatch):
    wrap(monkeypatch, "fully_fused_projection", lambda a, k: a.__setitem__(5, a[5].transpose(-1, -2)))


def sh_degree_off_by_one(monkeypatch):
    wrap(monkeypatch, "spherical_harmonics", lambda a, k: a.__setitem__(0, a[0] + 1 if a[0] < 3 else a[0] - 1))


def background_dropped(monkeypatch):
    wrap(monkeypatch, "rasterize_to_pixels", lambda a, k: k.__setitem__("backgrounds", None))


def absgrad_off(monkeypatch):
    wrap(monkeypatch, "rasterize_to_pixels", lambda a, k: k.__setitem__("absgrad", False))


def absgrad_as_abs_of_grad(monkeypatch):
    """absgrad taken as |sum over pixels| rather than gsplat's sum over pixels of |.|."""

    def change(args, kwargs):
        kwargs["absgrad"] = False
        means2d = args[0]
        means2d.register_hook(lambda grad: setattr(means2d, "absgrad", grad.abs()))

    wrap(monkeypatch, "rasterize_to_pixels", change)


MUTATIONS = {
    "quaternions xyzw": (quaternions_xyzw, AssertionError),
    "log-scales": (log_scales, AssertionError),
    "opacity logits": (opacity_logits, AssertionError),
    "camera-to-world viewmat": (camera_to_world_viewmat, AssertionError),
    "transposed K": (transposed_k, AssertionError),
    "SH degree off by one": (sh_degree_off_by_one, AssertionError),
    "background dropped": (background_dropped, AssertionError),
    # No .absgrad from gsplat: liquidgs' hook that copies it fails in backward.
    "absgrad off": (absgrad_off, AttributeError),
    "absgrad as |grad|": (absgrad_as_abs_of_grad, AssertionError),
}


@pytest.mark.parametrize("mutation", list(MUTATIONS))
def test_a_broken_mapping_is_caught(stand_in, monkeypatch, mutation):
    apply, caught_as = MUTATIONS[mutation]
    dtype, sh_degree = torch.float64, 1
    ours, our_grads = torch_reference(dtype, sh_degree)
    apply(monkeypatch)
    with pytest.raises(caught_as):
        theirs, their_grads = render(make_scene(dtype, sh_degree), "gsplat")
        assert_same_render(ours, our_grads, theirs, their_grads, TOLERANCES[dtype])


# ---------------------------------------------------------------- the near plane, and the rest of the set-up


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
def test_depth_on_the_near_and_far_planes_is_kept_as_gsplat_does(stand_in, dtype):
    """gsplat's projection kernel culls `mean_c.z < near_plane || mean_c.z > far_plane`."""
    near, far = torch.tensor(0.01, dtype=dtype), torch.tensor(5.0, dtype=dtype)
    depths = [near, torch.nextafter(near, torch.zeros_like(near)), far, torch.nextafter(far, 2 * far)]
    scene = {key: value[:4] if key in PARAMETERS else value for key, value in make_scene(dtype, None).items()}
    scene["means"] = torch.zeros(4, 3, dtype=dtype)
    scene["means"][:, 2] = torch.stack(depths)
    scene["means"][2:, 0] = 0.3  # x / z = 0.06 at the far plane: inside the image
    scene["opacities"] = torch.full((4,), 0.5, dtype=dtype)
    scene["viewmat"] = torch.eye(4, dtype=dtype)
    kwargs = {"near_plane": 0.01, "far_plane": 5.0}
    backends = ["torch", "gsplat"] + (["cpu"] if cpu_backend.unavailable_reason(scene["means"]) is None else [])
    outputs = {backend: render(scene, backend, **kwargs) for backend in backends}
    for backend, (out, _) in outputs.items():
        assert out.info["visible"].tolist() == [True, False, True, False], backend
        assert (out.info["depths"][0] == near).item() and (out.info["depths"][2] == far).item()
    ours, our_grads = outputs["torch"]
    for backend in backends[1:]:
        theirs, their_grads = outputs[backend]
        if backend == "gsplat":
            assert_same_render(ours, our_grads, theirs, their_grads, TOLERANCES[dtype])
        else:
            for name in ("rgb", "alpha", "depth"):
                assert_close(getattr(theirs, name), getattr(ours, name), TOLERANCES[dtype], f"{backend} {name}")


def test_every_backend_returns_the_same_info(stand_in):
    """One info builder: the same keys from each backend, and tiling figures that mean the same."""
    scene = make_scene(torch.float32, 1)
    backends = ["torch", "gsplat"] + (["cpu"] if cpu_backend.unavailable_reason(scene["means"]) is None else [])
    infos = {backend: render(scene, backend, tile_size=8)[0].info for backend in backends}
    keys = set(infos["torch"])
    assert {"means2d", "radii", "radii_xy", "visible", "depths", "conics", "tile_size", "n_pairs"} <= keys
    for backend, info in infos.items():
        assert set(info) == keys and info["backend"] == backend, backend
        assert torch.equal(info["radii"], info["radii_xy"].amax(dim=1)), backend
    # gsplat tiles at its own 16 px: a Gaussian's pairs are the 16 px tiles its box touches.
    assert infos["gsplat"]["tile_size"] == gsplat_backend.GSPLAT_TILE_SIZE
    assert 0 < infos["gsplat"]["n_pairs"] < infos["torch"]["n_pairs"]
    if "cpu" in infos:
        assert (infos["cpu"]["tile_size"], infos["cpu"]["n_pairs"]) == (8, infos["torch"]["n_pairs"])


def test_a_kernel_without_a_stand_in_raises_instead_of_compiling(stand_in):
    quats, scales = torch.randn(3, 4), torch.rand(3, 3)
    with pytest.raises(RuntimeError, match="no CPU stand-in"):
        gsplat.quat_scale_to_covar_preci(quats, scales)


def test_gsplat_backend_is_float32_only():
    """rasterize_to_pixels' kernels read float pointers: float64 on a GPU goes elsewhere."""
    on_gpu = types.SimpleNamespace(device=torch.device("cuda", 0), dtype=torch.float64)
    reason = gsplat_backend.unavailable_reason(on_gpu)
    assert reason is not None and "float32" in reason
