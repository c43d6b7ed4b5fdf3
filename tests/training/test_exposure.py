"""Tests of the exposure perturbation (m4dgs.training.exposure)."""

import numpy as np
import pytest
import torch
from scipy import stats

from m4dgs.training.exposure import exposure_offsets, perturb_exposures


def test_bounds_and_determinism():
    base = np.log2(np.array([0.125, 2.0, 32.0] * 20))
    a = perturb_exposures(base, 1.0, seed=7)
    b = perturb_exposures(base, 1.0, seed=7)
    c = perturb_exposures(base, 1.0, seed=8)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    assert np.all(np.abs(a - base) <= 1.0)
    # offsets are exactly numpy's uniform draws for that seed
    np.testing.assert_allclose(
        a - base, np.random.default_rng(7).uniform(-1.0, 1.0, size=60), atol=1e-12
    )
    np.testing.assert_array_equal(perturb_exposures(base, 0.0, seed=3), base)


def test_types_preserved():
    t = torch.zeros(5, dtype=torch.float32)
    out = perturb_exposures(t, 0.5, seed=1)
    assert isinstance(out, torch.Tensor) and out.dtype == torch.float32
    np.testing.assert_allclose(out.numpy(), exposure_offsets(5, 0.5, 1), rtol=1e-6)
    arr = perturb_exposures(np.zeros(4, dtype=np.float32), 0.5, seed=1)
    assert arr.dtype == np.float32
    with pytest.raises(ValueError):
        exposure_offsets(3, -1.0, 0)


def test_distribution_uniform():
    u = exposure_offsets(20000, 2.0, seed=123)
    assert stats.kstest(u, stats.uniform(loc=-2.0, scale=4.0).cdf).pvalue > 0.01
    assert abs(u.mean()) < 0.05
    assert abs(u.var() - 16.0 / 12.0) < 0.05
