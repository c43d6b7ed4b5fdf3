"""Where a run's test-frame error sits: its squared error split over disjoint pixel regions.

A score says how far a run is off; this says where. Each test frame's pixels are split into
disjoint regions read from the clip's ground truth:

- ``bright``: pixels whose ground-truth HDR value (the maximum over channels, clip units) exceeds
  ``bright_above``, or, with ``bright_top``, the frame's brightest fraction of pixels by that value;
  grown by ``dilate`` pixels (4-connected steps) so that a lamp's antialiased rim goes with it;
- ``edge`` (only with ``edges``): both pixels of every pair of 4-neighbours whose ground-truth
  depths differ by more than the fraction ``edges`` (occlusion boundaries), less ``bright``;
- ``dynamic``: the ground truth's dynamic mask (``gt/masks/dynamic``), less the above;
- ``static``: the rest.

Per domain (each LDR test level, 8-bit codes scaled to [0, 1] as the renders are written, and the
HDR frames in the mu-law domain normalised by the ground truth's maximum, the HDR PSNR's convention,
docs/metrics.md) it gives each region's share of the pixels and of the squared error, the PSNR of
the region alone and the PSNR with the region left out (both per frame, capped, then the mean over
the frames that have such pixels, as the scores average). Beside a reference run of the same scene,
frames and levels it gives how the change in squared error splits over the regions and the change
of each PSNR. The two kinds of number pool differently: squared errors are summed over all frames,
PSNRs averaged over frames, so for a small change a region's error factor and the change of its
PSNR can point different ways (a few frames' large errors dominate a sum, not a mean of logs); the
PSNR columns are the ones that move as the scores do. `m4dgs-eval regions` prints it (docs/eval.md).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

from eval.experiments.run_files import read_render_exr, resolve_clip_dir
from eval.experiments.runner import job_list
from eval.experiments.score import PSNR_CAP_DB
from eval.metrics._util import psnr_from_mse
from eval.metrics.hdr import hdr_tonemap_pair
from eval.metrics.image import masked_psnr
from eval.stats import interval_text, mean_ci
from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError

REGIONS = ("bright", "edge", "dynamic", "static")


def active_regions(opts: dict) -> List[str]:
    """The regions a split with these options (split_run's "regions") can fill: dynamic and
    static always, bright with a bright option, edge with edges."""
    out = []
    if opts.get("bright_above") is not None or opts.get("bright_top") is not None:
        out.append("bright")
    if opts.get("edges") is not None:
        out.append("edge")
    return out + ["dynamic", "static"]


def depth_edges(depth: np.ndarray, rel: float) -> np.ndarray:
    """[H, W] bool: both pixels of every pair of 4-neighbours whose depths differ by more than the
    fraction rel of the nearer (|log z1 - log z2| > log(1 + rel)). depth: [H, W] (or [H, W, 1]);
    a pixel without a finite positive depth (sky) counts as farther than everything else, so a
    rim against the sky is an edge and the sky itself is not."""
    if not rel > 0:
        raise ValueError(f"edges must be > 0, got {rel}")
    z = np.asarray(depth, dtype=np.float64)
    z = z[..., 0] if z.ndim == 3 else z
    ok = np.isfinite(z) & (z > 0)
    far = float(z[ok].max()) * 1e3 if ok.any() else 1.0
    lz = np.log(np.where(ok, z, far))
    cut = math.log1p(float(rel))
    dx = np.abs(np.diff(lz, axis=1)) > cut
    dy = np.abs(np.diff(lz, axis=0)) > cut
    e = np.zeros(z.shape, dtype=bool)
    e[:, 1:] |= dx
    e[:, :-1] |= dx
    e[1:, :] |= dy
    e[:-1, :] |= dy
    return e


def region_masks(
    gt_hdr: np.ndarray,
    dynamic: Optional[np.ndarray] = None,
    *,
    bright_above: Optional[float] = None,
    bright_top: Optional[float] = None,
    dilate: int = 0,
    depth: Optional[np.ndarray] = None,
    edges: Optional[float] = None,
) -> Dict[str, np.ndarray]:
    """Disjoint boolean masks [H, W] covering the frame, keyed by REGIONS.

    gt_hdr: [H, W, C] linear ground truth. dynamic: [H, W] bool ground-truth dynamic mask, or None
    (no dynamic region). bright_above / bright_top (at most one; neither: an empty bright region):
    a threshold on max over channels of gt_hdr, or the fraction in (0, 1) of the frame's pixels
    with the largest such value (ties at the cut included). dilate: grow the bright region by this
    many 4-connected steps. edges: the edge region, depth_edges(depth, edges) less bright (None:
    an empty edge region); depth: [H, W] ground-truth depth, needed with edges.
    """
    if bright_above is not None and bright_top is not None:
        raise ValueError("give bright_above or bright_top, not both")
    if dilate < 0:
        raise ValueError(f"dilate must be >= 0, got {dilate}")
    peak = np.asarray(gt_hdr, dtype=np.float64)
    peak = peak.max(axis=-1) if peak.ndim == 3 else peak
    if bright_above is not None:
        bright = peak > float(bright_above)
    elif bright_top is not None:
        if not 0.0 < float(bright_top) < 1.0:
            raise ValueError(f"bright_top must lie in (0, 1), got {bright_top}")
        k = max(1, int(math.ceil(float(bright_top) * peak.size)))
        cut = np.partition(peak.ravel(), peak.size - k)[peak.size - k]
        bright = peak >= cut
    else:
        bright = np.zeros(peak.shape, dtype=bool)
    if dilate and bright.any():
        from scipy.ndimage import binary_dilation

        bright = binary_dilation(bright, iterations=int(dilate))
    if dynamic is None:
        dyn = np.zeros(peak.shape, dtype=bool)
    else:
        dyn = np.asarray(dynamic, dtype=bool)
        if dyn.shape != peak.shape:
            raise ValueError(f"dynamic mask {dyn.shape} does not match the frame {peak.shape}")
    if edges is None:
        edge = np.zeros(peak.shape, dtype=bool)
    else:
        if depth is None:
            raise ValueError("an edge region needs the ground-truth depth")
        edge = depth_edges(depth, edges)
        if edge.shape != peak.shape:
            raise ValueError(f"depth {edge.shape} does not match the frame {peak.shape}")
        edge &= ~bright
    dyn = dyn & ~bright & ~edge
    return {"bright": bright, "edge": edge, "dynamic": dyn, "static": ~(bright | edge | dyn)}


def region_sse(pred: np.ndarray, gt: np.ndarray, masks: Dict[str, np.ndarray]) -> Dict[str, float]:
    """Sum of squared errors over each region's pixels and all channels. pred, gt: [H, W, C]
    float in [0, 1]; masks: [H, W] bool per region."""
    err = ((np.asarray(pred, np.float64) - np.asarray(gt, np.float64)) ** 2).sum(axis=-1)
    return {r: float(err[m].sum()) for r, m in masks.items()}


def _capped(mse: float) -> float:
    """PSNR (peak 1) of a mean squared error, capped at the scores' cap."""
    return min(psnr_from_mse(mse, 1.0), PSNR_CAP_DB)


def psnr_without(pred: np.ndarray, gt: np.ndarray, left_out: np.ndarray) -> float:
    """PSNR (peak 1, capped at the scores' cap) over the pixels outside `left_out` ([H, W] bool):
    the project's masked PSNR of the complement; NaN when nothing is left. pred, gt: [H, W, C]
    float in [0, 1]. The direct per-frame form of what _Domain.add derives from the region sums
    (the tests compare the two)."""
    v = masked_psnr(pred, gt, ~np.asarray(left_out, dtype=bool))
    return math.nan if v is None else min(v, PSNR_CAP_DB)


def _mean(values: Sequence[float], weights: Optional[Sequence[float]] = None) -> Optional[float]:
    """Mean (weighted) of the values that are not None / NaN; None when none is left."""
    w = [1.0] * len(values) if weights is None else list(weights)
    vw = [(x, wi) for x, wi in zip(values, w) if x is not None and not math.isnan(x)]
    if not vw:
        return None
    return float(np.average([x for x, _ in vw], weights=[wi for _, wi in vw]))


class _Domain:
    """Accumulates one domain (a test level or the HDR frames) over frames."""

    def __init__(self):
        self.frames = 0
        self.pixels = {r: 0 for r in REGIONS}
        self.sse = {r: 0.0 for r in REGIONS}
        self.psnr: List[float] = []
        self.without: Dict[str, List[float]] = {r: [] for r in REGIONS}
        self.only: Dict[str, List[float]] = {r: [] for r in REGIONS}

    def add(self, pred: np.ndarray, gt: np.ndarray, masks: Dict[str, np.ndarray]) -> None:
        """One frame: its squared error is computed once; the regions cover the frame, so the
        error outside a region is the frame's total less the region's (the same value as
        psnr_without, without a pass per region)."""
        sse = region_sse(pred, gt, masks)
        total, channels = sum(sse.values()), np.shape(pred)[-1]
        n_all = masks["static"].size
        self.frames += 1
        self.psnr.append(_capped(total / (n_all * channels)))
        for r in REGIONS:
            n = int(masks[r].sum())
            self.sse[r] += sse[r]
            self.pixels[r] += n
            rest = n_all - n
            self.without[r].append(
                _capped(max(total - sse[r], 0.0) / (rest * channels)) if rest else math.nan
            )
            self.only[r].append(_capped(sse[r] / (n * channels)) if n else math.nan)

    def result(self) -> dict:
        return {
            "frames": self.frames,
            "pixels": dict(self.pixels),
            "sse": dict(self.sse),
            "psnr": _mean(self.psnr),
            "psnr_without": {r: _mean(v) for r, v in self.without.items()},
            "psnr_only": {r: _mean(v) for r, v in self.only.items()},
        }


def renders_root(run: Path) -> Path:
    """RUN/renders for a run folder; RUN itself for a prediction folder (score-frames layout)."""
    return run / "renders" if (run / "renders" / "test").is_dir() else run


def _ldr01(img: np.ndarray) -> np.ndarray:
    return np.asarray(img, np.float64) / 255.0


def frame_pair(root: Path, clip: Clip, g: int, level: Optional[float]) -> tuple:
    """(prediction, ground truth), each [H, W, C] float64 in [0, 1], of test frame g as the scores
    compare them: the 8-bit LDR render at `level` (RUN/renders/test/ldr/<level>/<g>.png) over 255,
    or with level None the HDR render and ground truth mu-law tone-mapped, normalised by the
    ground truth's maximum (the HDR PSNR's domain). root: RUN/renders (or a prediction folder)."""

    def need(p: Path) -> Path:
        if not p.exists():
            raise InputError(
                f"{p}: missing render (render the run's test frames first: m4dgs render)"
            )
        return p

    if level is None:
        tp, tg = hdr_tonemap_pair(
            read_render_exr(need(root / "test/hdr" / frame_name(g, "exr"))),
            clip.load_gt_hdr(g),
        )
        return tp[0].numpy(), tg[0].numpy()
    p = mio.read_png(need(root / "test/ldr" / level_name(level) / frame_name(g, "png")))
    return _ldr01(p), _ldr01(clip.load_gt_ldr(level, g))


def split_run(
    run,
    clip=None,
    *,
    bright_above: Optional[float] = None,
    bright_top: Optional[float] = None,
    dilate: int = 0,
    edges: Optional[float] = None,
    masks_cache: Optional[dict] = None,
) -> dict:
    """The region split of one run's test renders (RUN/renders/test/{ldr/<level>,hdr}/<frame>).

    Returns {"run", "clip", "test_frames", "regions" (the options), "domains": {name: {"kind"
    ("observed", "novel", "hdr"), "frames", "pixels" {region: count}, "sse" {region: float},
    "psnr", "psnr_only" {region: dB}, "psnr_without" {region: dB}}}}, the domains named
    "ldr <level>" and "hdr", plus "LDR-OE" / "LDR-NE" (the levels' pixels and errors summed, their
    PSNRs averaged over levels, as ldr_oe_psnr is). edges: an edge region of depth jumps above
    this fraction (region_masks; needs the clip's gt/depth). masks_cache: a dict shared between
    calls on the same clip with the same region options (the masks of its frames are computed
    once).
    """
    run = Path(run)
    clip_obj = clip if isinstance(clip, Clip) else Clip.open(resolve_clip_dir(run, clip))
    if not clip_obj.has_gt:
        raise InputError(f"{clip_obj.root / 'gt'}: the clip has no ground truth to split against")
    test = clip_obj.test_frames
    if not test:
        raise InputError(f"{clip_obj.root / 'clip.json'}: split: the clip has no test frames")
    if edges is not None and not clip_obj.has_gt_part("depth"):
        raise InputError(
            f"{clip_obj.root / 'gt/depth'}: missing; an edge region needs the ground-truth depth"
        )
    root = renders_root(run)
    has_dyn = (clip_obj.root / "gt/masks/dynamic").is_dir()
    cache = {} if masks_cache is None else masks_cache

    def masks_of(g: int) -> Dict[str, np.ndarray]:
        if g not in cache:
            dyn = clip_obj.load_gt_dynamic_mask(g) if has_dyn else None
            cache[g] = region_masks(
                clip_obj.load_gt_hdr(g),
                dyn,
                bright_above=bright_above,
                bright_top=bright_top,
                dilate=dilate,
                depth=clip_obj.load_gt_depth(g) if edges is not None else None,
                edges=edges,
            )
        return cache[g]

    ex = clip_obj.meta.exposures
    domains: Dict[str, dict] = {}
    for kind, levels in (("observed", ex.observed), ("novel", ex.novel)):
        for lv in levels:
            frames = [g for g in test if lv in clip_obj.meta.test_levels_of(g)]
            if not frames:
                continue
            acc = _Domain()
            for g in frames:
                acc.add(*frame_pair(root, clip_obj, g, lv), masks_of(g))
            domains[f"ldr {level_name(lv)}"] = dict(acc.result(), kind=kind)
    if clip_obj.has_gt_part("hdr"):
        acc = _Domain()
        for g in test:
            acc.add(*frame_pair(root, clip_obj, g, None), masks_of(g))
        domains["hdr"] = dict(acc.result(), kind="hdr")
    # a real clip's levels hold different frame counts: its pools weight them by frames, as the
    # scorer's ldr_oe_psnr does
    weighted = ex.test_dt is not None
    for name, kind in (("LDR-OE", "observed"), ("LDR-NE", "novel")):
        parts = [d for d in domains.values() if d["kind"] == kind]
        if parts:
            domains[name] = _pool(parts, kind, weighted)
    return {
        "run": str(run),
        "clip": str(clip_obj.root),
        "clip_name": clip_obj.meta.name,
        "test_frames": len(test),
        "regions": {
            "bright_above": bright_above,
            "bright_top": bright_top,
            "dilate": dilate,
            "edges": edges,
        },
        "domains": domains,
    }


def _pool(parts: Sequence[dict], kind: str, weighted: bool = False) -> dict:
    """Levels pooled: pixels and errors summed, PSNRs the mean over levels (weighted by their
    frame counts when `weighted`), as ldr_oe_psnr / ldr_ne_psnr are."""
    w = [d["frames"] for d in parts] if weighted else None
    return {
        "kind": f"{kind} (levels pooled)",
        "frames": sum(d["frames"] for d in parts),
        "pixels": {r: sum(d["pixels"][r] for d in parts) for r in REGIONS},
        "sse": {r: sum(d["sse"][r] for d in parts) for r in REGIONS},
        "psnr": _mean([d["psnr"] for d in parts], w),
        "psnr_without": {r: _mean([d["psnr_without"][r] for d in parts], w) for r in REGIONS},
        "psnr_only": {r: _mean([d["psnr_only"][r] for d in parts], w) for r in REGIONS},
    }


def check_comparable(a: Clip, b: Clip) -> None:
    """Raise InputError unless two clips are of one scene with the same frame size, test frames and
    levels, so that their runs' errors can be compared pixel for pixel. Their ground truths may
    still differ in scale (benchgen places each clip's exposure range on its own schedule) and
    their priors in anything: each run is split against its own clip's ground truth."""
    for what, x, y in (
        ("name", a.meta.name, b.meta.name),
        ("frame size", (a.width, a.height), (b.width, b.height)),
        ("test frames", a.test_frames, b.test_frames),
        ("observed levels", list(a.meta.exposures.observed), list(b.meta.exposures.observed)),
        ("novel levels", list(a.meta.exposures.novel), list(b.meta.exposures.novel)),
    ):
        if x != y:
            raise InputError(
                f"{b.root / 'clip.json'}: {what} {y} differs from {a.root}'s ({x}); a reference "
                "run must be of the same scene, frames and levels"
            )


def _pct(x: Optional[float]) -> str:
    return "n/a" if x is None or math.isnan(x) else f"{100.0 * x:.1f}"


def _db(x: Optional[float], signed: bool = False) -> str:
    if x is None or math.isnan(x):
        return "n/a"
    return f"{x:+.2f}" if signed else f"{x:.2f}"


def _share(part: float, whole: float) -> Optional[float]:
    return part / whole if whole > 0 else None


def format_split(res: dict) -> str:
    """One run's split as a Markdown table (a row per domain; a column group per active region)."""
    regions = active_regions(res["regions"])
    head = ["domain", "frames", "PSNR"]
    for r in regions:
        head += [f"{r} px %", f"{r} err %", f"{r} alone", f"w/o {r}"]
    lines = ["| " + " | ".join(head) + " |", "|:---" + "|---:" * (len(head) - 1) + "|"]
    for name, d in res["domains"].items():
        px, sse = sum(d["pixels"].values()), sum(d["sse"].values())
        row = [name, str(d["frames"]), _db(d["psnr"])]
        for r in regions:
            row += [
                _pct(_share(d["pixels"][r], px)),
                _pct(_share(d["sse"][r], sse)),
                _db(d["psnr_only"][r]),
                _db(d["psnr_without"][r]),
            ]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def _diff(a: Optional[float], b: Optional[float]) -> Optional[float]:
    return None if a is None or b is None else a - b


def format_extra(res: dict, ref: dict) -> str:
    """How a run's change in squared error against a reference run splits over the regions
    (Markdown): per domain the PSNR difference, each region's share of the change (a region that
    moves against the total has a negative share, the others then more than 100 %), the factor
    its own summed error grew by, and the PSNR differences of the region alone and with the region
    left out (means over frames, as the scores: they can differ in sign from the error factor)."""
    regions = active_regions(res["regions"])
    head = ["domain", "Δ PSNR"]
    for r in regions:
        head += [f"{r} share of Δ err %", f"{r} err x", f"Δ {r} alone", f"Δ w/o {r}"]
    lines = ["| " + " | ".join(head) + " |", "|:---" + "|---:" * (len(head) - 1) + "|"]
    for name, d in res["domains"].items():
        e = ref["domains"].get(name)
        if e is None:
            continue
        extra = {r: d["sse"][r] - e["sse"][r] for r in REGIONS}
        total = sum(extra.values())
        row = [name, _db(_diff(d["psnr"], e["psnr"]), signed=True)]
        for r in regions:
            growth = d["sse"][r] / e["sse"][r] if e["sse"][r] > 0 else None
            row += [
                _pct(extra[r] / total) if total != 0 else "n/a",
                "n/a" if growth is None else f"{growth:.2f}",
                _db(_diff(d["psnr_only"][r], e["psnr_only"][r]), signed=True),
                _db(_diff(d["psnr_without"][r], e["psnr_without"][r]), signed=True),
            ]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def describe_regions(bright_above, bright_top, dilate, edges=None) -> str:
    """One sentence naming the regions as split."""
    if bright_above is not None:
        b = f"ground-truth HDR above {bright_above:g}"
    elif bright_top is not None:
        b = f"each frame's brightest {100 * bright_top:g} % of pixels"
    else:
        b = "none"
    if dilate and b != "none":
        b += f", grown by {dilate} px"
    if edges is None:
        return f"Regions: bright = {b}; dynamic = gt/masks/dynamic less bright; static = the rest."
    return (
        f"Regions: bright = {b}; edge = both pixels of each 4-neighbour pair whose ground-truth "
        f"depths differ by more than {100 * edges:g} %, less bright; dynamic = gt/masks/dynamic "
        "less those; static = the rest."
    )


# --------------------------------------------------------------------------------------------------
# paired region differences over a suite's (scene, seed) pairs: `m4dgs-eval region-pairs`
# --------------------------------------------------------------------------------------------------
def pair_quantities(regions: Sequence[str] = REGIONS) -> List[str]:
    """The quantities a pair's difference is taken of: the domain's PSNR, then each region's
    PSNR alone, then each region's PSNR with it left out. Of only two regions (dynamic and static)
    only the first two kinds: the one left out leaves the other alone."""
    alone = ["PSNR"] + [f"{r} alone" for r in regions]
    return alone if len(regions) <= 2 else alone + [f"w/o {r}" for r in regions]


def pair_region_diffs(res: dict, ref: dict, domain: str) -> Dict[str, Optional[float]]:
    """{quantity (pair_quantities): res - ref} of one domain of two splits (split_run); None where
    either side has no such pixels. Raises KeyError naming a domain either split lacks."""
    for side in (res, ref):
        if domain not in side["domains"]:
            raise KeyError(
                f"{side['run']}: no domain {domain!r} (it has {sorted(side['domains'])})"
            )
    d, e = res["domains"][domain], ref["domains"][domain]
    out: Dict[str, Optional[float]] = {"PSNR": _diff(d["psnr"], e["psnr"])}
    for r in REGIONS:
        out[f"{r} alone"] = _diff(d["psnr_only"][r], e["psnr_only"][r])
    for r in REGIONS:
        out[f"w/o {r}"] = _diff(d["psnr_without"][r], e["psnr_without"][r])
    return out


def suite_region_pairs(
    suite,
    root,
    ref: str,
    rows: Sequence[str],
    *,
    scenes: Optional[Sequence[str]] = None,
    seeds: int = 1,
    domain: str = "LDR-OE",
    bright_above: Optional[float] = None,
    bright_top: Optional[float] = None,
    dilate: int = 0,
    edges: Optional[float] = None,
    log=None,
) -> dict:
    """Each row's region differences against `ref` per (scene, seed) pair of a suite's runs under
    ROOT (ROOT/runs/<suite>/<scene>/<row>[-seed-n], split with split_run against the clip each
    job names; a pair counts only when both runs have their test renders, and a scene or seed
    the suite has but ROOT never ran is passed over).

    Returns {"domain", "ref", "regions" (the options), "diffs": {row: {(scene, seed): {quantity:
    row - ref}}}, "missing": [run folders without test renders]}. Raises InputError for a row the
    suite does not have, a ROOT without the suite's runs, or two runs of a pair whose clips cannot
    be compared pixel for pixel."""
    if domain not in ("LDR-OE", "LDR-NE", "hdr") and not domain.startswith("ldr "):
        raise InputError(
            f"domain {domain!r}: one of LDR-OE, LDR-NE, hdr or 'ldr <level>' (e.g. 'ldr 0.125')"
        )
    jobs = job_list(suite, root, "small", scenes, seeds)
    if jobs and not Path(jobs[0].run_dir).parent.parent.is_dir():
        raise InputError(f"{Path(jobs[0].run_dir).parent.parent}: no runs of suite {suite} here")
    by_key = {(j.row, j.scene, int(j.seed)): j for j in jobs}
    names = list(dict.fromkeys(j.row for j in jobs))
    unknown = [n for n in [ref, *rows] if n not in names]
    if unknown:
        raise InputError(f"suite {suite}: no row(s) {unknown} (rows: {names})")
    opts = dict(bright_above=bright_above, bright_top=bright_top, dilate=dilate, edges=edges)
    caches: Dict[str, dict] = {}
    splits: Dict[str, dict] = {}
    missing: List[str] = []

    def rendered(job) -> bool:
        """Whether the job's run has its test renders; a run folder without them is noted."""
        run = Path(job.run_dir)
        if (renders_root(run) / "test").is_dir():
            return True
        if run.is_dir() and job.run_dir not in missing:
            missing.append(job.run_dir)
        return False

    def split_of(job) -> dict:
        if job.run_dir not in splits:
            if log is not None:
                log(f"splitting {job.run_dir} ...")
            clip = Clip.open(job.clip_dir)
            cache = caches.setdefault(str(clip.root), {})
            splits[job.run_dir] = split_run(job.run_dir, clip, masks_cache=cache, **opts)
        return splits[job.run_dir]

    diffs: Dict[str, Dict[tuple, dict]] = {}
    for row in rows:
        diffs[row] = {}
        for (name, scene, seed), job in by_key.items():
            base = by_key.get((ref, scene, seed))
            if name != row or base is None:
                continue
            if not all([rendered(job), rendered(base)]):  # both looked at: both noted
                continue
            check_comparable(Clip.open(base.clip_dir), Clip.open(job.clip_dir))
            diffs[row][(scene, seed)] = pair_region_diffs(split_of(job), split_of(base), domain)
    return {"domain": domain, "ref": ref, "regions": opts, "diffs": diffs, "missing": missing}


def region_changes(result: dict, base: dict, base_suite: str, base_row: str) -> dict:
    """The difference in differences per region: each row's (row - ref) of `result` minus
    (base_row - base's ref) of `base` (both suite_region_pairs results over the same domain and
    region options, e.g. a control suite's effect against its base suite's), per (scene, seed)
    pair that both hold, per quantity where both have a value. Returns a result of the same shape
    (format_region_pairs prints it) with "titles" naming each row's two effects."""
    if base["domain"] != result["domain"] or base["regions"] != result["regions"]:
        raise ValueError("the two results must share the domain and the region options")
    effect = base["diffs"].get(base_row, {})
    diffs: Dict[str, Dict[tuple, dict]] = {}
    titles = {}
    for row, per_pair in result["diffs"].items():
        diffs[row] = {}
        for key, d in per_pair.items():
            if key in effect:
                e = effect[key]
                diffs[row][key] = {q: _diff(d[q], e.get(q)) for q in d}
        titles[row] = f"({row} - {result['ref']}) - ({base_suite}: {base_row} - {base['ref']})"
    missing = list(dict.fromkeys(result["missing"] + base["missing"]))
    return {
        "domain": result["domain"],
        "ref": result["ref"],
        "regions": result["regions"],
        "diffs": diffs,
        "missing": missing,
        "titles": titles,
    }


def format_region_pairs(result: dict, describe: bool = True) -> str:
    """Markdown, one table per row: per quantity the mean of row - ref over the pairs with its
    Student-t 95 % interval (eval.stats.mean_ci, † where it excludes 0), how many pairs are above
    0, then each pair's value (scenes by name, then seeds); the quantities of pair_quantities, the
    bright region's only where the split had one (--bright-above / --bright-top); a region_changes
    result is titled by its two effects. describe=False leaves out the line that defines the
    regions (printed once above several results)."""
    out = [describe_regions(**result["regions"]), ""] if describe else []
    for row, per_pair in result["diffs"].items():
        keys = sorted(per_pair, key=lambda k: (str(k[0]), k[1]))
        title = result.get("titles", {}).get(row, f"{row} - {result['ref']}")
        out += [f"{title}, {result['domain']} (dB)", ""]
        if not keys:
            out += ["no pair with both runs' test renders", ""]
            continue
        out += [
            "| quantity | mean ± 95 % (n) | > 0 | "
            + " | ".join(f"{s} / {sd}" for s, sd in keys)
            + " |",
            "|:---|---:|---:|" + "---:|" * len(keys),
        ]
        for q in pair_quantities(active_regions(result["regions"])):
            vals = {k: per_pair[k][q] for k in keys if per_pair[k][q] is not None}
            if not vals:
                continue
            cells = [f"{vals[k]:+.2f}" if k in vals else "" for k in keys]
            above = f"{sum(v > 0 for v in vals.values())} of {len(vals)}"
            out.append(
                f"| Δ {q} | {interval_text(mean_ci(vals.values()), '.2f')} | {above} | "
                + " | ".join(cells)
                + " |"
            )
        out.append("")
    if result["missing"]:
        out.append("without test renders (left out): " + ", ".join(result["missing"]))
    return "\n".join(out).rstrip() + "\n"
