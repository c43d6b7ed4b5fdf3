"""Benchmark the cpu rasterizer: forward + backward time and peak memory on the two target scenes.

Usage: python bench/raster_bench.py [--backend cpu] [--iters 15]

Each case runs in its own subprocess; peak memory is the growth of VmHWM (/proc/self/status) from
just before the first render to the end of the timed loop. Targets (2-core machine): 10k Gaussians
at 216x120 with 16 channels <= 40 ms, 50k at 432x240 <= 150 ms, peak growth < 200 MiB."""

from __future__ import annotations

import os

# must precede the torch import (see rasterizer-facts.md)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

CASES = [  # (name, N Gaussians, width, height, channels, screen sigma in px, target ms or None)
    ("10k@216x120", 10_000, 216, 120, 16, 1.0, 40.0),
    ("50k@432x240", 50_000, 432, 240, 16, 1.0, 150.0),
    # stress: the same scenes with 1.5x larger Gaussians (about 2.3x the depth complexity)
    ("10k@216x120-dense", 10_000, 216, 120, 16, 1.5, None),
    ("50k@432x240-dense", 50_000, 432, 240, 16, 1.5, None),
]


def vm_hwm_mib() -> float:
    """Peak resident set size of this process so far (MiB), from /proc/self/status."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def make_scene(
    n: int, width: int, height: int, channels: int, sigma_px: float = 1.0, seed: int = 0
):
    """Random Gaussians filling a pinhole frustum: depth 2-6, random rotations, per-axis
    screen-space standard deviation ``sigma_px`` x lognormal(0, 0.4), opacity U(0.1, 0.9), features
    U(0, 1)."""
    import torch

    g = torch.Generator().manual_seed(seed)
    fx = 0.8 * width
    K = torch.tensor([[fx, 0.0, width / 2], [0.0, fx, height / 2], [0.0, 0.0, 1.0]])
    z = torch.rand(n, generator=g) * 4 + 2
    x = (torch.rand(n, generator=g) - 0.5) * width / fx * z * 1.1
    y = (torch.rand(n, generator=g) - 0.5) * height / fx * z * 1.1
    means = torch.stack([x, y, z], dim=-1)
    quats = torch.randn(n, 4, generator=g)
    scales = torch.exp(torch.randn(n, 3, generator=g) * 0.4) * (z[:, None] / fx) * sigma_px
    opacities = torch.rand(n, generator=g) * 0.8 + 0.1
    features = torch.rand(n, channels, generator=g)
    return means, quats, scales, opacities, features, torch.eye(4), K


def depth_complexity(scene, width: int, height: int) -> float:
    """Mean number of Gaussians per pixel with alpha >= 1/255 (summed footprint areas / pixels)."""
    import math

    import torch

    from m4dgs.raster import project_gaussians

    p = project_gaussians(*scene[:4], scene[5], scene[6], width, height)
    op = scene[3][p.visible]
    det = torch.linalg.det(p.cov2d[p.visible])
    area = 2 * math.pi * torch.log(op * 255).clamp_min(0) * det.sqrt()
    return float(area.sum()) / (width * height)


def run_case(
    name: str,
    n: int,
    width: int,
    height: int,
    channels: int,
    sigma_px: float,
    backend: str,
    iters: int,
) -> dict:
    import torch

    from m4dgs.raster import render

    scene = make_scene(n, width, height, channels, sigma_px)
    params = [t.clone().requires_grad_(True) for t in scene[:5]]
    viewmat, K = scene[5], scene[6]
    weights = torch.rand(height, width, channels, generator=torch.Generator().manual_seed(1))
    if backend == "cpu":
        from m4dgs.raster import load_extension

        load_extension()  # build/load outside the measurement
    hwm0 = vm_hwm_mib()

    def step() -> int:
        for p in params:
            p.grad = None
        feat, depth, alpha, meta = render(*params, viewmat, K, width, height, backend=backend)
        loss = (feat * weights).sum() + depth.mean() + alpha.mean()
        loss.backward()
        return meta.n_isects

    for _ in range(3):
        n_isects = step()
    times, cpu_times = [], []
    for _ in range(iters):
        t0, c0 = time.perf_counter(), time.process_time()
        step()
        times.append((time.perf_counter() - t0) * 1e3)
        cpu_times.append((time.process_time() - c0) * 1e3)
    return {
        "case": name,
        "backend": backend,
        "ms_median": statistics.median(times),
        "ms_min": min(times),
        "cpu_ms_median": statistics.median(cpu_times),
        "peak_rss_increase_mib": vm_hwm_mib() - hwm0,
        "threads": torch.get_num_threads(),
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", ""),
        "n_isects": n_isects,
        "depth_complexity": depth_complexity(scene, width, height),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="cpu", choices=["cpu", "torch"])
    parser.add_argument("--iters", type=int, default=15)
    # internal: run one case in-process
    parser.add_argument("--case", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case is not None:
        spec = next(c for c in CASES if c[0] == args.case)
        print(json.dumps(run_case(*spec[:6], args.backend, args.iters)))
        return
    print(
        f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')} (PASSIVE: "
        f"{os.environ.get('OMP_WAIT_POLICY', '').upper() == 'PASSIVE'}); load average before: "
        f"{' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs "
        "(wall times are only meaningful on an otherwise idle machine; CPU ms = all threads)"
    )
    for name, _n, _width, _height, channels, _sigma_px, target in CASES:
        proc = subprocess.run(
            [
                sys.executable,
                __file__,
                "--backend",
                args.backend,
                "--iters",
                str(args.iters),
                "--case",
                name,
            ],
            capture_output=True,
            text=True,
            check=False,
        )
        if proc.returncode != 0:
            print(f"{name}: FAILED\n{proc.stderr[-2000:]}")
            continue
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        if target is None:
            verdict = "stress case, no target"
        elif r["ms_median"] <= target and r["peak_rss_increase_mib"] < 200:
            verdict = "OK"
        else:
            verdict = "OVER TARGET"
        target_s = "-" if target is None else f"{target:.0f}"
        print(
            f"{name} C={channels} backend={r['backend']}: fwd+bwd median {r['ms_median']:.1f} ms "
            f"(min {r['ms_min']:.1f}, target {target_s}) | CPU {r['cpu_ms_median']:.1f} ms | "
            f"peak RSS +{r['peak_rss_increase_mib']:.1f} MiB | "
            f"threads {r['threads']} | OMP_WAIT_POLICY={r['omp_wait_policy']} | isects "
            f"{r['n_isects']} | "
            f"depth complexity {r['depth_complexity']:.1f} | {verdict}"
        )


if __name__ == "__main__":
    main()
