import math

import numpy as np
import pytest
import torch

from liquidgs.errors import DataError
from liquidgs.gaussians import (
    activate,
    init_from_points,
    init_random_box,
    mean_sq_dist_to_neighbors,
    read_ply,
    write_ply,
)


def brute_force_mean_sq_dist(points: np.ndarray, k: int) -> np.ndarray:
    d2 = ((points[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    return np.sort(d2, axis=1)[:, :k].mean(axis=1)


def test_knn_matches_brute_force():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(700, 3))
    ours = mean_sq_dist_to_neighbors(torch.from_numpy(points), k=3).numpy()
    np.testing.assert_allclose(ours, brute_force_mean_sq_dist(points, 3), rtol=1e-5)


def test_knn_duplicates_and_tiny_inputs():
    points = torch.tensor([[0.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0], [0.0, 2, 0]])
    d2 = mean_sq_dist_to_neighbors(points, k=3)
    # The duplicate pair sees each other at distance 0.
    assert d2[0].item() == pytest.approx((0 + 1 + 4) / 3)
    assert mean_sq_dist_to_neighbors(torch.zeros(1, 3)).shape == (1,)
    assert mean_sq_dist_to_neighbors(torch.zeros(2, 3), k=3).tolist() == [0.0, 0.0]


def test_knn_handles_100k_points_quickly():
    import time

    points = torch.rand(100_000, 3)
    started = time.perf_counter()
    d2 = mean_sq_dist_to_neighbors(points)
    assert time.perf_counter() - started < 10.0
    assert d2.shape == (100_000,) and torch.isfinite(d2).all() and (d2 > 0).all()


def test_random_box_init_follows_d3dgs():
    params = init_random_box(2000, half_extent=1.3, sh_degree=3, seed=1)
    assert params["means"].abs().max() <= 1.3
    assert params["shN"].shape == (2000, 15, 3)
    act = activate(params)
    assert torch.allclose(act["opacities"], torch.full((2000,), 0.1), atol=1e-6)
    assert torch.equal(act["quats"], torch.tensor([1.0, 0, 0, 0]).expand(2000, 4))
    # Isotropic scale: sqrt of the mean of the 3 nearest squared distances.
    d2 = mean_sq_dist_to_neighbors(params["means"]).clamp_min(1e-7)
    assert torch.allclose(act["scales"][:, 0], d2.sqrt(), rtol=1e-5)
    assert torch.equal(act["scales"][:, 0], act["scales"][:, 2])
    # Near-grey: DC in [0, 1/255] renders as 0.5 plus at most a hair.
    rgb = params["sh0"] * 0.28209479177387814 + 0.5
    assert rgb.min() >= 0.5 and rgb.max() < 0.5 + 0.3 / 255
    again = init_random_box(2000, 1.3, seed=1)
    assert torch.equal(again["means"], params["means"])


def test_point_cloud_init_keeps_colours():
    points = torch.rand(50, 3)
    colors = torch.rand(50, 3)
    params = init_from_points(points, colors, sh_degree=1)
    rgb = params["sh0"][:, 0] * 0.28209479177387814 + 0.5
    assert torch.allclose(rgb, colors, atol=1e-6)
    assert params["shN"].shape == (50, 3, 3)
    with pytest.raises(ValueError, match="points"):
        init_from_points(torch.rand(5, 2))


@pytest.mark.parametrize("sh_degree", [0, 3])
def test_ply_round_trip_is_bit_exact(tmp_path, sh_degree):
    params = init_random_box(500, 1.3, sh_degree=sh_degree, seed=3)
    with torch.no_grad():
        for value in params.values():
            value.add_(torch.randn_like(value))
    path = write_ply(tmp_path / "scene.ply", params)
    loaded = read_ply(path)
    for key, value in params.items():
        assert torch.equal(loaded[key], value.detach()), key
    assert not list(tmp_path.glob(".*.tmp*")), "no temporary file may be left behind"


def test_ply_layout_is_the_standard_one(tmp_path):
    from plyfile import PlyData

    params = init_random_box(10, 1.3, sh_degree=3, seed=0)
    write_ply(tmp_path / "a.ply", params)
    ply = PlyData.read(str(tmp_path / "a.ply"))
    names = [p.name for p in ply["vertex"].properties]
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert names[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert ply.byte_order == "<"
    # f_rest is channel-major: f_rest_0..14 are the red coefficients.
    red = np.stack([ply["vertex"][f"f_rest_{i}"] for i in range(15)], axis=1)
    assert np.array_equal(red, params["shN"][:, :, 0].detach().numpy())
    assert math.isclose(float(ply["vertex"]["opacity"][0]), float(params["opacities"][0].detach()), rel_tol=0)


def test_ply_errors_name_file_and_field(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"not a ply at all")
    with pytest.raises(DataError, match="bad.ply"):
        read_ply(bad)
    from plyfile import PlyData, PlyElement

    vertex = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(tmp_path / "partial.ply"))
    with pytest.raises(DataError, match="field 'f_dc_0'"):
        read_ply(tmp_path / "partial.ply")
