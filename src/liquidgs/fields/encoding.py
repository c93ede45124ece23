"""Input encodings shared by the MLP and liquid fields (the D-3DGS embedder and time network)."""

from __future__ import annotations

import torch
from torch import nn


class PositionalEncoding(nn.Module):
    """gamma(x) = [x, sin(2^0 x), cos(2^0 x), ..., sin(2^(L-1) x), cos(2^(L-1) x)].

    The D-3DGS embedder: the raw input is kept, frequencies are powers of two without a
    factor pi, and each frequency contributes a sin block then a cos block over all input
    dimensions. Output width in_dims * (1 + 2 L).
    """

    def __init__(self, in_dims: int, freqs: int):
        super().__init__()
        self.in_dims = in_dims
        self.out_dims = in_dims * (1 + 2 * freqs)
        self.register_buffer("bands", 2.0 ** torch.arange(freqs, dtype=torch.float32), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scaled = x[:, None, :] * self.bands.to(x.dtype)[None, :, None]  # [N, L, d]
        periodic = torch.stack((torch.sin(scaled), torch.cos(scaled)), dim=2)  # [N, L, 2, d]
        return torch.cat((x, periodic.flatten(1)), dim=1)


class TimeFeatures(nn.Module):
    """gamma(t), optionally through the D-3DGS time network Linear(.., W)-ReLU-Linear(W, out)."""

    def __init__(self, freqs: int, timenet_width: int, timenet_out: int):
        super().__init__()
        self.encoding = PositionalEncoding(1, freqs)
        if timenet_width > 0:
            self.timenet = nn.Sequential(
                nn.Linear(self.encoding.out_dims, timenet_width),
                nn.ReLU(),
                nn.Linear(timenet_width, timenet_out),
            )
            self.out_dims = timenet_out
        else:
            self.timenet = None
            self.out_dims = self.encoding.out_dims

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        features = self.encoding(t)
        return features if self.timenet is None else self.timenet(features)


class EncodedInputs:
    """A field's input u = [gamma(x); time features], kept as its two blocks.

    A Linear layer on u (and on further columns after it) runs as products of its column
    blocks, never building the [N, I] concatenation: the time block is one row when every
    Gaussian shares the time, so its product folds into the bias, and gamma(x) needs no
    gradient (the field stops it), so the products on it skip their input gradient. Same
    result as layer(cat(...)) up to float rounding (tests hold it to the concatenation).
    """

    def __init__(self, xyz: torch.Tensor, time: torch.Tensor):
        self.xyz = xyz
        """gamma(x), [N, Dx]."""
        self.time = time
        """Time features, [1, Dt] (shared time) or [N, Dt]."""

    @classmethod
    def plain(cls, u: torch.Tensor) -> EncodedInputs:
        """A dense [N, I] input as one block (no time block)."""
        return cls(u, u.new_zeros(1, 0))

    @property
    def rows(self) -> int:
        return self.xyz.shape[0]

    @property
    def width(self) -> int:
        return self.xyz.shape[1] + self.time.shape[1]

    def dense(self) -> torch.Tensor:
        """The concatenation [gamma(x); time features], [N, I]."""
        return torch.cat((self.xyz, self.time.expand(self.rows, -1)), dim=1)

    def linear(self, layer: nn.Linear, rest: torch.Tensor | None = None) -> torch.Tensor:
        """layer([u; rest]) for rest [N, R]; rest None stands for zeros (or no further columns)."""
        weight, dx, di = layer.weight, self.xyz.shape[1], self.width
        out = torch.addmm(layer.bias, self.time, weight[:, dx:di].t()) if di > dx else layer.bias[None]
        out = torch.addmm(out, self.xyz, weight[:, :dx].t())
        return out if rest is None else torch.addmm(out, rest, weight[:, di:].t())


class FieldInputs(nn.Module):
    """A field's input per Gaussian: gamma(x) and the time features, time encoded once when shared."""

    def __init__(self, xyz_freqs: int, time_freqs: int, timenet_width: int, timenet_out: int):
        super().__init__()
        self.xyz_encoding = PositionalEncoding(3, xyz_freqs)
        self.time_features = TimeFeatures(time_freqs, timenet_width, timenet_out)
        self.out_dims = self.xyz_encoding.out_dims + self.time_features.out_dims

    def forward(self, xyz: torch.Tensor, t: torch.Tensor) -> EncodedInputs:
        return EncodedInputs(self.xyz_encoding(xyz), self.time_features(t))


def time_column(t: torch.Tensor | float, n: int, like: torch.Tensor) -> torch.Tensor:
    """t as a [1, 1] (shared by all Gaussians) or [n, 1] tensor with like's dtype and device.

    Accepts a float, a 0-d tensor, or a tensor of shape [1], [n], [1, 1] or [n, 1].
    """
    t = torch.as_tensor(t, dtype=like.dtype, device=like.device)
    if t.dim() < 2:
        t = t.reshape(-1, 1)
    if t.dim() != 2 or t.shape[1] != 1 or t.shape[0] not in (1, n):
        raise ValueError(f"time must be a float or have shape [1, 1] or [{n}, 1], got {tuple(t.shape)}")
    return t
