"""What the HDR-TAE floor of a clip is made of, on one pair of consecutive training frames.

    python bench/floor_bench.py CLIP [--frame 40] [--spp 1024]

CLIP is a finished benchgen clip (its scene spec is found by the clip's generator.scene_spec, its
light selection reused). For the pair (g, g + 2) the script prints the HDR-TAE term (the authors'
convention, and without occlusion-edge pixels) of:

- clip: the clip's own ground-truth frames (denoised), with the exact flow;
- hi_spp: both frames rendered raw at --spp samples per pixel (what is left without the clip's
  Monte Carlo noise and denoiser, up to the --spp render's own noise);
- camera_only: frame g + 2 rendered with frame g's objects and lights and only frame g + 2's camera
  (what the camera motion alone leaves: view-dependent shading, parallax, resampling);
- camera_only_diffuse: the same with every glossy material made diffuse (no view-dependent shading);
- noise_hi_spp: frame g twice at --spp with two seeds (the --spp renders' own noise floor).

So, roughly: scene dynamics (moving lights, objects, deformation) = hi_spp - camera_only;
view-dependent shading = camera_only - camera_only_diffuse; resampling and parallax =
camera_only_diffuse - noise_hi_spp; the clip's noise = clip - hi_spp. docs/rendering.md has the
table for the nine small clips.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import os
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

from benchgen.groundtruth import flow_between  # noqa: E402
from benchgen.render import Renderer, RenderSettings  # noqa: E402
from benchgen.scene import load_scene  # noqa: E402
from benchgen.suite import builtin_scenes_dir  # noqa: E402
from m4dgs.clip import frame_name  # noqa: E402
from m4dgs.core.io import read_exr  # noqa: E402
from m4dgs.core.temporal import depth_edges, hdr_tae_pairs, interior_visibility  # noqa: E402


def camera_of(cam_state, world_state):
    """world_state's objects and lights seen through cam_state's camera (a shallow copy)."""
    h = copy.copy(world_state)
    h.K, h.c2w = cam_state.K, cam_state.c2w
    return h


def all_diffuse(state):
    """state with every glossy material replaced by a diffuse one of the same albedo."""
    h = copy.copy(state)
    meshes = []
    for m in state.meshes:
        m2 = copy.copy(m)
        if m.material.kind == "glossy":
            m2.material = dataclasses.replace(m.material, kind="diffuse")
        meshes.append(m2)
    h.meshes = meshes
    return h


def pair_tae(a, b):
    """(authors' convention, interior) HDR-TAE of two (state, ray cast, hdr) frames."""
    (A, ca, ha), (B, cb, hb) = a, b
    f_ab, v_ab = flow_between(ca, B, B, cb.depth, cb.instance, cam_a=A)
    f_ba, v_ba = flow_between(cb, A, A, ca.depth, ca.instance, cam_a=B)
    ea, eb = depth_edges(ca.depth), depth_edges(cb.depth)
    pair = np.stack([ha, hb])
    full = hdr_tae_pairs(pair, f_ab[None], f_ba[None], v_ab[None], v_ba[None])[0]
    ia = interior_visibility(v_ab, f_ab, ea, eb)
    ib = interior_visibility(v_ba, f_ba, eb, ea)
    inner = hdr_tae_pairs(pair, f_ab[None], f_ba[None], ia[None], ib[None])[0]
    return round(float(full), 4), round(float(inner), 4)


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("clip", help="a finished benchgen clip folder")
    ap.add_argument("--frame", type=int, default=40, help="first training frame g of the pair")
    ap.add_argument("--spp", type=int, default=1024, help="samples per pixel of the raw renders")
    a = ap.parse_args()
    clip = Path(a.clip)
    meta = json.loads((clip / "clip.json").read_text())
    W, H = meta["width"], meta["height"]
    g0, g1 = a.frame, a.frame + 2
    scene = load_scene(builtin_scenes_dir() / meta["generator"]["scene_spec"], band_limit=(W, H))
    s0, s1 = scene.frame(g0, W, H), scene.frame(g1, W, H)
    settings = dataclasses.replace(
        RenderSettings.resolve(meta["generator"]["preset"]),
        emitter_sampling=meta["gt"]["render"]["emitter_sampling"],
        denoise=False,
        adaptive_spp=0,
    )
    glossy = Renderer(s0, W, H, settings)
    # materials are fixed when a Renderer builds its scene (update() moves vertices, camera, lights)
    diffuse = Renderer(all_diffuse(s0), W, H, settings)

    def frame(state, seed, hdr=None, r=glossy):
        r.update(state)
        cast = r.cast_rays()
        return state, cast, (r.render_hdr(seed=seed, spp=a.spp) if hdr is None else hdr)

    def read(g):
        return read_exr(clip / "gt" / "hdr" / frame_name(g, "exr"))

    out = {
        "clip": clip.name,
        "pair": [g0, g1],
        "spp": a.spp,
        "clip_frames": pair_tae(frame(s0, 0, read(g0)), frame(s1, 0, read(g1))),
        "hi_spp": pair_tae(frame(s0, 11), frame(s1, 12)),
        "camera_only": pair_tae(frame(s0, 11), frame(camera_of(s1, s0), 12)),
        "camera_only_diffuse": pair_tae(
            frame(all_diffuse(s0), 11, r=diffuse),
            frame(all_diffuse(camera_of(s1, s0)), 12, r=diffuse),
        ),
        "noise_hi_spp": pair_tae(frame(s0, 21), frame(s0, 22)),
    }
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
