"""m4dgs.core.hdr: the mu-law curve against its formula, for numpy and torch inputs."""

from __future__ import annotations

import math

import numpy as np
import torch

from m4dgs.core import crf
from m4dgs.core.hdr import MU, mu_law, mu_law_inverse


def test_mu_law_matches_the_formula_and_clips():
    x = [-0.5, 0.0, 1e-4, 0.001, 0.25, 1.0, 3.0]
    want = [math.log(1 + 5000 * min(max(v, 0.0), 1.0)) / math.log(5001) for v in x]
    assert MU == 5000.0
    got = mu_law(np.array(x))
    assert isinstance(got, np.ndarray) and got.dtype == np.float64
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=0)
    assert mu_law(0.0) == 0.0 and abs(float(mu_law(1.0)) - 1.0) < 1e-15
    # another mu
    np.testing.assert_allclose(mu_law(np.array([0.5]), mu=100.0), [math.log(51) / math.log(101)])


def test_mu_law_keeps_the_input_type():
    t = torch.tensor([0.0, 0.1, 2.0], dtype=torch.float32)
    out = mu_law(t)
    assert isinstance(out, torch.Tensor) and out.dtype == torch.float32
    np.testing.assert_allclose(out.numpy(), mu_law(np.array([0.0, 0.1, 1.0])), rtol=1e-6)
    t64 = torch.linspace(0, 1, 11, dtype=torch.float64, requires_grad=True)
    mu_law(t64).sum().backward()  # differentiable
    assert torch.isfinite(t64.grad).all()
    assert mu_law(np.array([0.5], np.float32)).dtype == np.float32
    assert mu_law(np.array([0, 1], np.uint8)).dtype == np.float64


def test_mu_law_inverse_round_trip_and_the_mulog_crf():
    y = np.linspace(0, 1, 21)
    np.testing.assert_allclose(mu_law(mu_law_inverse(y)), y, atol=1e-12)
    t = torch.linspace(0, 1, 5, dtype=torch.float64)
    torch.testing.assert_close(mu_law_inverse(mu_law(t)), t)
    f = crf.get_crf("mulog")  # the mu-law curve used as a camera response
    x = np.array([0.0, 0.01, 0.3, 1.0, 2.0])
    np.testing.assert_array_equal(f(x), mu_law(x))
    np.testing.assert_allclose(f.inverse(f(x)), np.minimum(x, 1.0), atol=1e-12)
