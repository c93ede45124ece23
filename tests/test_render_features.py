"""Extra feature channels composited in the colour pass (rasterize's `features`): the torch backend
against the dense reference, the compiled CPU kernel against the torch backend, gradients included.
(The gsplat backend's are in test_gsplat_cpu.py; the screen motion the flow loss renders this way,
in test_flow_loss.py.)"""

from __future__ import annotations

import pytest
import torch

from liquidgs.render import cpu_backend
from liquidgs.render.contract import MAX_EXTRA_FEATURES
from test_render import PARAMETERS, random_scene, reference_composite, render

needs_kernel = pytest.mark.skipif(
    cpu_backend.unavailable_reason() is not None,
    reason=f"compiled CPU rasteriser unavailable: {cpu_backend.unavailable_reason()}",
)


def extra_features(scene: dict, channels: int, seed: int = 11) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    n = scene["means"].shape[0]
    return torch.randn(n, channels, generator=generator, dtype=torch.float64).to(scene["means"])


def images_and_gradients(scene: dict, features: torch.Tensor, render_fn) -> tuple[tuple, dict]:
    """render_fn(scene, features) -> (rgb, alpha, depth, features image); a random weighting of all
    four is back-propagated to the Gaussians' parameters and the features."""
    leaves = {key: scene[key].clone().requires_grad_(True) for key in PARAMETERS}
    features = features.clone().requires_grad_(True)
    images = render_fn(scene | leaves, features)
    generator = torch.Generator().manual_seed(1)
    weights = [torch.randn(image.shape, generator=generator, dtype=image.dtype).to(image.device) for image in images]
    loss = sum((image * weight).sum() for image, weight in zip(images, weights))
    loss.backward()
    grads = {key: leaf.grad for key, leaf in leaves.items()} | {"features": features.grad}
    return tuple(image.detach() for image in images), grads


def backend_images(backend: str, **kwargs):
    def render_fn(scene, features):
        out = render(scene, backend=backend, features=features, **kwargs)
        return out.rgb, out.alpha, out.depth, out.features

    return render_fn


def reference_images(scene, features):
    accumulated, alpha = reference_composite(scene, features)
    return accumulated[..., :3], alpha, accumulated[..., 3:4] / alpha.clamp_min(1e-10), accumulated[..., 4:]


def assert_all_close(got: tuple, want: tuple, got_grads: dict, want_grads: dict, rtol: float) -> None:
    for index, (image, expected) in enumerate(zip(got, want)):
        torch.testing.assert_close(image, expected, rtol=rtol, atol=rtol, msg=f"image {index}")
    for key, expected in want_grads.items():
        assert expected.abs().max() > 0, f"the gradient of {key} is zero: the comparison would prove nothing"
        scale = expected.abs().max().item()
        torch.testing.assert_close(got_grads[key], expected, rtol=rtol, atol=rtol * scale, msg=key)


@pytest.mark.parametrize(("seed", "channels", "sh_degree"), [(0, 1, None), (1, 2, 2), (2, MAX_EXTRA_FEATURES, None)])
def test_torch_backend_matches_the_dense_reference_float64(seed, channels, sh_degree):
    scene = random_scene(80, seed=seed, dtype=torch.float64, sh_degree=sh_degree)
    features = extra_features(scene, channels)
    ours, our_grads = images_and_gradients(scene, features, backend_images("torch"))
    reference, reference_grads = images_and_gradients(scene, features, reference_images)
    assert ours[3].shape == (scene["height"], scene["width"], channels)
    assert ours[1].max() > 0.9, "the scene should contain saturated pixels"
    assert_all_close(ours, reference, our_grads, reference_grads, 1e-9)


def test_gradcheck_with_features_tiny_scene():
    scene = random_scene(4, width=7, height=6, seed=6, dtype=torch.float64, scale_range=(0.2, 0.4))
    scene["opacities"] = torch.tensor([0.3, 0.6, 0.5, 0.8], dtype=torch.float64)

    def images(means, quats, scales, opacities, features):
        out = render(scene | dict(zip(PARAMETERS, (means, quats, scales, opacities))), features=features)
        return out.features, out.rgb

    inputs = tuple(scene[key].clone().requires_grad_(True) for key in PARAMETERS[:4])
    features = extra_features(scene, 2).requires_grad_(True)
    assert torch.autograd.gradcheck(images, (*inputs, features), eps=1e-7, atol=1e-6, rtol=1e-5)


@needs_kernel
@pytest.mark.parametrize("channels", range(1, MAX_EXTRA_FEATURES + 1))
@pytest.mark.parametrize(("seed", "width", "height", "tile_size"), [(3, 23, 17, 4), (4, 37, 41, 16)])
def test_cpu_kernel_matches_the_torch_backend_float64(channels, seed, width, height, tile_size):
    scene = random_scene(200, width=width, height=height, seed=seed, dtype=torch.float64, sh_degree=1)
    features = extra_features(scene, channels, seed)
    ours, our_grads = images_and_gradients(scene, features, backend_images("cpu", tile_size=tile_size))
    reference, reference_grads = images_and_gradients(scene, features, backend_images("torch"))
    assert_all_close(ours, reference, our_grads, reference_grads, 1e-10)


@needs_kernel
def test_cpu_kernel_float32_within_the_tolerance_of_colour():
    scene = random_scene(1500, width=96, height=64, seed=5, scale_range=(0.01, 0.1))
    features = extra_features(scene, 2)
    ours, our_grads = images_and_gradients(scene, features, backend_images("cpu"))
    reference, reference_grads = images_and_gradients(scene, features, backend_images("torch"))
    for image, expected in zip(ours, reference):
        torch.testing.assert_close(image, expected, rtol=1e-4, atol=1e-4)
    for key, expected in reference_grads.items():
        scale = expected.abs().max().item()
        torch.testing.assert_close(our_grads[key], expected, rtol=1e-3, atol=1e-4 * scale, msg=key)


@pytest.mark.parametrize("backend", ["torch", pytest.param("cpu", marks=needs_kernel)])
def test_features_leave_colour_alpha_and_depth_as_they_were(backend):
    scene = random_scene(150, seed=8, dtype=torch.float64)
    plain = render(scene, backend=backend)
    with_features = render(scene, backend=backend, features=extra_features(scene, 3))
    assert plain.features is None
    for name in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(getattr(with_features, name), getattr(plain, name), rtol=1e-13, atol=1e-13)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs an NVIDIA GPU")
@pytest.mark.parametrize("channels", [2, MAX_EXTRA_FEATURES])
def test_gsplat_kernels_composite_features_as_the_torch_backend_on_cuda(channels):
    """gsplat's CUDA kernels themselves (6 channels padded to 8, 8 as they are), against the torch
    backend on the same GPU, at gsplat's own test tolerances for colours (test_render.CUDA_TOLERANCES)."""
    scene = random_scene(400, width=96, height=72, seed=23, scale_range=(0.02, 0.15))
    scene = {key: value.cuda() if isinstance(value, torch.Tensor) else value for key, value in scene.items()}
    features = extra_features(scene, channels)
    ours, our_grads = images_and_gradients(scene, features, backend_images("torch"))
    theirs, their_grads = images_and_gradients(scene, features, backend_images("gsplat"))
    for image, expected in zip(theirs[:2] + theirs[3:], ours[:2] + ours[3:]):
        torch.testing.assert_close(image, expected, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(their_grads["features"], our_grads["features"], rtol=1e-3, atol=1e-3)
    torch.testing.assert_close(their_grads["opacities"], our_grads["opacities"], rtol=8e-3, atol=6e-3)
