"""The liquid CfC field against ncps.torch.CfCCell, and the paper's stochastic gate."""

import pytest
import torch

from field_reference import assert_matches_with_gradients
from liquidgs.fields import ACTIVATIONS, CfCCell, FieldConfig, build_field
from shared_data import require_module

pytestmark = pytest.mark.usefixtures("one_torch_thread")


TAUS = ["0", "0.5", "1", "10", "-1", "random"]


def tau_column(kind: str, batch: int, generator: torch.Generator) -> torch.Tensor:
    if kind == "random":
        return torch.randn(batch, 1, dtype=torch.float64, generator=generator) * 3
    return torch.full((batch, 1), float(kind), dtype=torch.float64)


def ncps_pair(inputs, hidden, units, layers, activation="gelu"):
    """An ncps cell (eval, fp64) and ours with its weights copied in."""
    ncps_cell = require_module("ncps.torch").CfCCell
    reference = ncps_cell(inputs, hidden, "default", activation, units, layers, 0.0).double().eval()
    ours = CfCCell(inputs, hidden, units, layers, activation).double().eval()
    ours.load_state_dict(reference.state_dict())  # same layout: backbone.0 sees cat([u, h])
    return reference, ours


@pytest.mark.parametrize("batch", [257, 128])
@pytest.mark.parametrize("tau_kind", TAUS)
def test_cell_matches_ncps(batch, tau_kind):
    generator = torch.Generator().manual_seed(batch)
    torch.manual_seed(1)
    reference, ours = ncps_pair(95, 128, 256, 2)
    u = torch.randn(batch, 95, dtype=torch.float64, generator=generator)
    h = torch.randn(batch, 128, dtype=torch.float64, generator=generator)
    tau = tau_column(tau_kind, batch, generator)
    expected, _ = reference(u, h, tau)
    torch.testing.assert_close(ours(u, h, tau), expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("activation", ACTIVATIONS)
@pytest.mark.parametrize("layers", [1, 3])
def test_cell_matches_ncps_for_every_activation(activation, layers):
    torch.manual_seed(2)
    reference, ours = ncps_pair(21, 16, 32, layers, activation)
    u, h, tau = torch.randn(40, 21).double(), torch.randn(40, 16).double(), torch.rand(40, 1).double()
    torch.testing.assert_close(ours(u, h, tau), reference(u, h, tau)[0], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(("preset", "inputs", "units"), [("dnerf", 95, 256), ("nerfds", 84, 64)])
@pytest.mark.parametrize("batch", [257, 128])
def test_stack_of_six_matches_ncps(preset, inputs, units, batch):
    torch.manual_seed(3)
    field = build_field(FieldConfig(name="cfc", preset=preset)).double().eval()
    ncps_cell = require_module("ncps.torch").CfCCell
    references = [ncps_cell(inputs, 128, "default", "gelu", units, 2, 0.0) for _ in range(6)]
    for reference, cell in zip(references, field.cells):
        reference.double().eval()
        cell.load_state_dict(reference.state_dict())
    generator = torch.Generator().manual_seed(batch)
    xyz = torch.randn(batch, 3, dtype=torch.float64, generator=generator)
    for tau_kind in TAUS:
        t = tau_column(tau_kind, batch, generator)
        encoded, tau = field.inputs(xyz, t)
        u = encoded.dense()
        assert u.shape == (batch, inputs) and tau.shape == (batch, 1)
        h = torch.zeros(batch, 128, dtype=torch.float64)
        for index, reference in enumerate(references):
            if index == 3:  # the residual enters at cell D / 2
                h = h + field.skip(u)
            h, _ = reference(u, h, tau)
        torch.testing.assert_close(field.hidden_state(encoded, tau), h, rtol=1e-11, atol=1e-11)
        expected = field.readout(h)
        got = torch.cat(field(xyz, t), dim=1)
        torch.testing.assert_close(got, expected, rtol=1e-11, atol=1e-11)


def test_noise_switches_off_exactly():
    torch.manual_seed(4)
    cfc = build_field(FieldConfig(name="cfc", preset="tiny"))
    sde = build_field(FieldConfig(name="sde", preset="tiny", lambda_=0.3))
    sde.load_state_dict(cfc.state_dict())
    xyz, t = torch.randn(300, 3), torch.rand(300, 1)
    deterministic = cfc.eval()(xyz, t)
    same = [cfc.train()(xyz, t), sde.eval()(xyz, t)]  # train at lambda 0; eval at lambda > 0
    for outputs in same:
        assert all(torch.equal(a, b) for a, b in zip(outputs, deterministic))
    noisy = sde.train()(xyz, t)
    noisy_again = sde(xyz, t)
    assert not torch.equal(noisy[0], deterministic[0])
    assert not torch.equal(noisy[0], noisy_again[0])  # fresh noise every pass


@pytest.mark.parametrize("batch", [257, 128])
def test_fixed_noise_equals_ncps_with_noise_added_to_time_b(batch):
    torch.manual_seed(5)
    reference, ours = ncps_pair(84, 128, 64, 2)
    u, h = torch.randn(batch, 84).double(), torch.randn(batch, 128).double()
    tau, eps, lam = torch.rand(batch, 1).double(), torch.randn(batch, 128).double(), 0.37
    reference.time_b.register_forward_hook(lambda module, args, out: out + lam * eps)
    torch.testing.assert_close(ours(u, h, tau, lam, eps), reference(u, h, tau)[0], rtol=1e-12, atol=1e-12)


def test_gate_preactivation_variance_grows_by_lambda_squared():
    torch.manual_seed(6)
    cell = CfCCell(84, 128, 64, 2, "gelu").double()
    u, h, tau = torch.randn(3000, 84).double(), torch.randn(3000, 128).double(), torch.rand(3000, 1).double()
    with torch.no_grad():
        z = cell.features(u, h)
        _, _, time_a, time_b = cell.heads(z)
        clean = time_a * tau + time_b
        for lam in (0.05, 0.5):
            noisy = time_a * tau + (time_b + cell.gate_noise(z, time_b, lam))
            growth = noisy.var() - clean.var()
            # 384k samples: the estimate's standard error is about 0.01 * lambda.
            assert abs(growth - lam**2) < 0.05 * lam, (lam, growth)


def test_gate_noise_is_independent_per_cell_pass_gaussian_and_unit(monkeypatch):
    torch.manual_seed(7)
    lam = 0.2
    field = build_field(FieldConfig(name="sde", preset="tiny", lambda_=lam)).train()
    draws = []
    for cell in field.cells:
        original = cell.gate_noise

        def recording(z, like, lam=0.0, eps=None, original=original):
            noise = original(z, like, lam, eps)
            draws.append(noise.detach())
            return noise

        monkeypatch.setattr(cell, "gate_noise", recording)
    xyz, t = torch.randn(2000, 3), torch.rand(1, 1)
    field(xyz, t)
    field(xyz, t)
    noise = torch.stack(draws)  # [2 passes x 3 cells, 2000 Gaussians, 32 units]
    assert noise.shape == (6, 2000, 32)
    torch.testing.assert_close(noise.std(dim=(1, 2)), torch.full((6,), lam), rtol=0.03, atol=0)
    flat = noise.flatten(1)
    correlation = torch.corrcoef(flat) - torch.eye(6)
    assert correlation.abs().max() < 0.02  # across cells and passes
    per_unit = torch.corrcoef(noise[0].T.double())  # 32 units, 2000 samples each
    # 32 Gaussians, 192 samples each (6 draws x 32 units).
    per_gaussian = torch.corrcoef(noise[:, :32].permute(1, 0, 2).flatten(1).double())
    assert (per_unit - torch.eye(32).double()).abs().max() < 0.12
    assert (per_gaussian - torch.eye(32).double()).abs().max() < 0.35
    assert noise[0, 0].unique().numel() == 32 and noise[0, :, 0].unique().numel() == 2000


def cfc_reference(field, xyz, t):
    """The CfC stack on concatenated inputs, every layer a plain nn.Linear / nn.Sequential call."""
    u = torch.cat([field.encode.xyz_encoding(xyz), field.encode.time_features(t).expand(len(xyz), -1)], dim=1)
    tau = t.expand(len(xyz), 1)
    h = torch.zeros(len(xyz), field.config.hidden, dtype=xyz.dtype)
    for index, cell in enumerate(field.cells):
        if index == field.skip_before:
            h = h + field.skip(u)
        z = cell.backbone(torch.cat((u, h), dim=1))
        sigma = torch.sigmoid(cell.time_a(z) * tau + cell.time_b(z))
        h = torch.tanh(cell.ff1(z)) * (1 - sigma) + sigma * torch.tanh(cell.ff2(z))
    return field.readout(h).split((3, 4, 3), dim=1)


@pytest.mark.parametrize("preset", ["tiny", "nerfds"])
@pytest.mark.parametrize("shared_time", [True, False])
def test_stack_block_products_match_the_concatenation_with_gradients(preset, shared_time):
    """The stack runs input layers as column-block products (time folded into the bias, the
    first cell's zero state skipped); outputs and every parameter's gradient must equal the
    concatenated computation."""
    torch.manual_seed(8)
    field = build_field(FieldConfig(name="cfc", preset=preset))
    assert_matches_with_gradients(field, cfc_reference, shared_time, 0.6)
