"""Beyond the paper: annealed and input-dependent noise, hidden-state OU diffusion (exact and
through torchsde), Monte-Carlo inference; and finite gradients for every field and variant."""

import math

import pytest
import torch

from liquidgs.fields import (
    CfCCell,
    FieldConfig,
    build_field,
    field_names,
    ou_std,
    ou_transition,
    schedule_factor,
    solve_ltc_sde,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_ou_std_is_the_closed_form_and_stable_at_the_limits():
    kappa = torch.tensor([0.0, 1e-9, 1e-3, 0.5, 3.0, 50.0, 0.5, 0.0], dtype=torch.float64, requires_grad=True)
    tau = torch.tensor([0.7, 0.7, 0.7, 0.7, 0.7, 0.7, 0.0, 0.0], dtype=torch.float64)
    std = ou_std(kappa, tau)
    k, s = kappa.detach()[2:6], tau[2:6]
    expected = torch.sqrt((1 - torch.exp(-2 * k * s)) / (2 * k))
    torch.testing.assert_close(std[2:6], expected, rtol=1e-12, atol=0)
    torch.testing.assert_close(std[:2], torch.full((2,), math.sqrt(0.7), dtype=torch.float64))  # kappa -> 0
    assert std[6] == 0 and std[7] == 0
    std.sum().backward()
    assert torch.isfinite(kappa.grad).all()
    for dtype in (torch.float32, torch.float64):  # no jump where the series takes over
        x = torch.tensor([0.99e-4, 1.01e-4], dtype=dtype)
        values = ou_std(x / 2, torch.ones_like(x))
        assert abs(values[0] - values[1]) < 1e-6


def ou_moments(h0, m, kappa, tau, lam):
    decay = torch.exp(-kappa * tau)
    return m + (h0 - m) * decay, lam**2 * (1 - decay**2) / (2 * kappa)


def test_ou_transition_matches_its_closed_form_moments():
    torch.manual_seed(8)
    kappa = torch.tensor([0.05, 0.5, 2.0, 8.0], dtype=torch.float64)
    h0, m = torch.tensor([0.9, -0.4, 0.1, 0.6]).double(), torch.tensor([-0.5, 0.3, 0.8, -0.2]).double()
    tau, lam, n = torch.full((20_000, 1), 0.7, dtype=torch.float64), 0.3, 20_000
    samples = ou_transition(h0.expand(n, 4), m.expand(n, 4), kappa.expand(n, 4), tau, lam)
    mean, var = ou_moments(h0, m, kappa, 0.7, lam)
    assert ((samples.mean(0) - mean).abs() < 4 * var.sqrt() / math.sqrt(n)).all()
    torch.testing.assert_close(samples.var(0), var, rtol=0.05, atol=0)
    # No elapsed time (or negative): the state stays at h0, with no noise.
    for still in (0.0, -1.0):
        out = ou_transition(h0[None], m[None], kappa[None], torch.full((1, 1), still).double(), lam)
        torch.testing.assert_close(out[0], h0, rtol=0, atol=0)


@pytest.mark.parametrize("leak", [0.0, 1.5])
def test_torchsde_solver_matches_the_ou_closed_form(leak):
    torch.manual_seed(9)
    n, lam, dt = 4000, 0.4, 0.01
    f = torch.tensor([0.05, 0.5, 2.0, 4.0], dtype=torch.float64).expand(n, 4)
    a = torch.tensor([-0.5, 0.3, 0.8, -0.9], dtype=torch.float64).expand(n, 4)
    h0 = torch.tensor([0.9, -0.4, 0.1, 0.6], dtype=torch.float64).expand(n, 4).contiguous()
    tau = torch.full((n, 1), 0.8, dtype=torch.float64)
    samples = solve_ltc_sde(h0, f, a, leak, tau, lam, dt)
    kappa = f[0] + leak
    mean, var = ou_moments(h0[0], f[0] * a[0] / kappa, kappa, 0.8, lam)
    # Euler bias is O(kappa * tau * dt) relative; statistical error about 2.2% on the variance.
    assert ((samples.mean(0) - mean).abs() < 4 * var.sqrt() / math.sqrt(n) + 0.01).all()
    torch.testing.assert_close(samples.var(0), var, rtol=0.1, atol=0)
    exact = ou_transition(h0, f[0] * a[0] / kappa, kappa.expand(n, 4), tau, lam)
    torch.testing.assert_close(samples.var(0), exact.var(0), rtol=0.12, atol=0)


def test_solver_is_repeatable_under_a_torch_seed():
    args = (torch.zeros(5, 3), torch.ones(5, 3), torch.ones(5, 3), 0.0, torch.rand(5, 1), 0.5, 0.1)
    torch.manual_seed(10)
    first = solve_ltc_sde(*args)
    torch.manual_seed(10)
    assert torch.equal(first, solve_ltc_sde(*args))


def test_solver_field_converges_to_the_exact_ou_field_without_noise():
    torch.manual_seed(11)
    exact = build_field(FieldConfig(name="sde", preset="tiny", noise="ou")).eval()
    solver = build_field(FieldConfig(name="sde", preset="tiny", noise="solver", solver_dt=0.002)).eval()
    solver.load_state_dict(exact.state_dict())
    xyz, t = torch.randn(200, 3), torch.rand(200, 1)
    for got, want in zip(solver(xyz, t), exact(xyz, t)):
        torch.testing.assert_close(got, want, rtol=0, atol=5e-3)


@pytest.mark.parametrize("noise", ["ou", "solver"])
def test_hidden_state_variants_switch_off_in_eval(noise):
    torch.manual_seed(12)
    field = build_field(FieldConfig(name="sde", preset="tiny", noise=noise, lambda_=0.2, solver_dt=0.25))
    xyz, t = torch.randn(64, 3), torch.rand(64, 1)
    clean = field.eval()(xyz, t)
    torch.manual_seed(0)  # the solver's Brownian path differs, but with no noise it is unused
    assert all(torch.equal(a, b) for a, b in zip(field(xyz, t), clean))
    assert not torch.equal(field.train()(xyz, t)[0], clean[0])


def test_schedules_decay_to_zero():
    assert [schedule_factor("constant", s, 100) for s in (0, 50, 500)] == [1.0, 1.0, 1.0]
    assert [schedule_factor("linear", s, 100) for s in (-5, 0, 25, 100, 500)] == [1.0, 1.0, 0.75, 0.0, 0.0]
    cosine = [schedule_factor("cosine", s, 100) for s in (0, 50, 100, 500)]
    assert cosine[0] == 1.0 and abs(cosine[1] - 0.5) < 1e-12 and cosine[2] == cosine[3] == 0.0


@pytest.mark.parametrize("schedule", ["linear", "cosine"])
def test_annealed_field_is_deterministic_after_the_decay(schedule):
    torch.manual_seed(13)
    field = build_field(
        FieldConfig(name="sde", preset="tiny", lambda_=0.1, lambda_schedule=schedule, lambda_decay_steps=1000)
    )
    xyz, t = torch.randn(50, 3), 0.4
    clean = field.eval()(xyz, t)
    field.train()
    field.set_progress(500)
    assert field.current_lambda() == pytest.approx(0.05)
    assert not torch.equal(field(xyz, t)[0], clean[0])
    field.set_progress(1000)
    assert field.current_lambda() == 0.0
    assert all(torch.equal(a, b) for a, b in zip(field(xyz, t), clean))


def test_adaptive_lambda_is_bounded_and_cannot_collapse():
    torch.manual_seed(14)
    cell = CfCCell(20, 8, 16, 2, "gelu", adaptive_floor=0.25)
    z = torch.randn(500, 16) * 10
    assert torch.allclose(cell.noise_scale(z, 0.2), torch.full((500, 1), 0.2 * 0.625))  # zero init
    with torch.no_grad():
        for push in (-1e4, 1e4):  # drive the head as far as it goes either way
            cell.noise_head.bias.fill_(push)
            scale = cell.noise_scale(z, 0.2)
            assert (scale >= 0.2 * 0.25).all() and (scale <= 0.2).all()
            assert (scale - (0.05 if push < 0 else 0.2)).abs().max() < 1e-6
    assert cell.noise_scale(z, 0.0) is None
    # The scale varies with the input, so the gate noise differs per Gaussian.
    with torch.no_grad():
        cell.noise_head.bias.zero_()
        cell.noise_head.weight.normal_()
    scale = cell.noise_scale(z, 0.2)
    assert scale.std() > 0.01


def test_monte_carlo_gives_uncertainty_only_for_noisy_fields():
    torch.manual_seed(15)
    sde = build_field(FieldConfig(name="sde", preset="tiny", lambda_=0.3)).eval()
    cfc = build_field(FieldConfig(name="cfc", preset="tiny")).eval()
    cfc.load_state_dict(sde.state_dict())
    xyz = torch.randn(400, 3, requires_grad=True)
    clean = cfc(xyz, 0.6)
    mean, var = sde.monte_carlo(xyz, 0.6, samples=64)
    assert not sde.training and not sde.noise_active  # restored afterwards
    assert [v.shape for v in var] == [(400, 3), (400, 4), (400, 3)]
    assert all((v > 0).all() and not v.requires_grad for v in var)
    # Small noise: the MC mean stays close to the clean pass, within a few standard errors.
    for m, v, c in zip(mean, var, clean):
        assert ((m - c).abs() < 6 * (v / 64).sqrt() + 0.05 * v.sqrt() + 1e-5).float().mean() > 0.99
    # A direct check of the estimator: the same K passes, stacked.
    torch.manual_seed(16)
    _, var_k = sde.monte_carlo(xyz, 0.6, samples=5)
    torch.manual_seed(16)
    with torch.no_grad():
        sde.train()
        stacked = torch.stack([sde(xyz, 0.6)[0] for _ in range(5)])
        sde.eval()
    torch.testing.assert_close(var_k[0], stacked.var(0), rtol=1e-4, atol=1e-9)
    _, cfc_var = cfc.monte_carlo(xyz, 0.6, samples=4)
    assert not any(v.any() for v in cfc_var)
    with pytest.raises(ValueError, match="samples"):
        sde.monte_carlo(xyz, 0.6, samples=1)


VARIANTS = [dict(name=name) for name in field_names()] + [
    dict(name="sde", adaptive_lambda=True),
    dict(name="sde", lambda_schedule="cosine", lambda_decay_steps=100),
    dict(name="sde", noise="ou", adaptive_lambda=True),
    dict(name="sde", noise="ou", ltc_leak=1.0),
    dict(name="sde", noise="solver", solver_dt=0.1, ltc_leak=0.5),
    dict(name="sde", backbone_dropout=0.1, activation="lecun_tanh"),
]


@pytest.mark.parametrize("settings", VARIANTS, ids=lambda s: "-".join(str(v) for v in s.values()))
def test_gradients_are_finite_and_never_reach_xyz(settings):
    torch.manual_seed(17)
    field = build_field(FieldConfig(preset="tiny", **settings)).train()
    field.set_progress(10)
    xyz = torch.randn(128, 3, requires_grad=True)
    t = torch.cat([torch.tensor([[0.0], [-0.5], [1.0], [10.0]]), torch.rand(124, 1)])
    deltas = field(xyz, t)
    assert all(torch.isfinite(d).all() for d in deltas)
    if field.num_parameters() == 0:
        assert not any(d.requires_grad for d in deltas)
        return
    sum(d.square().sum() for d in deltas).backward()
    assert xyz.grad is None
    for name, parameter in field.named_parameters():
        assert parameter.grad is not None, name
        assert torch.isfinite(parameter.grad).all(), name
