"""m4dgs.core.knn against brute-force torch.cdist ordering (both backends)."""

from __future__ import annotations

import pytest
import torch

from m4dgs.core.knn import knn


def _brute(pts, k):
    d = torch.cdist(pts, pts)
    d.fill_diagonal_(float("inf"))
    return d.topk(k, dim=1, largest=False, sorted=True)  # (dist, idx)


@pytest.mark.parametrize("backend", ["torch", "scipy"])
def test_knn_matches_brute_force_order(backend):
    g = torch.Generator().manual_seed(3)
    pts = torch.rand(257, 3, generator=g, dtype=torch.float64)  # continuous: no distance ties
    want_d, want_i = _brute(pts, 6)
    idx, dist = knn(pts, 6, chunk_elems=257 * 10, backend=backend)  # torch: several chunks
    assert idx.dtype == torch.long and idx.shape == (257, 6) and dist.dtype == torch.float64
    torch.testing.assert_close(idx, want_i, rtol=0, atol=0)  # indices first, same order
    torch.testing.assert_close(dist, want_d, rtol=0, atol=1e-12)  # Euclidean, ascending
    assert (dist[:, 1:] >= dist[:, :-1]).all()


@pytest.mark.parametrize("backend", ["torch", "scipy"])
def test_knn_excludes_self_with_duplicates(backend):
    pts = torch.rand(50, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    pts[10] = pts[11]
    idx, dist = knn(pts, 3, backend=backend)
    assert (idx != torch.arange(50)[:, None]).all()
    assert idx[10, 0] == 11 and idx[11, 0] == 10 and dist[10, 0] == 0


def test_knn_float32_and_errors():
    pts = torch.rand(20, 2)
    idx, dist = knn(pts, 2)  # auto -> scipy on the CPU; dtype follows the input
    assert dist.dtype == torch.float32 and not dist.requires_grad
    with pytest.raises(ValueError, match="0 < k < N"):
        knn(pts, 20)
    with pytest.raises(ValueError, match="unknown backend"):
        knn(pts, 2, backend="faiss")
