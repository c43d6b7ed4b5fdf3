"""The denoiser on frame 0 of each scene: one OIDN pass at its automatic exposure (generator
versions 4-5) against the exposure ladder (version 6), on the same two raw renders and guides.

    python bench/denoise_bench.py [--scenes a,b] [--preset small] [--clips ROOT/syn-exp-3]
                                  [--spp-factors 1,2,4 --ladder-only --no-bias]

Prints one line per scene and method: rel. std and two-seed noise
(benchgen.groundtruth.render_noise, over surface pixels / interior pixels), the median relative
error against a raw 1,024-spp render in four brightness bands and its mean
(benchgen.groundtruth.render_bias), and the denoising seconds per frame. --clips: a folder of
finished clips whose clip.json light selection is reused (otherwise each scene's is chosen again,
as benchgen make does). --spp-factors renders the two seeds again with the preset's spp and adaptive
extra spp multiplied by each factor (what more samples would buy a generator version), with the
render seconds per frame (the low-discrepancy sampler rounds spp up to a power of 4: use factors
1, 4, 16; --adaptive-spp N sets the extra samples instead); --ladder-only skips the one-pass
denoiser, --no-bias the 1,024-spp reference. docs/rendering.md has the tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

from benchgen.clip_pass import BIAS_REFERENCE_SPP, NOISE_SEED_OFFSET  # noqa: E402
from benchgen.denoise import denoise_hdr  # noqa: E402
from benchgen.groundtruth import render_bias, render_noise  # noqa: E402
from benchgen.make import get_preset  # noqa: E402
from benchgen.render import GUIDE_SPP, Renderer, RenderSettings  # noqa: E402
from benchgen.scene import load_scene  # noqa: E402
from benchgen.suite import load_suite  # noqa: E402
from m4dgs.core.temporal import depth_edges  # noqa: E402


def raw_with_guides(r: Renderer, seed: int):
    """(raw colour, albedo, normal) [H, W, 3] of the renderer's state, as render_hdr makes them."""
    mi = r._mi
    guides = mi.load_dict({"type": "aov", "aovs": "albedo:albedo,nn:sh_normal"})
    c = r.render_hdr(seed=seed)
    aux = np.array(mi.render(r.scene, integrator=guides, seed=seed, spp=GUIDE_SPP))
    return c, aux[..., 0:3].astype(np.float32), aux[..., 3:6].astype(np.float32)


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--suite", default="syn-exp-3")
    ap.add_argument("--scenes", default=None, help="comma-separated subset")
    ap.add_argument("--preset", default="small")
    ap.add_argument("--clips", default=None, help="folder of finished clips (light selection)")
    ap.add_argument(
        "--spp-factors",
        default="1",
        help="comma-separated multipliers of the preset's spp and adaptive extra spp (default 1)",
    )
    ap.add_argument(
        "--adaptive-spp",
        type=int,
        default=None,
        help="adaptive extra spp (mean per pixel) for every factor instead of the scaled one",
    )
    ap.add_argument("--ladder-only", action="store_true", help="skip the one-pass denoiser")
    ap.add_argument("--no-bias", action="store_true", help="skip the 1,024-spp bias reference")
    a = ap.parse_args()
    factors = [float(x) for x in a.spp_factors.split(",")]
    pr = get_preset(a.preset)
    W, H = pr.width, pr.height
    pick = None if a.scenes is None else set(a.scenes.split(","))
    for path in load_suite(a.suite).scenes:
        if pick is not None and path.stem not in pick:
            continue
        scene = load_scene(path, band_limit=(W, H))
        st = scene.frame(0, W, H)
        settings = dataclasses.replace(RenderSettings.resolve(a.preset), denoise=False)
        if a.clips:
            meta = json.loads((Path(a.clips) / path.stem / "clip.json").read_text())
            mode = meta["gt"]["render"].get("emitter_sampling", settings.emitter_sampling)
            settings = dataclasses.replace(settings, emitter_sampling=mode)
        base = settings
        ref = cast = None
        for k in factors:
            extra = round(base.adaptive_spp * k) if a.adaptive_spp is None else a.adaptive_spp
            settings = dataclasses.replace(
                base, spp=max(1, round(base.spp * k)), adaptive_spp=extra
            )
            r = Renderer(st, W, H, settings)
            r.update(st)
            if cast is None:
                cast = r.cast_rays()
                emitter = r.emitter_pixels()
                inner = cast.hit & ~depth_edges(cast.depth)
                if not a.no_bias:
                    ref = r.render_hdr(seed=2 * NOISE_SEED_OFFSET, spp=BIAS_REFERENCE_SPP)
            t0 = time.perf_counter()
            A, B = raw_with_guides(r, 0), raw_with_guides(r, NOISE_SEED_OFFSET)
            render_sec = (time.perf_counter() - t0) / 2
            for ladder in (True,) if a.ladder_only else (False, True):
                t0 = time.perf_counter()
                da = denoise_hdr(*A, emitter, ladder=ladder)
                sec = time.perf_counter() - t0
                db = denoise_hdr(*B, emitter, ladder=ladder)
                n = render_noise(da, db, cast.hit)
                ni = render_noise(da, db, inner)
                bias = ""
                if ref is not None:
                    b = render_bias(da, ref, cast.hit & ~emitter)
                    bands = " ".join(f"{e:.3f}" for e in b["median_rel_error"])
                    bias = f"  bias by band [{bands}]  mean {b['mean_rel_error']:.3f}"
                print(
                    f"{path.stem:26s} {'ladder' if ladder else 'one pass':8s} spp "
                    f"{settings.spp}+{settings.adaptive_spp} rel.std {n['rel_std']:.4f}  "
                    f"noise(int) {ni['tae_two_seeds']:.4f}{bias}  render {render_sec:.1f} s, "
                    f"denoise {sec:.2f} s",
                    flush=True,
                )


if __name__ == "__main__":
    main()
