"""Holding a field's fast computation to a plain reference: outputs and parameter gradients."""

from __future__ import annotations

import torch


def assert_matches_with_gradients(field, reference, shared_time: bool, time: float) -> None:
    """field(xyz, t) and reference(field, xyz, t) in float64 on 70 random Gaussians, t shared
    ([1, 1]) or one per Gaussian: same outputs and the same gradient on every parameter."""
    field = field.double()
    xyz = torch.randn(70, 3, dtype=torch.float64)
    t = torch.full((1, 1), time, dtype=torch.float64) if shared_time else torch.rand(70, 1, dtype=torch.float64)
    weights = [torch.randn(70, k, dtype=torch.float64) for k in (3, 4, 3)]
    results = []
    for compute in (field, lambda x, s: reference(field, x, s)):
        field.zero_grad()
        outputs = compute(xyz, t)
        sum((o * w).sum() for o, w in zip(outputs, weights)).backward()
        results.append(([o.detach() for o in outputs], {n: p.grad.clone() for n, p in field.named_parameters()}))
    (got, got_grads), (want, want_grads) = results
    for a, b in zip(got, want):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
    assert got_grads.keys() == want_grads.keys()
    for name in want_grads:
        torch.testing.assert_close(got_grads[name], want_grads[name], rtol=1e-10, atol=1e-12, msg=name)
