"""Differentiable SSIM in the 3DGS convention (used by the D-SSIM loss and by the SSIM metrics).

3DGS style (paper appendix, "LDR RGB Loss"; metric conventions in docs): an 11x11 Gaussian window
with sigma 1.5, per-channel conv2d with zero padding 5, C1 = 0.01^2, C2 = 0.03^2 for data range 1,
and the mean of the SSIM map over the WHOLE image, borders included. scikit-image's Gaussian SSIM
equals the mean of this map over the interior (5-pixel border cropped); `crop` reproduces that."""

from __future__ import annotations

import torch
import torch.nn.functional as F

WINDOW_SIZE = 11
SIGMA = 1.5


def gaussian_window(
    size: int = WINDOW_SIZE, sigma: float = SIGMA, *, dtype=torch.float32, device=None
) -> torch.Tensor:
    """Normalised separable Gaussian window as a [size, size] tensor."""
    x = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2.0
    g = torch.exp(-(x**2) / (2.0 * sigma**2))
    g = g / g.sum()
    return g[:, None] * g[None, :]


def ssim_map(img1: torch.Tensor, img2: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Per-pixel, per-channel SSIM map.

    Args:
        img1, img2: [..., H, W, C] images (channels last), same shape.
        data_range: dynamic range of the images (1 for [0, 1] images).
    Returns:
        [..., H, W, C] SSIM map computed with zero padding (3DGS convention).
    """
    if img1.shape != img2.shape:
        raise ValueError(f"ssim: shape mismatch {tuple(img1.shape)} vs {tuple(img2.shape)}")
    lead = img1.shape[:-3]
    h, w, c = img1.shape[-3:]
    a = img1.reshape(-1, h, w, c).permute(0, 3, 1, 2)
    b = img2.reshape(-1, h, w, c).permute(0, 3, 1, 2)
    g1 = gaussian_window(dtype=a.dtype, device=a.device)
    g1 = g1.sum(dim=1)  # the 1-D factor of the separable window
    wv = g1.reshape(1, 1, WINDOW_SIZE, 1).expand(c, 1, WINDOW_SIZE, 1).contiguous()
    wh = g1.reshape(1, 1, 1, WINDOW_SIZE).expand(c, 1, 1, WINDOW_SIZE).contiguous()
    pad = WINDOW_SIZE // 2

    def filt(x):
        # separable 11x11 Gaussian with zero padding: identical to the 2-D convolution, about 5x
        # cheaper
        return F.conv2d(F.conv2d(x, wh, padding=(0, pad), groups=c), wv, padding=(pad, 0), groups=c)

    mu1, mu2 = filt(a), filt(b)
    s11 = filt(a * a) - mu1 * mu1
    s22 = filt(b * b) - mu2 * mu2
    s12 = filt(a * b) - mu1 * mu2
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    m = ((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1 * mu1 + mu2 * mu2 + c1) * (s11 + s22 + c2))
    return m.permute(0, 2, 3, 1).reshape(*lead, h, w, c)


def ssim(
    img1: torch.Tensor, img2: torch.Tensor, data_range: float = 1.0, crop: int = 0
) -> torch.Tensor:
    """Mean SSIM (3DGS convention) of [..., H, W, C] images; returns a tensor of shape [...].

    `crop` > 0 averages the map over the interior only (crop=5 reproduces scikit-image's Gaussian
    SSIM)."""
    m = ssim_map(img1, img2, data_range)
    if crop > 0:
        m = m[..., crop:-crop, crop:-crop, :]
    return m.mean(dim=(-3, -2, -1))


def dssim(img1: torch.Tensor, img2: torch.Tensor) -> torch.Tensor:
    """Structural dissimilarity (1 - SSIM) / 2 as used in the 3DGS photometric loss; scalar for [H,
    W, C] input."""
    return (1.0 - ssim(img1, img2)) / 2.0
