"""Bad arguments to `rasterize` raise ValueError naming the argument."""

from __future__ import annotations

import pytest
import torch

from liquidgs.render import rasterize


def valid_arguments(n: int = 4) -> dict:
    return {
        "means": torch.randn(n, 3) * 0.1,
        "quats": torch.randn(n, 4),
        "scales": torch.full((n, 3), 0.1),
        "opacities": torch.full((n,), 0.5),
        "colors": torch.rand(n, 3),
        "viewmat": torch.tensor([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]),
        "K": torch.tensor([[20.0, 0, 8], [0, 20, 8], [0, 0, 1]]),
        "width": 16,
        "height": 16,
    }


def call(arguments: dict, **options):
    options.setdefault("backend", "torch")
    return rasterize(**arguments, **options)


def test_valid_arguments_render():
    assert call(valid_arguments()).rgb.shape == (16, 16, 3)


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("means", torch.zeros(4, 2), r"means must have shape \[N,3\], got \[4, 2\]"),
        ("quats", torch.zeros(4, 3), r"quats must have shape \[N,4\] with N=4, got \[4, 3\]"),
        ("quats", torch.zeros(5, 4), r"quats must have shape \[N,4\] with N=4, got \[5, 4\]"),
        ("scales", torch.zeros(3, 3), r"scales must have shape \[N,3\] with N=4"),
        ("opacities", torch.zeros(4, 1), r"opacities must have shape \[N\] with N=4"),
        ("colors", torch.zeros(4, 4), r"colors must have shape \[N,3\] with N=4"),
        ("viewmat", torch.eye(3), r"viewmat must have shape \[4,4\]"),
        ("K", torch.eye(4), r"K must have shape \[3,3\]"),
        ("means", torch.zeros(4, 3, dtype=torch.int64), "means must be a floating-point tensor"),
        ("colors", [[0.0, 0.0, 0.0]] * 4, "colors must be a torch.Tensor"),
        ("width", 0, "width must be an integer >= 1"),
        ("height", -3, "height must be an integer >= 1"),
        ("width", 16.0, "width must be an integer >= 1"),
    ],
)
def test_bad_shapes_and_sizes(name, value, message):
    arguments = valid_arguments() | {name: value}
    with pytest.raises(ValueError, match=message):
        call(arguments)


@pytest.mark.parametrize("name", ["means", "quats", "scales", "opacities", "colors", "viewmat", "K"])
@pytest.mark.parametrize("bad_value", [float("nan"), float("inf")])
def test_non_finite_inputs(name, bad_value):
    arguments = valid_arguments()
    arguments[name] = arguments[name].clone()
    arguments[name].view(-1)[0] = bad_value
    with pytest.raises(ValueError, match=f"{name} contains NaN or inf"):
        call(arguments)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_finiteness_check_is_exact(dtype):
    from liquidgs.render.rasterize import _all_finite

    big = torch.finfo(dtype).max
    assert _all_finite(torch.full((100, 3), big, dtype=dtype))  # a sum that overflows is asked again
    assert _all_finite(torch.tensor([big, -big], dtype=dtype))
    for values in ([1.0, float("inf"), float("-inf")], [float("-inf")] * 20, [0.0] * 30 + [float("nan")]):
        assert not _all_finite(torch.tensor(values, dtype=dtype))


def test_bad_background():
    with pytest.raises(ValueError, match=r"background must have shape \[3\]"):
        call(valid_arguments(), background=torch.zeros(4))
    with pytest.raises(ValueError, match="background contains NaN or inf"):
        call(valid_arguments(), background=torch.tensor([0.0, float("nan"), 0.0]))


def test_unknown_backend():
    with pytest.raises(ValueError, match="backend must be one of"):
        call(valid_arguments(), backend="cuda")


def test_colors_and_sh_degree_mismatch():
    with pytest.raises(ValueError, match=r"colors must have shape \[N,3\].*sh_degree is None"):
        call(valid_arguments() | {"colors": torch.zeros(4, 16, 3)})
    with pytest.raises(ValueError, match=r"colors must have shape \[N,K,3\].*sh_degree is set"):
        call(valid_arguments(), sh_degree=1)
    with pytest.raises(ValueError, match="at least 16 SH coefficients for sh_degree=3"):
        call(valid_arguments() | {"colors": torch.zeros(4, 9, 3)}, sh_degree=3)
    with pytest.raises(ValueError, match="sh_degree must be None or an integer in 0..3"):
        call(valid_arguments() | {"colors": torch.zeros(4, 25, 3)}, sh_degree=4)


def test_bad_tile_size():
    with pytest.raises(ValueError, match="tile_size must be an integer >= 1"):
        call(valid_arguments(), tile_size=0)


@pytest.mark.parametrize(
    ("features", "message"),
    [
        (torch.zeros(4), r"features must have shape \[N,C\] with N=4, 1 <= C <= 4, got \[4\]"),
        (torch.zeros(3, 2), r"features must have shape \[N,C\] with N=4, 1 <= C <= 4, got \[3, 2\]"),
        (torch.zeros(4, 0), r"features must have 1 to 4 channels, got shape \[4, 0\]"),
        (torch.zeros(4, 5), r"features must have 1 to 4 channels, got shape \[4, 5\]"),
        (torch.zeros(4, 2, dtype=torch.int64), "features must be a floating-point tensor"),
        (torch.tensor([[0.0, 1.0]] * 3 + [[float("nan"), 0.0]]), "features contains NaN or inf"),
        ([[0.0, 0.0]] * 4, "features must be a torch.Tensor"),
    ],
)
def test_bad_features(features, message):
    with pytest.raises(ValueError, match=message):
        call(valid_arguments(), features=features)
    assert call(valid_arguments(), features=torch.zeros(4, 4)).features.shape == (16, 16, 4)
