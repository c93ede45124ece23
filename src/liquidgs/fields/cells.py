"""Liquid cells: the CfC cell with its stochastic time gate, and two hidden-state SDE cells.

All three share the ncps CfC layout (backbone on cat([u, h]), heads named as in
ncps.torch.CfCCell so weights load across), map (u, h, tau) -> h', and take a noise level
`lam` (0 = deterministic) plus an optional fixed `eps` for testing.

Paper names <-> ncps names: W_g = ff1, W_h = ff2, W_a = time_a, W_b = time_b.
"""

from __future__ import annotations

import torch
import torchsde
from torch import nn
from torch.nn import functional as F

from liquidgs.fields.base import stacked_linear, stacked_product
from liquidgs.fields.cpu_gate import cfc_gate
from liquidgs.fields.encoding import EncodedInputs


class LeCunTanh(nn.Module):
    """1.7159 * tanh(0.666 x), the ncps default backbone activation."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return 1.7159 * torch.tanh(0.666 * x)


ACTIVATION_MODULES: dict[str, type[nn.Module]] = {
    "silu": nn.SiLU,
    "relu": nn.ReLU,
    "tanh": nn.Tanh,
    "gelu": nn.GELU,  # exact erf form, as in ncps
    "lecun_tanh": LeCunTanh,
}


class LiquidCell(nn.Module):
    """Backbone z = phi([u; h]) and the heads shared by every liquid cell.

    Backbone: Linear(I + H, U), act, then (layers - 1) x [Linear(U, U), act, Dropout if p > 0].
    Heads Linear(U, H): ff1, ff2, time_a and, for the gate cell, time_b. Init as ncps:
    xavier_uniform on every 2-D weight, default biases. With adaptive_floor set, a head
    Linear(U, 1) makes the noise scale input-dependent (see `noise_scale`).
    """

    uses_time_b = True

    def __init__(
        self,
        input_size: int,
        hidden_size: int,
        units: int,
        layers: int,
        activation: str,
        dropout: float = 0.0,
        adaptive_floor: float | None = None,
    ):
        super().__init__()
        self.input_size, self.hidden_size = input_size, hidden_size
        act = ACTIVATION_MODULES[activation]
        backbone: list[nn.Module] = [nn.Linear(input_size + hidden_size, units), act()]
        for _ in range(layers - 1):
            backbone += [nn.Linear(units, units), act()]
            if dropout > 0:
                backbone.append(nn.Dropout(dropout))
        self.backbone = nn.Sequential(*backbone)
        self.ff1 = nn.Linear(units, hidden_size)
        self.ff2 = nn.Linear(units, hidden_size)
        self.time_a = nn.Linear(units, hidden_size)
        self.time_b = nn.Linear(units, hidden_size) if self.uses_time_b else None
        for weight in self.parameters():
            if weight.dim() == 2:
                nn.init.xavier_uniform_(weight)
        self.adaptive_floor = adaptive_floor
        if adaptive_floor is not None:
            # Zero init: every Gaussian starts at the same scale, halfway between floor and lambda.
            self.noise_head = nn.Linear(units, 1)
            nn.init.zeros_(self.noise_head.weight)
            nn.init.zeros_(self.noise_head.bias)
        else:
            self.noise_head = None

    def features(self, u: torch.Tensor | EncodedInputs, h: torch.Tensor | None) -> torch.Tensor:
        """z = phi([u; h]) for u dense [N, I] or as its blocks, and h [N, H] or None (the zero
        state, whose columns are then skipped)."""
        if isinstance(u, torch.Tensor):
            u = EncodedInputs.plain(u)
        return self.backbone[1:](u.linear(self.backbone[0], h))

    def head_layers(self) -> list[nn.Linear]:
        return [self.ff1, self.ff2, self.time_a] + ([self.time_b] if self.time_b is not None else [])

    def heads(self, z: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """(ff1 z, ff2 z, time_a z[, time_b z]) from one matrix product (see stacked_linear)."""
        return stacked_linear(z, self.head_layers())

    def noise_scale(self, z: torch.Tensor, lam: float) -> torch.Tensor | float | None:
        """The noise standard deviation: None when lam == 0, else lam or, adaptive,
        lam_i = lam * (floor + (1 - floor) * sigmoid(w . z + b)), one value per Gaussian.

        The adaptive scale lies in [floor * lam, lam]: bounded above, and it cannot collapse to
        0 however the loss pushes w, because the floor is a constant, not a parameter.
        """
        if lam == 0:
            return None
        if self.noise_head is None:
            return lam
        floor = self.adaptive_floor
        return lam * (floor + (1.0 - floor) * torch.sigmoid(self.noise_head(z)))


class CfCCell(LiquidCell):
    """ncps.torch.CfCCell (mode "default") with the paper's stochastic time gate:

        g = tanh(ff1 z), h_cand = tanh(ff2 z)
        sigma = sigmoid(time_a(z) * tau + (time_b(z) + lam * eps))
        h' = g * (1 - sigma) + h_cand * sigma

    The noise is added to time_b's output, which is bit-for-bit where a hook on ncps's time_b
    would put it; lam == 0 skips it, so the cell is then exactly the deterministic CfC.
    tau must be [B, 1] (ncps's sequence wrapper squeezes it to [B], which mis-broadcasts when
    B == H). The gate runs as fields.cpu_gate.cfc_gate: one compiled pass on a CPU.
    """

    def gate_noise(self, z, like: torch.Tensor, lam: float = 0.0, eps: torch.Tensor | None = None):
        """lam * eps (or the adaptive scale times eps) for time_b's output `like`; None when lam is 0."""
        scale = self.noise_scale(z, lam)
        if scale is None:
            return None
        return scale * (torch.randn_like(like) if eps is None else eps)

    def forward(self, u, h, tau, lam: float = 0.0, eps: torch.Tensor | None = None) -> torch.Tensor:
        z = self.features(u, h)
        heads = stacked_product(z, self.head_layers())  # [ff1 | ff2 | time_a | time_b]
        noise = self.gate_noise(z, heads[:, 3 * self.hidden_size :], lam, eps)
        return cfc_gate(heads, tau, noise)


