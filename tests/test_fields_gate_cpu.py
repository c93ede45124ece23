"""The compiled CfC gate (fields/cpu_gate.cpp) held against its torch reference, values and gradients."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from liquidgs.fields import cpu_gate
from liquidgs.fields.cpu_gate import cfc_gate, cfc_gate_torch

pytestmark = pytest.mark.skipif(
    cpu_gate.unavailable_reason() is not None, reason=f"compiled CfC gate unavailable: {cpu_gate.unavailable_reason()}"
)


def gate_case(n: int, hidden: int, dtype: torch.dtype, seed: int, shared_time: bool, noise: bool):
    generator = torch.Generator().manual_seed(seed)
    # Wide pre-activations: tanh and sigmoid saturate in places, and cross tanhf's 0.625 switch.
    heads = (4 * torch.randn(n, 4 * hidden, generator=generator)).to(dtype)
    tau = torch.rand(1 if shared_time else n, 1, generator=generator).to(dtype)
    offset = (0.3 * torch.randn(n, hidden, generator=generator)).to(dtype) if noise else None
    return heads, tau, offset


def run(gate, heads, tau, offset):
    leaves = [t if t is None else t.clone().requires_grad_(True) for t in (heads, tau, offset)]
    out = gate(leaves[0], leaves[1].expand(heads.shape[0], 1), leaves[2])
    weight = torch.linspace(-1, 2, out.numel(), dtype=out.dtype).reshape(out.shape)
    (out * weight).sum().backward()
    return [out] + [None if leaf is None else leaf.grad for leaf in leaves]


@pytest.mark.parametrize(
    ("n", "hidden", "shared_time", "noise"), [(300, 32, True, False), (257, 128, False, True), (5, 3, False, True)]
)
def test_float64_equals_the_torch_gate_with_gradients(n, hidden, shared_time, noise):
    heads, tau, offset = gate_case(n, hidden, torch.float64, seed=hidden, shared_time=shared_time, noise=noise)
    ours, reference = run(cfc_gate, heads, tau, offset), run(cfc_gate_torch, heads, tau, offset)
    for name, got, want in zip(("out", "heads", "tau", "offset"), ours, reference):
        if want is None:
            assert got is None, name
            continue
        assert want.abs().max() > 0, name
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-13, msg=name)


def test_float32_within_a_stated_tolerance():
    """float32 runs Cephes' expf / tanhf eight lanes at a time: within a few ulp of torch's."""
    heads, tau, offset = gate_case(4000, 32, torch.float32, seed=3, shared_time=False, noise=True)
    ours, reference = run(cfc_gate, heads, tau, offset), run(cfc_gate_torch, heads, tau, offset)
    for name, got, want in zip(("out", "heads", "tau", "offset"), ours, reference):
        scale = want.abs().max().item()
        torch.testing.assert_close(got, want, rtol=1e-5, atol=2e-6 * scale, msg=name)


def test_float32_widths_the_kernel_does_not_take_run_in_torch():
    heads, tau, _ = gate_case(50, 12, torch.float32, seed=4, shared_time=True, noise=False)
    torch.testing.assert_close(cfc_gate(heads, tau), cfc_gate_torch(heads, tau), rtol=0, atol=0)


def test_without_a_compiler_the_gate_runs_in_torch_with_one_line(tmp_path):
    code = (
        "import torch; from liquidgs.fields.cpu_gate import cfc_gate, cfc_gate_torch\n"
        "h, t = torch.randn(40, 128), torch.rand(1, 1)\n"
        "for _ in range(2): out = cfc_gate(h, t)\n"
        "print(torch.equal(out, cfc_gate_torch(h, t)))\n"
    )
    env = os.environ | {"CXX": "false", "LIQUIDGS_CACHE_DIR": str(tmp_path)}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=False)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "True"
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "compiled CfC gate unavailable (false failed on cpu_gate.cpp" in lines[0], lines
