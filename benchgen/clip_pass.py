"""The ground-truth pass over a clip: HDR, depth, flow, tracks and masks of every frame
(docs/rendering.md).

This module holds :func:`render_clip_gt`, which walks a clip's frames with one
:class:`benchgen.render.Renderer` (the Mitsuba scene and its exact ray casts) and turns each
frame's render and ray cast into the clip's ground truth through benchgen.groundtruth: pass 1
(:func:`_track_queries`) picks the track queries on the reference frames, pass 2
(:class:`_GroundTruthPass`) renders and casts every frame once and writes the files and the notes
(render noise, bias and the HDR-TAE floor). :func:`frame_progress` is the progress bar of a walk
over frames, shared with benchgen.make's test-view renders.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Dict, List, Optional

import numpy as np

from m4dgs.clip import TrackSet, frame_name

from .groundtruth import DEFAULT_DEPTH_RTOL, render_bias, render_noise
from .render import Renderer, RenderSettings

# --------------------------------------------------------------------------------------------------
# Whole-clip ground truth
# --------------------------------------------------------------------------------------------------
# seed of the second, independent render of the first frame (noise measurement)
NOISE_SEED_OFFSET = 1_000_003
#: samples per pixel of the reference render that gt.render_bias compares the first frame with
BIAS_REFERENCE_SPP = 1024


def render_clip_gt(
    scene,
    width: int,
    height: int,
    frames,
    preset,
    out,
    progress: bool = True,
    *,
    num_grid: int = 256,
    num_dynamic: int = 64,
    num_ref: int = 4,
    rtol: float = DEFAULT_DEPTH_RTOL,
    hdr_dir=("gt", "hdr"),
    rendered: Optional[Dict[int, dict]] = None,
) -> dict:
    """Render and write the ground truth of a clip through a m4dgs.clip.ClipWriter.

    For every frame g in `frames`: the HDR frame into `hdr_dir` (a folder relative to the clip,
    default gt/hdr; skipped when the file exists: resume; read back where needed), gt/depth
    (z-depth, 0 = no surface) and gt/masks/dynamic. Then gt/cameras.json, gt/flow.npz (exact flow +
    visibility between consecutive TRAINING frames of out.meta.split.train, both directions) and
    gt/tracks.npz (over all frames, queries from `num_ref` reference frames). Returns the
    ground-truth notes, also merged into out.meta.gt: render_noise {rel_std, tae_two_seeds, mu_psnr}
    from two seeds of the first frame, hdr_tae_floor (HDR-TAE of the ground-truth training sequence
    with its exact flow and visibility) and hdr_tae_floor_interior (the same without occlusion-edge
    pixels), render settings, variant and timings. Does not call out.finalize() (the caller owns
    clip.json).

    rendered: {g: {"extra_spp", "seconds"}} of the frames in `hdr_dir` that a render task made
    (benchgen.distribute): they count in the notes' adaptive samples and render time as if this
    pass had rendered them, so that the notes do not depend on where the frames were rendered."""
    from .groundtruth import default_reference_indices

    settings = RenderSettings.resolve(preset)
    frames = [int(g) for g in frames]
    if not frames:
        raise ValueError("render_clip_gt: no frames")
    fset = set(frames)
    train = [g for g in out.meta.split.train if g in fset]
    first = scene.frame(frames[0], width, height)
    renderer = Renderer(first, width, height, settings)
    # pass 1: query points on the reference frames (ray casts only)
    refs = default_reference_indices(len(frames), num_ref)
    queries = _track_queries(
        scene, renderer, first, frames, refs, num_grid, num_dynamic, settings.seed
    )
    # pass 2: every frame once
    gt = _GroundTruthPass(renderer, out, queries, train, rtol, hdr_dir, rendered)
    for g in frame_progress(frames, scene, progress):
        gt.add_frame(g, first if g == frames[0] else scene.frame(g, width, height), g == frames[0])
    gt.write(frames)
    notes = gt.notes(settings, rtol)
    notes["tracks"] = {
        "num": int(len(queries)),
        "reference_frames": [frames[r] for r in refs],
        "num_grid": num_grid,
        "num_dynamic": num_dynamic,
    }
    out.meta.gt.update(notes)
    return notes


def _track_queries(scene, renderer, first, frames, refs, num_grid, num_dynamic, seed):
    """Pass 1 of render_clip_gt: ground-truth track queries (uniform grid + dynamic pixels) on the
    reference frames `refs` (indices into frames), from ray casts only."""
    from .groundtruth import SurfaceQueries, select_queries

    rng = np.random.default_rng(seed)
    W, H = renderer.width, renderer.height
    queries = []
    for r in refs:
        st = first if r == 0 else scene.frame(frames[r], W, H)
        renderer.update(st)
        queries.append(select_queries(renderer.cast_rays(), st, r, num_grid, num_dynamic, rng))
    return SurfaceQueries.concat(queries)


def frame_progress(frames, scene, progress: bool):
    """The frames, with a tqdm progress bar when asked for and available."""
    if progress:
        try:
            from m4dgs.core.progress import progress_bar

            return progress_bar(
                frames,
                desc=f"render {getattr(scene, 'name', '')}",
                unit="frame",
                dynamic_ncols=False,
            )
        except ImportError:
            pass
    return frames


class _GroundTruthPass:
    """Pass 2 of render_clip_gt: per frame the ray cast, the HDR render (or the file of a resumed
    clip), depth and dynamic mask, track positions, and for consecutive training frames the exact
    flow and the HDR-TAE floor terms; then the clip files and the notes."""

    def __init__(self, renderer, out, queries, train, rtol, hdr_dir, rendered=None):
        self.renderer, self.out, self.q = renderer, out, queries
        self.rendered = dict(rendered or {})  # frames a render task made: their stats
        self.train, self.rtol, self.hdr_dir = set(train), rtol, tuple(hdr_dir)
        self.cams, self.tr_uv, self.tr_p3, self.tr_vis = [], [], [], []
        self.pairs, self.flows, self.valids = [], [], []
        self.tae_pairs, self.tae_inner = [], []
        self.prev = None  # (g, state, cast, hdr) of the previous training frame
        self.noise = self.noise_interior = self.surface_fraction = self.bias = None
        self.t_render, self.t_cast, self.n_render = 0.0, 0.0, 0
        self.extra_spp: List[float] = []

    def add_frame(self, g: int, st, first: bool) -> None:
        from .groundtruth import dynamic_mask, track_frame

        r, out = self.renderer, self.out
        r.update(st)
        t0 = time.perf_counter()
        cast = r.cast_rays()
        self.t_cast += time.perf_counter() - t0
        self.cams.append(st)
        hdr = self._hdr(g, need=g in self.train or first)
        if not out.exists("gt", "depth", frame_name(g, "exr")):
            out.write_gt_depth(g, cast.depth)
        if not out.exists("gt", "masks", "dynamic", frame_name(g, "png")):
            out.write_gt_dynamic_mask(g, dynamic_mask(cast.instance, st))
        if first:
            self._measure_noise(g, hdr, cast)
        uv, p3, vis = track_frame(self.q, st, cast.depth, cast.instance, self.rtol)
        self.tr_uv.append(uv)
        self.tr_p3.append(p3)
        self.tr_vis.append(vis)
        if g in self.train:
            if self.prev is not None:
                self._add_pair(self.prev, (g, st, cast, hdr))
            self.prev = (g, st, cast, hdr)

    def _hdr(self, g: int, need: bool) -> Optional[np.ndarray]:
        """The frame's HDR: rendered and written, or read back from a resumed clip (or a render
        task, whose stats count as if rendered here) when `need`."""
        from m4dgs.core import io as mio

        rel = self.hdr_dir + (frame_name(g, "exr"),)
        if self.out.exists(*rel):
            stats = self.rendered.get(g)
            if stats is not None:
                self.t_render += float(stats["seconds"])
                self.n_render += 1
                if stats.get("extra_spp") is not None:
                    self.extra_spp.append(float(stats["extra_spp"]))
            return mio.read_exr(self.out.root.joinpath(*rel)).astype(np.float32) if need else None
        t0 = time.perf_counter()
        hdr = self.renderer.render_hdr()
        self.t_render += time.perf_counter() - t0
        self.n_render += 1
        if self.renderer.last_extra_spp is not None:
            self.extra_spp.append(self.renderer.last_extra_spp)
        mio.write_exr(self.out.root.joinpath(*rel), hdr)
        return hdr

    def _measure_noise(self, g: int, hdr: np.ndarray, cast) -> None:
        """Two-seed noise of the first frame, over surface pixels and over interior ones."""
        from m4dgs.core.temporal import depth_edges

        r = self.renderer
        other = r.render_hdr(seed=r.settings.seed + g + NOISE_SEED_OFFSET)
        self.noise = render_noise(hdr, other, cast.hit)
        self.noise_interior = render_noise(hdr, other, cast.hit & ~depth_edges(cast.depth))
        # what the denoised frame gets wrong: against a raw render of BIAS_REFERENCE_SPP samples
        # (its own relative noise ~0.01-0.02 at the median pixel), over the surface pixels that are
        # not emitters (those bypass the denoiser)
        ref = r.render_hdr(
            seed=r.settings.seed + g + 2 * NOISE_SEED_OFFSET, spp=BIAS_REFERENCE_SPP, denoise=False
        )
        self.bias = render_bias(hdr, ref, cast.hit & ~r.emitter_pixels())
        self.surface_fraction = float(cast.hit.mean())

    def _add_pair(self, a, b) -> None:
        """Exact flow both ways between consecutive training frames and the pair's HDR-TAE, with
        and without occlusion-edge pixels."""
        from m4dgs.core.temporal import depth_edges, hdr_tae_pairs, interior_visibility

        from .groundtruth import flow_between

        ga, sa, ca, ha = a
        gb, sb, cb, hb = b
        rtol = self.rtol
        f_ab, v_ab = flow_between(ca, sb, sb, cb.depth, cb.instance, cam_a=sa, rtol=rtol)
        f_ba, v_ba = flow_between(cb, sa, sa, ca.depth, ca.instance, cam_a=sb, rtol=rtol)
        self.pairs += [(ga, gb), (gb, ga)]
        self.flows += [f_ab, f_ba]
        self.valids += [v_ab, v_ba]
        pair = np.stack([ha, hb])
        self.tae_pairs += hdr_tae_pairs(pair, f_ab[None], f_ba[None], v_ab[None], v_ba[None])
        ea, eb = depth_edges(ca.depth), depth_edges(cb.depth)
        self.tae_inner += hdr_tae_pairs(
            pair,
            f_ab[None],
            f_ba[None],
            interior_visibility(v_ab, f_ab, ea, eb)[None],
            interior_visibility(v_ba, f_ba, eb, ea)[None],
        )

    def write(self, frames) -> None:
        """gt/cameras.json, gt/flow.npz (training pairs) and gt/tracks.npz."""
        from m4dgs.clip import FlowSet

        from .groundtruth import cameras_from_states

        out = self.out
        out.write_gt_cameras(cameras_from_states(self.cams))
        if self.pairs:
            out.write_gt_flow(
                FlowSet(
                    pairs=np.array(self.pairs, np.int64),
                    flow=np.stack(self.flows),
                    valid=np.stack(self.valids),
                )
            )
        out.write_gt_tracks(
            TrackSet(
                tracks=np.stack(self.tr_uv, 1).astype(np.float32),
                visible=np.stack(self.tr_vis, 1),
                frames=np.array(frames, np.int64),
                points3d=np.stack(self.tr_p3, 1).astype(np.float32),
                dynamic=self.q.dynamic.astype(bool),
            )
        )

    def notes(self, settings, rtol) -> dict:
        r = self.renderer
        finite = [v for v in self.tae_pairs if np.isfinite(v)]
        inner = [v for v in self.tae_inner if np.isfinite(v)]
        floor = float(np.mean(finite)) if finite else None
        floor_inner = float(np.mean(inner)) if inner else None
        noise_inner = float(self.noise_interior["tae_two_seeds"])
        return {
            "render": {
                "variant": r.variant,
                **dataclasses.asdict(settings),
                "integrator": "path",
                "pixel_filter": "box",
                "emitter_sampling": r.emitter_sampling,
                "emitter_weights": r.emitter_weights,
                # extra samples per pixel the adaptive sampler spent, mean over rendered frames
                "adaptive_extra_spp_mean": float(np.mean(self.extra_spp))
                if self.extra_spp
                else None,
            },
            "render_noise": {
                k: (float(v) if np.isfinite(v) else None) for k, v in self.noise.items()
            },
            "render_noise_pixels": "surface pixels of the first frame (no-surface pixels "
            "excluded, as in HDR-TAE)",
            "render_bias": {
                **self.bias,
                "reference_spp": BIAS_REFERENCE_SPP,
                "bands": "darkest tenth, 10-50 %, 50-90 %, brightest tenth of the reference's "
                "brightness (surface pixels of the first frame that are not emitters)",
            },
            "surface_fraction_first_frame": self.surface_fraction,
            "hdr_tae_floor": floor,
            "hdr_tae_floor_convention": "HDR-TAE (channel sum) of the gt training sequence with "
            "exact gt flow and visibility (m4dgs.core.temporal.hdr_tae_pairs)",
            # the edge-excluded variant eval reports as hdr_tae_interior
            "hdr_tae_floor_interior": floor_inner,
            "hdr_tae_floor_interior_convention": "the same without occlusion-edge pixels (a 5 % "
            "depth jump or a surface boundary, grown by 1 px, in either frame; "
            "m4dgs.core.temporal.depth_edges), as eval's hdr_tae_interior",
            # where the floor comes from: occlusion-edge pixels (mixed colours, one flow), noise
            # (two seeds of frame 0, no motion), and the rest (resampling of texture by the
            # bilinear warp, shading that changes with motion)
            "hdr_tae_floor_parts": {
                "interior": floor_inner,
                "edges": floor - floor_inner if finite and inner else None,
                "noise_interior_two_seeds": noise_inner,
                "rest_interior": floor_inner - noise_inner if inner else None,
            },
            "depth_no_surface": 0.0,
            "visibility_depth_rtol": rtol,
            "timing_s_per_frame": {
                "render": self.t_render / self.n_render if self.n_render else None,
                "ray_cast": self.t_cast / len(self.cams),
            },
        }
