"""Spherical harmonics against hand-computed values and gsplat's PyTorch reference."""

from __future__ import annotations

import math

import pytest
import torch
from gsplat.cuda._torch_impl import _eval_sh_bases_fast

from liquidgs.sh import eval_sh, eval_sh_bases


def one_hot_coeffs(index: int, n_bases: int = 16) -> torch.Tensor:
    coeffs = torch.zeros(1, n_bases, 3, dtype=torch.float64)
    coeffs[0, index] = torch.tensor([1.0, 2.0, -1.0])
    return coeffs


# (basis index, direction, value of that basis), worked out by hand from the real SH formulas.
HAND_VALUES = [
    (0, (0.0, 0.0, 1.0), 0.5 / math.sqrt(math.pi)),
    (1, (0.0, 1.0, 0.0), -math.sqrt(3 / (4 * math.pi))),
    (2, (0.0, 0.0, 1.0), math.sqrt(3 / (4 * math.pi))),
    (3, (1.0, 0.0, 0.0), -math.sqrt(3 / (4 * math.pi))),
    (4, (1.0, 1.0, 0.0), 0.5 * math.sqrt(15 / math.pi) * 0.5),  # x*y = 1/2
    (6, (0.0, 0.0, 1.0), 0.25 * math.sqrt(5 / math.pi) * 2.0),  # 2z^2 - x^2 - y^2 = 2
    (8, (1.0, 0.0, 0.0), 0.25 * math.sqrt(15 / math.pi)),  # x^2 - y^2 = 1
    (9, (0.0, 1.0, 0.0), -0.25 * math.sqrt(35 / (2 * math.pi)) * -1.0),  # y(3x^2 - y^2) = -1
    (12, (0.0, 0.0, 1.0), 0.25 * math.sqrt(7 / math.pi) * 2.0),  # z(2z^2 - 3x^2 - 3y^2) = 2
    (15, (1.0, 0.0, 0.0), -0.25 * math.sqrt(35 / (2 * math.pi))),  # x(x^2 - 3y^2) = 1
    (10, (1.0, 1.0, 1.0), 0.5 * math.sqrt(105 / math.pi) * 3**-1.5),  # xyz on the unit diagonal
]


@pytest.mark.parametrize(("index", "direction", "value"), HAND_VALUES)
def test_single_basis_against_hand_values(index, direction, value):
    degree = math.isqrt(index)
    # Unnormalised directions are normalised inside, as in gsplat.
    dirs = 3.0 * torch.tensor([direction], dtype=torch.float64)
    colours = eval_sh(degree, one_hot_coeffs(index), dirs)
    expected = value * torch.tensor([[1.0, 2.0, -1.0]], dtype=torch.float64)
    torch.testing.assert_close(colours, expected, rtol=1e-12, atol=1e-12)


def test_degree_zero_is_constant():
    coeffs = torch.tensor([[[0.5, -1.0, 2.0]]], dtype=torch.float64)
    for direction in ((1.0, 0.0, 0.0), (0.3, -0.2, 0.9)):
        colours = eval_sh(0, coeffs, torch.tensor([direction], dtype=torch.float64))
        torch.testing.assert_close(colours, 0.28209479177387814 * coeffs[:, 0])


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_bases_match_gsplat_reference(degree):
    dirs = torch.nn.functional.normalize(torch.randn(500, 3, dtype=torch.float64), dim=-1)
    n_bases = (degree + 1) ** 2
    torch.testing.assert_close(eval_sh_bases(degree, dirs), _eval_sh_bases_fast(n_bases, dirs), rtol=0, atol=1e-12)


def test_higher_coefficients_are_ignored():
    coeffs = torch.randn(4, 16, 3, dtype=torch.float64)
    dirs = torch.randn(4, 3, dtype=torch.float64)
    truncated = coeffs.clone()
    truncated[:, 4:] = 0.0
    torch.testing.assert_close(eval_sh(1, coeffs, dirs), eval_sh(1, truncated, dirs))


def test_invalid_degree_and_too_few_coefficients():
    with pytest.raises(ValueError, match="sh_degree"):
        eval_sh_bases(4, torch.zeros(1, 3))
    with pytest.raises(ValueError, match="at least 9 SH coefficients"):
        eval_sh(2, torch.zeros(1, 4, 3), torch.ones(1, 3))