def ltc_to_ou(f: torch.Tensor, a: torch.Tensor, leak: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Rate kappa and mean m of the LTC drift -(leak + f) h + f A = kappa (m - h)."""
    kappa = f + leak
    return kappa, (a if leak == 0 else f * a / kappa)


def ou_std(kappa: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """sqrt((1 - exp(-2 kappa tau)) / (2 kappa)) for kappa >= 0, tau >= 0, stable at kappa -> 0.

    Written as sqrt(tau) * sqrt(phi(2 kappa tau)) with phi(x) = (1 - e^-x) / x, which lies in
    (0, 1] (so its square root has finite gradients); a Taylor series replaces it near x = 0.
    """
    x = 2.0 * kappa * tau
    small = x < 1e-4
    x_safe = torch.where(small, torch.ones_like(x), x)
    phi = torch.where(small, 1.0 - x / 2.0 + x * x / 6.0, -torch.expm1(-x_safe) / x_safe)
    return torch.sqrt(tau) * torch.sqrt(phi)


def ou_transition(h0, m, kappa, tau, scale=None, eps=None) -> torch.Tensor:
    """Exact transition of dh = kappa (m - h) ds + scale dW over s in [0, tau], coefficients frozen:

        h(tau) = m + (h0 - m) e^{-kappa tau} + scale * sqrt((1 - e^{-2 kappa tau}) / (2 kappa)) * eps

    tau <= 0 is clamped to 0 (no elapsed time: h = h0, no noise). scale None = no noise.
    """
    tau = tau.clamp(min=0.0)
    mean = m + (h0 - m) * torch.exp(-kappa * tau)
    if scale is None:
        return mean
    eps = torch.randn_like(mean) if eps is None else eps
    return mean + scale * ou_std(kappa, tau) * eps


class _FrozenLTCSDE(nn.Module):
    """dh = tau [-(leak + f) h + f A] dr + scale sqrt(tau) dW_r, r in [0, 1]: the LTC SDE over
    s = tau r, rescaled so every Gaussian integrates over the same grid whatever its tau."""

    noise_type = "diagonal"
    sde_type = "ito"

    def __init__(self, f, a, leak, tau, diffusion):
        super().__init__()
        self.f_, self.a, self.leak, self.tau, self.diffusion = f, a, leak, tau, diffusion

    def f(self, r, h):
        return self.tau * (-(self.leak + self.f_) * h + self.f_ * self.a)

    def g(self, r, h):
        return self.diffusion.expand_as(h)


def solve_ltc_sde(h0, f, a, leak: float, tau, scale=None, dt: float = 0.05) -> torch.Tensor:
    """Euler-Maruyama (torchsde.sdeint, Ito, diagonal noise, fixed step dt in r = s / tau) of
    dh = [-(leak + f) h + f A] ds + scale dW from h(0) = h0 over s in [0, tau].

    The Brownian motion's seed is drawn from torch's generator, so torch.manual_seed makes
    runs repeatable. tau <= 0 is clamped to 0. scale None = zero diffusion (an ODE solve).
    """
    tau = tau.clamp(min=0.0).expand(h0.shape[0], 1)
    diffusion = h0.new_zeros(1, 1) if scale is None else scale * torch.sqrt(tau)
    sde = _FrozenLTCSDE(f, a, leak, tau, diffusion)
    seed = int(torch.randint(0, 2**31 - 1, ()).item())
    bm = torchsde.BrownianInterval(t0=0.0, t1=1.0, size=h0.shape, dtype=h0.dtype, device=h0.device, entropy=seed)
    ts = torch.tensor([0.0, 1.0], dtype=h0.dtype, device=h0.device)
    return torchsde.sdeint(sde, h0, ts, bm=bm, method="euler", dt=dt)[-1]


class OUCell(LiquidCell):
    """Hidden-state diffusion with the exact Ornstein-Uhlenbeck transition (no solver).

    z = phi([u; h]); h0 = tanh(ff1 z) (CfC's zero-elapsed-time branch g), f = softplus(time_a z),
    A = tanh(ff2 z); the state relaxes from h0 for the elapsed time tau under the LTC drift
    -(leak + f) h + f A with diffusion lam, i.e. an OU process with kappa = leak + f and
    m = f A / kappa (= tanh(ff2 z) at leak 0). At lam = 0 this is CfC with the sigmoid gate
    replaced by the exact exponential gate 1 - e^{-kappa tau}. time_b is not needed.
    """

    uses_time_b = False

    def __init__(self, *args, leak: float = 0.0, **kwargs):
        super().__init__(*args, **kwargs)
        self.leak = leak

    def coefficients(self, u, h):
        z = self.features(u, h)
        ff1, ff2, t_a = self.heads(z)
        return z, torch.tanh(ff1), F.softplus(t_a), torch.tanh(ff2)

    def forward(self, u, h, tau, lam: float = 0.0, eps: torch.Tensor | None = None) -> torch.Tensor:
        z, h0, f, a = self.coefficients(u, h)
        kappa, m = ltc_to_ou(f, a, self.leak)
        return ou_transition(h0, m, kappa, tau, self.noise_scale(z, lam), eps)


class SolverCell(OUCell):
    """The OU cell's SDE integrated by torchsde instead of in closed form: a cost and accuracy
    reference (Euler-Maruyama, step dt). Same parameters and drift as OUCell."""

    def __init__(self, *args, dt: float = 0.05, **kwargs):
        super().__init__(*args, **kwargs)
        self.dt = dt

    def forward(self, u, h, tau, lam: float = 0.0, eps: torch.Tensor | None = None) -> torch.Tensor:
        if eps is not None:
            raise ValueError("the solver cell draws its own Brownian path; a fixed eps is not supported")
        z, h0, f, a = self.coefficients(u, h)
        return solve_ltc_sde(h0, f, a, self.leak, tau, self.noise_scale(z, lam), self.dt)
