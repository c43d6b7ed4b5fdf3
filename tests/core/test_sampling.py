"""m4dgs.core.warp's two sampling contracts: `sample_map` (one [H, W, C] map at [N, 2] points,
grid_sample) and `sample_per_frame` ([T, H, W] maps along [N, T, 2] tracks, explicit gather)."""

from __future__ import annotations

import torch

from m4dgs.core.warp import sample_map, sample_per_frame


def _bilinear(img, x, y):
    """Reference bilinear on an [H, W] image at index coordinates (border clamp)."""
    H, W = img.shape
    x = min(max(x, 0.0), W - 1.0)
    y = min(max(y, 0.0), H - 1.0)
    x0, y0 = int(x), int(y)
    x1, y1 = min(x0 + 1, W - 1), min(y0 + 1, H - 1)
    fx, fy = x - x0, y - y0
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bot = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return float(top * (1 - fy) + bot * fy)


def test_both_samplers_agree_with_a_reference_and_each_other():
    g = torch.Generator().manual_seed(0)
    maps = torch.rand(3, 5, 7, generator=g, dtype=torch.float64)  # [T, H, W]
    uv = torch.rand(4, 3, 2, generator=g, dtype=torch.float64) * torch.tensor([8.0, 6.0]) - 0.5
    per = sample_per_frame(maps, uv)
    assert per.shape == (4, 3)
    for t in range(3):
        one = sample_map(maps[t][..., None], uv[:, t])  # [N, 1]
        assert one.shape == (4, 1)
        for n in range(4):
            want = _bilinear(maps[t], float(uv[n, t, 0]) - 0.5, float(uv[n, t, 1]) - 0.5)
            assert abs(float(per[n, t]) - want) < 1e-12
            assert abs(float(one[n, 0]) - want) < 1e-12


def test_pixel_centres_are_exact_and_nearest_mode():
    maps = torch.arange(12, dtype=torch.float64).reshape(1, 3, 4)
    uv = torch.tensor([[[0.5, 0.5]], [[3.5, 2.5]], [[1.9, 1.2]]], dtype=torch.float64)
    torch.testing.assert_close(
        sample_per_frame(maps, uv)[:2, 0], torch.tensor([0.0, 11.0]).double()
    )
    assert float(sample_per_frame(maps, uv, mode="nearest")[2, 0]) == 5.0  # pixel (1, 1)
    img = maps[0][..., None].repeat(1, 1, 2)  # [H, W, 2]
    torch.testing.assert_close(
        sample_map(img, uv[:2, 0]), torch.tensor([[0.0, 0.0], [11.0, 11.0]]).double()
    )
