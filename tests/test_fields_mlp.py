"""The D-3DGS MLP, the encodings, the static field and the call interface shared by all fields."""

import pytest
import torch

from field_reference import assert_matches_with_gradients
from liquidgs.fields import FieldConfig, PositionalEncoding, build_field, field_names

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def embedder_reference(x: torch.Tensor, freqs: int) -> torch.Tensor:
    """The D-3DGS embedder: identity, then for each frequency 2^k a sin block and a cos block."""
    parts = [x]
    for k in range(freqs):
        parts += [torch.sin(x * 2.0**k), torch.cos(x * 2.0**k)]
    return torch.cat(parts, dim=-1)


@pytest.mark.parametrize(("dims", "freqs", "width"), [(3, 10, 63), (1, 6, 13), (1, 10, 21), (3, 0, 3)])
def test_positional_encoding_matches_the_d3dgs_embedder(dims, freqs, width):
    x = torch.randn(17, dims, dtype=torch.float64)
    encoding = PositionalEncoding(dims, freqs)
    out = encoding(x)
    assert encoding.out_dims == width == out.shape[1]
    torch.testing.assert_close(out, embedder_reference(x, freqs), rtol=0, atol=0)


@pytest.mark.parametrize(("preset", "inputs"), [("dnerf", 93), ("nerfds", 84)])
def test_mlp_layers_follow_the_reference(preset, inputs):
    field = build_field(FieldConfig(name="mlp", preset=preset))
    widths = [(layer.in_features, layer.out_features) for layer in field.layers]
    assert widths == [(inputs, 256)] + [(256, 256)] * 4 + [(256 + inputs, 256)] + [(256, 256)] * 2
    assert field.skip_after == 4
    heads = (field.head_xyz, field.head_rotation, field.head_scaling)
    assert [head.out_features for head in heads] == [3, 4, 3]
    timenet = field.encode.time_features.timenet
    assert (timenet is not None) == (preset == "dnerf")


def test_mlp_forward_is_the_reference_computation():
    torch.manual_seed(0)
    field = build_field(FieldConfig(name="mlp", preset="dnerf")).double()
    xyz, t = torch.randn(50, 3, dtype=torch.float64), torch.rand(50, 1, dtype=torch.float64)
    x_emb = embedder_reference(xyz, 10)
    t_emb = field.encode.time_features.timenet(embedder_reference(t, 6))
    h = torch.cat([x_emb, t_emb], dim=-1)
    for i, layer in enumerate(field.layers):
        h = torch.relu(layer(h))
        if i == 4:
            h = torch.cat([x_emb, t_emb, h], dim=-1)
    expected = field.head_xyz(h), field.head_rotation(h), field.head_scaling(h)
    for got, want in zip(field(xyz, t), expected):
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)


def test_shallow_mlp_has_no_skip():
    for depth in (1, 2):
        field = build_field(FieldConfig(name="mlp", preset="tiny", mlp_depth=depth))
        assert field.skip_after is None
        assert field(torch.zeros(4, 3), 0.5)[0].shape == (4, 3)


@pytest.mark.parametrize("name", field_names())
def test_output_shapes_and_time_broadcasting(name):
    torch.manual_seed(0)
    field = build_field(FieldConfig(name=name, preset="tiny")).eval()
    xyz = torch.randn(9, 3)
    reference = field(xyz, torch.full((9, 1), 0.25))
    assert [d.shape for d in reference] == [(9, 3), (9, 4), (9, 3)]
    for t in (0.25, torch.tensor(0.25), torch.tensor([[0.25]]), torch.full((9,), 0.25)):
        for got, want in zip(field(xyz, t), reference):
            torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match="shape"):
        field(xyz, torch.zeros(4, 1))
    with pytest.raises(ValueError, match="xyz"):
        field(torch.zeros(9, 2), 0.5)


def test_static_field_gives_zero_deltas():
    field = build_field(FieldConfig(name="static"))
    xyz = torch.randn(5, 3, dtype=torch.float64)
    d_xyz, d_rotation, d_scaling = field(xyz, 0.3)
    assert field.num_parameters() == 0
    assert d_rotation.shape == (5, 4) and d_xyz.dtype == torch.float64
    assert not any(d.any() for d in (d_xyz, d_rotation, d_scaling))


def test_deterministic_mlp_ignores_mode_and_progress():
    torch.manual_seed(0)
    field = build_field(FieldConfig(name="mlp", preset="tiny"))
    xyz = torch.randn(20, 3)
    train = field.train()(xyz, 0.7)
    field.set_progress(10_000)
    evaluated = field.eval()(xyz, 0.7)
    assert all(torch.equal(a, b) for a, b in zip(train, evaluated))
    _, variance = field.monte_carlo(xyz, 0.7, samples=3)
    assert not any(v.any() for v in variance)


def mlp_reference(field, xyz, t):
    """The D-3DGS MLP on the concatenated input, every layer a plain nn.Linear call."""
    inputs = torch.cat([embedder_reference(xyz, 10), field.encode.time_features(t).expand(len(xyz), -1)], dim=-1)
    h = inputs
    for i, layer in enumerate(field.layers):
        h = torch.relu(layer(h))
        if i == field.skip_after:
            h = torch.cat([inputs, h], dim=-1)
    return field.head_xyz(h), field.head_rotation(h), field.head_scaling(h)


@pytest.mark.parametrize("preset", ["tiny", "nerfds"])
@pytest.mark.parametrize("shared_time", [True, False])
def test_mlp_block_products_match_the_concatenation_with_gradients(preset, shared_time):
    """The field runs its input layers as products of column blocks (time folded into the
    bias); outputs and every parameter's gradient must equal the concatenated computation."""
    torch.manual_seed(1)
    field = build_field(FieldConfig(name="mlp", preset=preset))
    assert_matches_with_gradients(field, mlp_reference, shared_time, 0.3)
