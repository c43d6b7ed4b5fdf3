"""m4dgs.core.tensors.gather_rows: advanced indexing's values and gradient, the gradient the same on
every call on two CPU threads."""

from __future__ import annotations

import torch

from m4dgs.core.knn import knn
from m4dgs.core.tensors import gather_rows


def _arap_like(x, sub, idx, gather):
    # the ARAP term's pattern: each point against its neighbours (repeated indices), above torch's
    # parallel grain (4000 * 5 * 3 elements), where the order of the repeated additions matters
    return ((gather(x, sub)[:, None] - gather(x, idx)).norm(dim=-1) ** 2).mean()


def test_gather_rows_matches_indexing_and_repeats_its_gradient_on_two_threads():
    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(4000, 3, generator=g).cumsum(0) * 0.01  # a curve: close, repeated neighbours
    idx = knn(x0, 5)[0]
    sub = torch.randperm(4000, generator=g)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        x = x0.clone().requires_grad_()
        ref_v = _arap_like(x, sub, idx[sub], lambda a, i: a[i])
        (ref_g,) = torch.autograd.grad(ref_v, x)
        x = x0.clone().requires_grad_()
        v = _arap_like(x, sub, idx[sub], gather_rows)
        (gr,) = torch.autograd.grad(v, x)
        assert torch.equal(v, ref_v) and torch.equal(gr, ref_g)  # one thread: the same bits
        torch.set_num_threads(2)
        for _ in range(10):
            x = x0.clone().requires_grad_()
            (g2,) = torch.autograd.grad(_arap_like(x, sub, idx[sub], gather_rows), x)
            assert torch.equal(g2, gr)
    finally:
        torch.set_num_threads(before)
    assert gather_rows(x0, idx).shape == (4000, 5, 3)
    assert torch.equal(gather_rows(x0, idx), x0[idx])
