"""Tests of the learned tone mapper (m4dgs.model.tonemap) against independent references."""

import math

import numpy as np
import pytest
import torch

from m4dgs.model.tonemap import LOG_EPS, ToneMapper, monotonicity_penalty, pretrain_tonemapper


def _hdrnerf_crf(x):
    return (x / (x + 1.0)) ** (1.0 / 2.2)


def _reference_channels(tm: ToneMapper):
    """Three separate nn.Sequential MLPs holding the tone mapper's weights (the authors' per-channel
    layout)."""
    mods = []
    for c in range(tm.n_channels):
        seq = torch.nn.Sequential(
            torch.nn.Linear(1, tm.hidden),
            torch.nn.Softplus(),
            torch.nn.Linear(tm.hidden, 1),
            torch.nn.Sigmoid(),
        )
        with torch.no_grad():
            seq[0].weight.copy_(tm.w1[c][:, None])
            seq[0].bias.copy_(tm.b1[c])
            seq[2].weight.copy_(tm.w2[c][None, :])
            seq[2].bias.copy_(tm.b2[c : c + 1])
        mods.append(seq)
    return mods


def _tm(seed=0):
    return ToneMapper(generator=torch.Generator().manual_seed(seed))


def test_shapes_and_exposure_broadcast():
    tm = _tm()
    hdr = torch.rand(2, 4, 5, 3) * 4
    assert tm(hdr, 0.0).shape == (2, 4, 5, 3)
    # per-image exposure [2, 1, 1] and per-pixel exposure [2, 4, 5]
    dt = torch.tensor([-1.0, 3.0])
    out_img = tm(hdr, dt[:, None, None])
    out_pix = tm(hdr, dt[:, None, None].expand(2, 4, 5))
    torch.testing.assert_close(out_img, out_pix)
    torch.testing.assert_close(out_img[1], tm(hdr[1], 3.0))
    assert tm.curve(torch.zeros(7, 1)).shape == (7, 3)  # a shared axis broadcasts to all channels
    assert ((out_img > 0) & (out_img < 1)).all()


def test_matches_three_separate_mlps():
    tm = _tm(1)
    refs = _reference_channels(tm)
    hdr = torch.rand(6, 3) * 10
    log2_dt = 1.5
    out = tm(hdr, log2_dt)
    for c in range(3):
        z = torch.log2(hdr[:, c : c + 1] + LOG_EPS) + log2_dt
        torch.testing.assert_close(out[:, c : c + 1], refs[c](z), rtol=1e-5, atol=1e-6)


def test_channels_independent():
    tm = _tm(2)
    z = torch.randn(3)
    jac = torch.autograd.functional.jacobian(lambda v: tm.curve(v), z)
    off = jac - torch.diag(torch.diagonal(jac))
    assert off.abs().max() == 0
    assert (torch.diagonal(jac).abs() > 0).all()


def test_unit_exposure_value_is_phi_at_zero():
    tm = _tm(3)
    refs = _reference_channels(tm)
    expect = torch.cat([r(torch.zeros(1, 1))[0] for r in refs])
    torch.testing.assert_close(tm.unit_exposure_value(), expect, rtol=1e-6, atol=1e-7)
    # H = 1 at dt = 1 is log2 exposure 0 (up to the 1e-6 eps)
    torch.testing.assert_close(tm(torch.ones(1, 3), 0.0)[0], expect, atol=1e-5, rtol=0)


def test_monotonicity_penalty_analytic():
    tm = ToneMapper(hidden=4)
    with torch.no_grad():
        tm.w1.fill_(1.0)
        tm.b1.zero_()
        tm.b2.zero_()
        tm.w2.fill_(0.25)  # phi = sigmoid(softplus(z)), increasing
    assert float(monotonicity_penalty(tm).detach()) == 0.0
    with torch.no_grad():
        tm.w2.fill_(-0.25)  # phi = sigmoid(-softplus(z)), decreasing

    # finite-difference slopes telescope: mean relu(-slope) = (phi(-10) - phi(10)) / 20 per channel,
    # summed over 3
    def phi(z):
        return 1 / (1 + math.exp(math.log1p(math.exp(z))))

    expect = 3 * (phi(-10) - phi(10)) / 20.0
    assert float(monotonicity_penalty(tm, -10, 10, 1024).detach()) == pytest.approx(
        expect, rel=1e-4
    )


def test_pretraining_reaches_hdrnerf_crf():
    tm = _tm(0)
    res = pretrain_tonemapper(tm, _hdrnerf_crf, iters=1000)
    ln_x = np.linspace(-5, 5, 1001)
    with torch.no_grad():
        y = tm.curve(torch.tensor(ln_x / math.log(2), dtype=torch.float32)[:, None]).numpy()
        y_wide = tm.curve(torch.linspace(-10, 10, 4001)[:, None]).numpy()
    target = _hdrnerf_crf(np.exp(ln_x))[:, None]
    assert np.abs(y - target).max() < 0.02
    assert (np.diff(y_wide, axis=0) >= -1e-6).all()  # monotone over the whole pre-training range
    phi0 = tm.unit_exposure_value().detach().numpy()
    np.testing.assert_allclose(phi0, 0.5 ** (1 / 2.2), atol=2e-3)
    assert res["mono"] < 1e-6


def test_lut_path_matches_exact_curve_and_gradients():
    """The piecewise-linear table used on large images agrees with the exact MLP in values and
    gradients."""
    import torch

    from m4dgs.model.tonemap import ToneMapper

    torch.manual_seed(0)
    tm = ToneMapper(lut_size=2048).double()
    hdr = (torch.rand(60, 80, 3, dtype=torch.float64) * 6 - 3).exp2().requires_grad_(True)
    out_lut = tm(hdr, 1.5)  # 14400 values > 4 * 2048 * 3: the table path
    exact = tm.curve(torch.log2(hdr + tm.eps) + 1.5)
    assert (out_lut - exact).abs().max() < 1e-5
    g_lut = torch.autograd.grad(out_lut.sum(), [hdr, tm.w1, tm.w2])
    g_ex = torch.autograd.grad(exact.sum(), [hdr, tm.w1, tm.w2])
    for a, b in zip(g_lut, g_ex):
        assert torch.allclose(a, b, rtol=2e-3, atol=1e-4 * b.abs().max().item())
    # the default table (512 nodes): interpolation error still far below an 8-bit level (1/255)
    tm.lut_size = ToneMapper().lut_size
    assert tm.lut_size == 512
    assert (tm(hdr, 1.5) - exact).abs().max() < 1e-4
