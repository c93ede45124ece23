"""The HexPlane field (4DGaussians) against a naive float64 reference: bilinear plane sampling, the
fused multi-resolution feature, the decoders, gradients, and the grid regularisers by hand."""

import pytest
import torch

from field_reference import assert_matches_with_gradients
from liquidgs.errors import ConfigError
from liquidgs.fields.hexplane import (
    PRESETS,
    SPACE_PLANES,
    TIME_PLANES,
    HexPlaneConfig,
    HexPlaneField,
    sample_planes,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")

# Small enough for the loops below; non-square time planes so that a swapped axis cannot pass.
SMALL = dict(resolution=4, time_resolution=3, features=2, multires=(1, 2), width=5)


def small_field(**overrides) -> HexPlaneField:
    torch.manual_seed(0)
    field = HexPlaneField(HexPlaneConfig.preset("tiny", **{**SMALL, **overrides})).double()
    with torch.no_grad():  # away from the constant time planes of the initialisation
        for level in field.levels:
            level.space.uniform_(-1, 1)
            level.time.uniform_(-1, 1)
        field.aabb.copy_(torch.tensor([[-1.0, -2.0, 0.0], [1.0, 0.5, 3.0]]))
    return field


def bilinear_naive(plane: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """plane [C, H, W] at (u, v) in [-1, 1]: u along W, v along H, -1 / 1 the first / last node,
    clamped outside; written with explicit indices, one point at a time."""
    height, width = plane.shape[1:]
    col = ((u + 1) / 2 * (width - 1)).clamp(0, width - 1)
    row = ((v + 1) / 2 * (height - 1)).clamp(0, height - 1)
    c0, r0 = int(col.floor()), int(row.floor())
    c1, r1 = min(c0 + 1, width - 1), min(r0 + 1, height - 1)
    fc, fr = col - c0, row - r0
    return (
        plane[:, r0, c0] * (1 - fc) * (1 - fr)
        + plane[:, r0, c1] * fc * (1 - fr)
        + plane[:, r1, c0] * (1 - fc) * fr
        + plane[:, r1, c1] * fc * fr
    )


def fused_naive(field: HexPlaneField, xyz: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """For each point and level: the product over the planes 'ab' of plane_ab at (a, b), the
    position mapped by the box to [-1, 1] and the time used as it is; levels concatenated."""
    low, high = field.aabb
    rows = []
    for i in range(xyz.shape[0]):
        unit = {axis: 2 * (xyz[i, k] - low[k]) / (high[k] - low[k]) - 1 for k, axis in enumerate("xyz")}
        unit["t"] = t[i if t.shape[0] > 1 else 0, 0]
        levels = []
        for level in field.levels:
            product = 1.0
            for planes, names in ((level.space, SPACE_PLANES), (level.time, TIME_PLANES)):
                for plane, (a, b) in zip(planes, names):
                    product = product * bilinear_naive(plane, unit[a], unit[b])
            levels.append(product)
        rows.append(torch.cat(levels))
    return torch.stack(rows)


def decoders_naive(field: HexPlaneField, feature: torch.Tensor):
    """Linear, then per head ReLU-Linear-ReLU-Linear, written as products with the weights."""

    def linear(layer, x):
        return x @ layer.weight.t() + layer.bias

    hidden = linear(field.feature_out, feature)
    heads = (
        (field.hidden_xyz, field.head_xyz),
        (field.hidden_rotation, field.head_rotation),
        (field.hidden_scaling, field.head_scaling),
    )
    return tuple(linear(last, torch.relu(linear(first, torch.relu(hidden)))) for first, last in heads)


def sample_points(generator: torch.Generator, n: int) -> torch.Tensor:
    """Points inside and outside the small field's box, some exactly on its faces."""
    xyz = torch.rand(n, 3, dtype=torch.float64, generator=generator) * torch.tensor([3.0, 3.5, 4.0]) - torch.tensor(
        [1.5, 2.5, 0.5]
    )
    xyz[0] = torch.tensor([-1.0, -2.0, 0.0])
    xyz[1] = torch.tensor([1.0, 0.5, 3.0])
    return xyz


def test_plane_sampling_matches_explicit_bilinear_with_gradients():
    generator = torch.Generator().manual_seed(1)
    planes = torch.randn(3, 2, 5, 7, dtype=torch.float64, generator=generator, requires_grad=True)
    coords = torch.rand(3, 40, 2, dtype=torch.float64, generator=generator) * 2.6 - 1.3
    coords[:, 0] = torch.tensor([-1.0, 1.0])  # corners and nodes exactly
    coords[:, 1] = torch.tensor([0.0, -0.5])
    coords.requires_grad_(True)
    weights = torch.randn(3, 2, 40, dtype=torch.float64, generator=generator)
    got = sample_planes(planes, coords)
    want = torch.stack(
        [torch.stack([bilinear_naive(planes[p], *coords[p, i]) for i in range(40)], dim=1) for p in range(3)]
    )
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    (got_planes, got_coords), (want_planes, want_coords) = (
        torch.autograd.grad((out * weights).sum(), (planes, coords)) for out in (got, want)
    )
    torch.testing.assert_close(got_planes, want_planes, rtol=1e-10, atol=1e-12)
    # On the box's faces the clamp has a kink: grid_sample takes the outer side (0), autograd of
    # clamp the inner one. Everywhere else, inside and outside, the position gradients agree.
    off_faces = coords.detach().abs() != 1
    torch.testing.assert_close(got_coords[off_faces], want_coords[off_faces], rtol=1e-10, atol=1e-12)
    assert off_faces.sum() == coords.numel() - 6


@pytest.mark.parametrize("shared_time", [True, False])
def test_fused_feature_matches_the_naive_product_with_gradients(shared_time):
    field = small_field()
    generator = torch.Generator().manual_seed(2)
    xyz = sample_points(generator, 30)
    t = torch.rand(1 if shared_time else 30, 1, dtype=torch.float64, generator=generator)
    weights = torch.randn(30, 4, dtype=torch.float64, generator=generator)
    results = []
    for compute in (field.grid_features, lambda x, s: fused_naive(field, x, s)):
        field.zero_grad()
        features = compute(xyz, t)
        (features * weights).sum().backward()
        results.append((features.detach(), {n: p.grad.clone() for n, p in field.named_parameters() if "levels" in n}))
    (got, got_grads), (want, want_grads) = results
    assert got.shape == (30, 4)
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    for name in want_grads:
        torch.testing.assert_close(got_grads[name], want_grads[name], rtol=1e-10, atol=1e-12, msg=name)


@pytest.mark.parametrize("shared_time", [True, False])
def test_field_matches_the_naive_field_with_gradients(shared_time):
    field = small_field()

    def reference(field, xyz, t):
        return decoders_naive(field, fused_naive(field, xyz, t))

    assert_matches_with_gradients(field, reference, shared_time, time=0.3)


def test_grid_layout_of_the_4dgaussians_presets():
    """dnerf: 64^3 x 25 with 32 channels at multipliers 1, 2, width 64; nerfds (4DGaussians'
    HyperNeRF config): 64^3 x 150 with 16 channels at 1, 2, 4, width 128."""
    for preset, levels, width, params in (
        ("dnerf", [(32, 64, 25), (32, 128, 25)], 64, 2_444_170),
        ("nerfds", [(16, 64, 150), (16, 128, 150), (16, 256, 150)], 128, 7_411_466),
    ):
        field = HexPlaneField(HexPlaneConfig.preset(preset))
        shapes = [(tuple(level.space.shape), tuple(level.time.shape)) for level in field.levels]
        assert shapes == [((3, c, r, r), (3, c, t, r)) for c, r, t in levels]
        assert (field.feature_out.in_features, field.feature_out.out_features) == (levels[0][0] * len(levels), width)
        assert field.num_parameters() == params
        linears = width * (len(levels) * levels[0][0]) + 3 * width * width + width * 10
        assert field.flops_per_gaussian() == 2 * linears


def test_output_shapes_and_time_broadcasting():
    field = HexPlaneField(HexPlaneConfig.preset("tiny")).eval()
    xyz = torch.randn(9, 3)
    reference = field(xyz, torch.full((9, 1), 0.25))
    assert [d.shape for d in reference] == [(9, 3), (9, 4), (9, 3)]
    for t in (0.25, torch.tensor([[0.25]]), torch.full((9,), 0.25)):
        for got, want in zip(field(xyz, t), reference):
            torch.testing.assert_close(got, want)
    with pytest.raises(ValueError, match="shape"):
        field(xyz, torch.zeros(4, 1))
    with pytest.raises(ValueError, match="xyz"):
        field(torch.zeros(9, 2), 0.5)


def test_initialisation_as_in_4dgaussians_gives_time_independent_deltas():
    """Space planes uniform in [0.1, 0.5], time planes 1: the fused feature, and so the deltas, do
    not depend on the time until the time planes have learnt something."""
    torch.manual_seed(3)
    field = HexPlaneField(HexPlaneConfig.preset("tiny"))
    for level in field.levels:
        assert level.space.min() >= 0.1 and level.space.max() <= 0.5
        assert torch.equal(level.time, torch.ones_like(level.time))
    xyz = torch.rand(50, 3) * 2 - 1
    for a, b in zip(field(xyz, 0.1), field(xyz, 0.9)):  # equal up to the rounding of the weights
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)
    with torch.no_grad():
        field.levels[0].time[0, :, -1] = 2.0  # the xt plane at t = 1
    assert (field(xyz, 0.1)[0] - field(xyz, 1.0)[0]).abs().max() > 1e-3


def test_the_field_stops_gradients_to_the_positions():
    field = HexPlaneField(HexPlaneConfig.preset("tiny"))
    xyz = torch.randn(8, 3, requires_grad=True)
    sum(d.sum() for d in field(xyz, 0.5)).backward()
    assert xyz.grad is None
    assert field.levels[0].space.grad is not None


def test_fit_bounds_maps_the_points_extent_onto_the_grid():
    field = small_field()
    points = torch.tensor([[0.0, 1.0, -1.0], [2.0, 5.0, 3.0], [1.0, 2.0, 0.0]], dtype=torch.float64)
    field.fit_bounds(points)
    torch.testing.assert_close(field.aabb, torch.tensor([[0.0, 1.0, -1.0], [2.0, 5.0, 3.0]], dtype=torch.float64))
    assert "aabb" in field.state_dict()  # a resumed run keeps the box it trained with
    # The box's low corner at t = 1 reads the first node of every space plane and of the time planes'
    # last row (t = 1): columns and rows in the order the plane's name gives the axes.
    level = field.levels[0]
    expected = level.space[:, :, 0, 0].prod(0) * level.time[:, :, -1, 0].prod(0)
    feature = field.grid_features(points[:1], torch.ones(1, 1, dtype=torch.float64))
    torch.testing.assert_close(feature[0, : SMALL["features"]], expected)
    for bad, match in (
        (torch.zeros(0, 3), "shape"),
        (torch.zeros(4, 2), "shape"),
        (torch.tensor([[0.0, 0.0, float("nan")], [1.0, 1.0, 1.0]]), "finite"),
        (torch.tensor([[0.0, 1.0, 2.0], [1.0, 1.0, 2.0]]), "along y, z"),
    ):
        with pytest.raises(ValueError, match=match):
            field.fit_bounds(bad)


def test_regulariser_against_hand_computed_values():
    """One level of 3 x 3 planes, one channel. Every plane varies along its rows (the second axis;
    the time axis of a time plane) only, so a smoothness taken along the columns would give 0.

    Space planes, rows (0, 1, 4), (0, 0, 0), (1, 2, 3): second differences 2, 0, 0 -> squared
    means over 1 x 3 entries 4, 0, 0 -> sum 4.
    Time planes, rows (1, 1, 2), (1, 3, 1), (1, 1, 1): second differences 1, -4, 0 -> means 1, 16,
    0 -> sum 17; mean |1 - plane|: 3/9, 6/9, 0 -> sum 1.
    """
    field = HexPlaneField(
        HexPlaneConfig.preset(
            "tiny",
            resolution=3,
            time_resolution=3,
            features=1,
            multires=(1,),
            space_smoothness_weight=0.5,
            time_smoothness_weight=0.25,
            time_l1_weight=2.0,
        )
    )
    level = field.levels[0]
    with torch.no_grad():
        for planes, rows in (
            (level.space, ((0, 1, 4), (0, 0, 0), (1, 2, 3))),
            (level.time, ((1, 1, 2), (1, 3, 1), (1, 1, 1))),
        ):
            planes.copy_(torch.tensor(rows, dtype=torch.float32)[:, None, :, None].expand(3, 1, 3, 3))
    loss = field.regulariser_loss()
    assert loss.item() == pytest.approx(0.5 * 4 + 0.25 * 17 + 2.0 * 1)
    loss.backward()
    assert level.space.grad.abs().sum() > 0 and level.time.grad.abs().sum() > 0


def test_regulariser_is_zero_at_a_constant_grid_and_sums_over_levels():
    field = HexPlaneField(HexPlaneConfig.preset("tiny", resolution=4, time_resolution=4))
    with torch.no_grad():
        for level in field.levels:
            level.space.fill_(0.3)
    assert field.regulariser_loss().item() == 0.0
    with torch.no_grad():
        for level in field.levels:
            level.time[:, :, 1] = 3.0
    # Each level: time rows (1, 3, 1, 1): second differences -4, 2 -> mean 10 per plane, 30 in all;
    # mean |1 - plane| 2 / 4 per plane, 1.5 in all. Space planes constant: 0.
    assert field.regulariser_loss().item() == pytest.approx(2 * (1e-2 * 30 + 1e-4 * 1.5))


def test_presets_and_bad_settings():
    assert set(PRESETS) == {"dnerf", "nerfds", "tiny"}
    assert HexPlaneConfig.preset("tiny", width=7).width == 7
    for overrides, match in (
        (dict(resolution=2), "resolution must be an integer >= 3"),
        (dict(time_resolution=2), "time_resolution must be an integer >= 3"),
        (dict(features=0), "features must be an integer >= 1"),
        (dict(multires=()), "multires"),
        (dict(multires=(1, 0)), "multires"),
        (dict(time_l1_weight=float("nan")), "time_l1_weight"),
        (dict(space_smoothness_weight=-1.0), "space_smoothness_weight"),
        (dict(grid_lr_scale=0.0), "grid_lr_scale must be a finite number > 0, got 0.0"),
        (dict(grid_lr_scale=float("inf")), "grid_lr_scale must be a finite number > 0, got inf"),
        (dict(depth=2), "unknown setting"),
    ):
        with pytest.raises(ConfigError, match=match):
            HexPlaneConfig.preset("tiny", **overrides)
    with pytest.raises(ConfigError, match="unknown hexplane preset 'lego'"):
        HexPlaneConfig.preset("lego")


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_the_grid_trains_ten_times_faster_than_the_decoder(preset):
    """4DGaussians' ratio in every preset: grid_lr_init 1.6e-3 against deformation_lr_init 1.6e-4."""
    field = HexPlaneField(HexPlaneConfig.preset(preset, **SMALL))
    (grid, planes, grid_scale), (decoder, layers, decoder_scale) = field.checked_param_groups()
    assert (grid, grid_scale, decoder, decoder_scale) == ("grid", 10.0, "decoder", 1.0)
    assert planes == [p for level in field.levels for p in (level.space, level.time)]
    assert {id(p) for p in layers} == {id(p) for n, p in field.named_parameters() if not n.startswith("levels")}


def test_training_the_field_alone_fits_a_known_displacement():
    """A few hundred points moving by a smooth function of (x, t): Adam with 4DGaussians' ten-times
    larger rate on the grid than on the decoders; the error must fall well below its start."""
    torch.manual_seed(4)
    field = HexPlaneField(HexPlaneConfig.preset("tiny"))
    xyz = torch.rand(300, 3) * 2 - 1
    field.fit_bounds(xyz)
    times = torch.linspace(0, 1, 6)

    def target(t):
        return 0.2 * torch.stack((torch.sin(3 * xyz[:, 1] + 2 * t), t * xyz[:, 0], torch.cos(2 * xyz[:, 2]) * t), 1)

    optimiser = torch.optim.Adam([{"params": params, "lr": 1e-3 * scale} for _, params, scale in field.param_groups()])

    def loss_at(t):
        dx, dr, ds = field(xyz, t)
        return (dx - target(t)).square().mean() + 0.01 * (dr.square().mean() + ds.square().mean())

    with torch.no_grad():
        start = sum(loss_at(t) for t in times).item()
    for step in range(60):
        t = times[step % len(times)]
        optimiser.zero_grad()
        (loss_at(t) + field.regulariser_loss()).backward()
        optimiser.step()
    with torch.no_grad():
        end = sum(loss_at(t) for t in times).item()
    assert end < 0.2 * start, (start, end)
