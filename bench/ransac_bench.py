"""Robust fundamental-matrix fits and backward warps: ours against OpenCV and kornia (if installed).

Usage: python bench/ransac_bench.py [--points 25920] [--outliers 0.3] [--repeats 7]

The correspondences are synthetic, one flow map's worth at the small preset (216 x 120 = 25,920
pixels): two pinhole cameras, 3-D points in front of both, 0.3 px Gaussian noise on the matches and
a fraction of "dynamic" matches moved by a random displacement. For each fit it prints the median
wall time over --repeats runs and the accuracy: the median Sampson distance (px) of the true static
matches to the fitted F and the fraction of true static / dynamic matches classified as inliers.
The warp case times a bilinear backward warp of a 3-channel 216 x 120 image by a dense flow
(m4dgs.core.warp against kornia.geometry.transform.remap).

kornia is not a dependency of this package (docs/architecture.md says why); install it into a
scratch folder to compare: `pip install --no-deps --target /tmp/kornia kornia kornia_rs`, then run
with PYTHONPATH=/tmp/kornia."""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m4dgs.priors.epipolar import ransac_fundamental, sampson_error  # noqa: E402


def make_matches(n: int, outliers: float, seed: int = 0):
    """(x1 [n, 2], x2 [n, 2], dynamic [n] bool) in pixels of a 216 x 120 image."""
    rng = np.random.default_rng(seed)
    w, h, f = 216, 120, 200.0
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    px = np.stack([rng.uniform(0, w, n), rng.uniform(0, h, n)], -1)
    depth = rng.uniform(2.0, 8.0, n)
    X = np.concatenate([(px - K[:2, 2]) / f, np.ones((n, 1))], -1) * depth[:, None]
    a = 0.05
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    t = np.array([0.3, 0.05, 0.1])
    X2 = X @ R.T + t
    x2 = X2[:, :2] / X2[:, 2:] * f + K[:2, 2]
    x1 = px + rng.normal(0, 0.3, (n, 2))
    x2 = x2 + rng.normal(0, 0.3, (n, 2))
    dyn = rng.random(n) < outliers
    x2[dyn] += rng.normal(0, 6.0, (int(dyn.sum()), 2))
    return x1, x2, dyn


def timed(fn, repeats: int):
    out, times = None, []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, 1e3 * statistics.median(times)


def report(name, F, x1, x2, dyn, inl, ms):
    F = torch.as_tensor(np.asarray(F, dtype=np.float64))
    e = sampson_error(F, torch.as_tensor(x1), torch.as_tensor(x2)).numpy()
    static_err = float(np.median(np.sqrt(e[~dyn])))
    inl = np.asarray(inl, bool).reshape(-1)
    print(
        f"{name:28s} {ms:9.1f} ms   static Sampson median {static_err:6.3f} px   "
        f"inliers: static {inl[~dyn].mean():5.3f}  dynamic {inl[dyn].mean():5.3f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=216 * 120)
    ap.add_argument("--outliers", type=float, default=0.3)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
    x1, x2, dyn = make_matches(args.points, args.outliers)
    print(
        f"{args.points} matches, {dyn.mean():.0%} dynamic, torch threads "
        f"{torch.get_num_threads()}; median of {args.repeats}"
    )

    (F, inl), ms = timed(lambda: ransac_fundamental(x1, x2, method="lmeds"), args.repeats)
    report("ours lmeds (256 hyp, 2048)", F, x1, x2, dyn, inl.numpy(), ms)
    (F, inl), ms = timed(
        lambda: ransac_fundamental(x1, x2, method="msac", threshold=1.0), args.repeats
    )
    report("ours msac (256 hyp, 2048)", F, x1, x2, dyn, inl.numpy(), ms)

    import cv2

    cv2.setRNGSeed(0)
    (F, inl), ms = timed(lambda: cv2.findFundamentalMat(x1, x2, cv2.FM_LMEDS), args.repeats)
    report("opencv FM_LMEDS", F, x1, x2, dyn, inl, ms)
    (F, inl), ms = timed(
        lambda: cv2.findFundamentalMat(x1, x2, cv2.FM_RANSAC, 1.0, 0.999), args.repeats
    )
    report("opencv FM_RANSAC (1 px)", F, x1, x2, dyn, inl, ms)

    try:
        import kornia
        from kornia.geometry.ransac import RANSAC
    except ImportError:
        print("kornia not importable: its rows are skipped (see the usage above)")
        kornia = None
    if kornia is not None:
        torch.manual_seed(0)
        t1 = torch.as_tensor(x1, dtype=torch.float32)
        t2 = torch.as_tensor(x2, dtype=torch.float32)
        rs = RANSAC("fundamental", inl_th=1.0, batch_size=256, max_iter=10)
        (F, inl), ms = timed(lambda: rs(t1, t2), args.repeats)
        report(f"kornia {kornia.__version__} RANSAC (1 px)", F.double(), x1, x2, dyn, inl, ms)

    # backward warp of an image by a dense flow
    from m4dgs.core.warp import backward_warp

    g = torch.Generator().manual_seed(0)
    img = torch.rand(120, 216, 3, generator=g)
    flow = torch.randn(120, 216, 2, generator=g) * 3
    _, ms = timed(lambda: backward_warp(img, flow), args.repeats * 5)
    print(f"{'ours backward_warp':28s} {ms:9.2f} ms")
    if kornia is not None:
        from kornia.geometry.transform import remap

        ys, xs = torch.meshgrid(torch.arange(120.0), torch.arange(216.0), indexing="ij")
        mx, my = (xs + flow[..., 0])[None], (ys + flow[..., 1])[None]
        chw = img.permute(2, 0, 1)[None]
        _, ms = timed(
            lambda: remap(chw, mx, my, mode="bilinear", padding_mode="border", align_corners=True),
            args.repeats * 5,
        )
        print(f"{'kornia remap':28s} {ms:9.2f} ms")


if __name__ == "__main__":
    main()
