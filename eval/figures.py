"""Figures of a suite (PNG, written atomically): learned CRF curves, loss curves, side-by-side image
grids.

- `crf_figure`: the learned tone curves (metrics.json "crf_curve", sampled from model.tonemap_curve
  by eval.experiments.score) of every row against the clip's true CRF (m4dgs.core.crf.get_crf), LDR
  value vs log2 exposure (as the paper's "Recovered CRFs" figure; RGB mean per row, the true curve
  dashed).
- `loss_figure`: every loss term of log.jsonl against the iteration (densification counters left
  out), log scale, running mean over 1/40 of the iterations, stage 1 then stage 2 on one axis (stage
  2 offset by the last stage-1 step; a dotted line marks the switch).
- `image_grid`: the same test frame for GT and every row: LDR at an observed level, LDR at a novel
  level (when the clip has one), and HDR through the mu-law curve with the GT-max normalisation of
  the metrics.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.crf import get_crf
from m4dgs.core.hdr import mu_law
from m4dgs.run import RunDir

# keys of a log.jsonl record that are not loss terms (plus densification counters, see _is_loss)
NON_LOSS_KEYS = {
    "stage",
    "step",
    "sec",
    "num_gaussians",
    "lr",
    "time",
    "seconds",
    "elapsed",
    "iteration",
}
COUNTER_PREFIXES = ("n_", "num_")
COUNTER_SUFFIXES = ("_clone", "_prune", "_reset", "_split", "_removed")


def _is_loss(key: str) -> bool:
    """Loss terms of a log record: numeric keys that are neither bookkeeping nor densification
    counters."""
    return (
        key not in NON_LOSS_KEYS
        and not key.startswith(COUNTER_PREFIXES)
        and not key.endswith(COUNTER_SUFFIXES)
    )


def smooth(y: np.ndarray, window: int) -> np.ndarray:
    """Centred running mean over `window` points (shrinking at the ends); window <= 1 returns y."""
    if window <= 1 or y.size < 3:
        return y
    c = np.concatenate([[0.0], np.cumsum(y)])
    h = window // 2
    lo = np.clip(np.arange(y.size) - h, 0, y.size)
    hi = np.clip(np.arange(y.size) + h + 1, 0, y.size)
    return (c[hi] - c[lo]) / (hi - lo)


DPI = 100  # every figure of eval (tables, results page, error maps, responses)


def save_png(fig, path) -> Path:
    """Save a matplotlib figure as PNG atomically (temp file in the same folder, then
    os.replace), at DPI and without the Software tag (byte-stable across matplotlib versions'
    builds)."""
    import matplotlib.pyplot as plt  # deferred, as in _plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    path = Path(path)
    mio.write_bytes_atomic(path, buf.getvalue())
    return path


def pyplot():
    # deferred: matplotlib (~0.6 s) and its backend choice, only when a figure is drawn
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


# --------------------------------------------------------------------------------------------------
# CRF
# --------------------------------------------------------------------------------------------------
def learned_crf_curve(c: dict) -> Tuple[np.ndarray, np.ndarray]:
    """(log2 x [n], learned LDR value [n], the mean over RGB) of a crf_curve ({"log2_x", "learned"
    [n][C] or [n], None for a missing value -> NaN})."""
    z = np.asarray(c["log2_x"], np.float64)
    y = np.asarray(
        [[np.nan if v is None else v for v in np.atleast_1d(r)] for r in c["learned"]], np.float64
    )
    return z, y.reshape(len(z), -1).mean(axis=1)


def true_crf_curve(name: str, lo: float, hi: float, n: int) -> Optional[Tuple[np.ndarray, ...]]:
    """(log2 x [n] evenly over [lo, hi], the camera response `name`'s LDR value [n], the mean over
    RGB as learned curves are drawn); None for a response this installation does not know."""
    try:
        f = get_crf(name)
    except Exception:  # noqa: BLE001 - a response recorded by another version
        return None
    zz = np.linspace(lo, hi, n)
    return zz, np.asarray(f.rgb(np.repeat(np.exp2(zz)[:, None], 3, 1))).mean(axis=1)


def crf_figure(curves: Sequence[Tuple[str, dict]], out_png, title: str = "") -> Optional[Path]:
    """Learned CRF curves vs the true CRF.

    Args:
        curves: (label, crf_curve) pairs, crf_curve = metrics.json["crf_curve"] ({"log2_x",
        "learned" [n][C],
            "true" [n] or None, "crf"}).
        out_png: output path.
    Returns the path, or None when no curve is given.
    """
    curves = [(lab, c) for lab, c in curves if c]
    if not curves:
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 3.8))
    # rows of one scene may have different true CRFs (suite crf): each is drawn once
    true_done = set()
    for lab, c in curves:
        z, y = learned_crf_curve(c)
        (line,) = ax.plot(z, y, lw=1.4, label=lab)
        tc = (
            true_crf_curve(c["crf"], z.min(), z.max(), 401)
            if c.get("true") is not None and c.get("crf") not in true_done
            else None
        )
        if tc is not None:
            zz, true = tc
            one_true = len({d.get("crf") for _, d in curves}) == 1
            style = dict(color="k") if one_true else dict(color=line.get_color())
            ax.plot(zz, true, "--", lw=1.2, label=f"true CRF ({c['crf']})", **style)
            true_done.add(c.get("crf"))
    ax.set_xlabel("log2 exposure  log2(H dt)")
    ax.set_ylabel("LDR value")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    if title:
        ax.set_title(title, fontsize=9)
    return save_png(fig, out_png)


# --------------------------------------------------------------------------------------------------
# losses
# --------------------------------------------------------------------------------------------------
def loss_series(
    records: List[dict],
) -> Tuple[Dict[str, Tuple[np.ndarray, np.ndarray]], Optional[float]]:
    """{term: (iterations, values)} over both stages and the stage-2 offset (None without stage 2).

    Iterations: stage-1 steps as they are, stage-2 steps + the last stage-1 step. Non-positive or
    non-finite values are dropped (log scale)."""
    s1 = [r for r in records if r.get("stage") == "stage1"]
    off = float(max((r.get("step", 0) for r in s1), default=0))
    has2 = any(r.get("stage") == "stage2" for r in records)
    series: Dict[str, Tuple[list, list]] = {}
    for r in records:
        st = r.get("stage")
        if st not in ("stage1", "stage2"):
            continue
        it = float(r.get("step", 0)) + (off if st == "stage2" else 0.0)
        for k, v in r.items():
            if not _is_loss(k) or isinstance(v, bool) or not isinstance(v, (int, float)):
                continue
            if not math.isfinite(v) or v <= 0:
                continue
            xs, ys = series.setdefault(k, ([], []))
            xs.append(it)
            ys.append(float(v))
    return {k: (np.asarray(x), np.asarray(y)) for k, (x, y) in series.items()}, (
        off if has2 else None
    )


def loss_figure(run_dir, out_png, title: str = "") -> Optional[Path]:
    """Loss curves of one run (every numeric loss term of log.jsonl, log scale, both stages)."""
    series, off = loss_series(RunDir(run_dir).read_log())
    if not series:
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    n = max(len(v[0]) for v in series.values())
    window = max(1, n // 40)
    for k in sorted(series, key=lambda k: (k != "total", k)):
        x, y = series[k]
        ax.plot(
            x,
            smooth(y, window),
            lw=1.8 if k == "total" else 1.0,
            label=k,
            color="k" if k == "total" else None,
        )
    if off is not None:
        ax.axvline(off, color="k", ls=":", lw=1)
        ax.text(off, ax.get_ylim()[1], " stage 2", fontsize=7, va="top")
    ax.set_yscale("log")
    ax.set_xlabel(
        "iteration (stage 1, then stage 2)"
        + (f"; running mean over {window}" if window > 1 else "")
    )
    ax.set_ylabel("loss")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    if title:
        ax.set_title(title, fontsize=9)
    return save_png(fig, out_png)


# --------------------------------------------------------------------------------------------------
# image grids
# --------------------------------------------------------------------------------------------------
def _mu(h: np.ndarray, scale: float) -> np.ndarray:
    return mu_law(np.asarray(h / max(scale, 1e-12), np.float64))


def pick_frame_and_levels(clip: Clip) -> Tuple[int, float, Optional[float]]:
    """(middle test frame, middle observed level, middle novel level or None)."""
    ex = clip.meta.exposures
    g = clip.test_frames[len(clip.test_frames) // 2]
    obs = sorted(ex.observed)[len(ex.observed) // 2]
    nov = sorted(ex.novel)[len(ex.novel) // 2] if ex.novel else None
    return g, obs, nov


def image_grid(
    clip_dir, runs: Sequence[Tuple[str, str]], out_png, g: Optional[int] = None, title: str = ""
) -> Optional[Path]:
    """GT and each run's render side by side at one test frame: LDR observed / LDR novel / HDR
    (mu-law) rows.

    runs: (label, run_dir) pairs; a run lacking a render shows a blank cell.
    """
    clip = Clip.open(clip_dir)
    # None for a clip without ground-truth HDR (real footage split into training and test frames)
    if not clip.has_gt or not clip.test_frames or not clip.has_gt_part("hdr"):
        return None
    g0, obs, nov = pick_frame_and_levels(clip)
    g = g0 if g is None else g
    gt_hdr = clip.load_gt_hdr(g)
    scale = float(gt_hdr.max())
    blank = np.ones((clip.height, clip.width, 3)) * 0.85
    rows = [
        (
            f"LDR dt={obs:g} (observed)",
            lambda rd, lv=obs: Path(rd)
            / "renders/test/ldr"
            / level_name(lv)
            / frame_name(g, "png"),
            clip.load_gt_ldr(obs, g) / 255.0,
        )
    ]
    if nov is not None:
        rows.append(
            (
                f"LDR dt={nov:g} (novel)",
                lambda rd, lv=nov: Path(rd)
                / "renders/test/ldr"
                / level_name(lv)
                / frame_name(g, "png"),
                clip.load_gt_ldr(nov, g) / 255.0,
            )
        )
    rows.append(
        (
            "HDR (mu-law, GT max)",
            lambda rd: Path(rd) / "renders/test/hdr" / frame_name(g, "exr"),
            _mu(gt_hdr, scale),
        )
    )
    cols = [("GT", None)] + list(runs)
    plt = pyplot()
    cw = 2.4
    ch = cw * clip.height / clip.width
    fig, axes = plt.subplots(
        len(rows), len(cols), figsize=(cw * len(cols), ch * len(rows) + 0.5), squeeze=False
    )
    for i, (rname, pfn, gt_img) in enumerate(rows):
        for j, (lab, rd) in enumerate(cols):
            ax = axes[i][j]
            if rd is None:
                img = gt_img
            else:
                p = pfn(rd)
                if not p.exists():
                    img = blank
                elif p.suffix == ".exr":
                    img = _mu(mio.read_exr(p), scale)
                else:
                    img = mio.read_png(p) / 255.0
            ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(lab, fontsize=7)
            if j == 0:
                ax.set_ylabel(rname, fontsize=7)
    fig.suptitle(title or f"{clip.meta.name}, test frame {g}", fontsize=8)
    return save_png(fig, out_png)


def suite_figures(entries: Sequence[dict], out_dir, *, loss: bool = True) -> List[Path]:
    """Every figure of a suite from its collected runs.

    entries: dicts {"scene", "label", "row", "run_dir", "clip_dir", "metrics"} (eval.cli collects
    them). Writes crf_<scene>.png, grid_<scene>.png and loss_<scene>_<row>.png under out_dir;
    returns the paths."""
    out_dir = Path(out_dir)
    written: List[Path] = []
    scenes = list(dict.fromkeys(e["scene"] for e in entries))
    for sc in scenes:
        es = [e for e in entries if e["scene"] == sc]
        p = crf_figure(
            [(e["label"], (e.get("metrics") or {}).get("crf_curve")) for e in es],
            out_dir / f"crf_{sc}.png",
            title=f"Learned CRFs, {sc}",
        )
        if p:
            written.append(p)
        clip_dir = next(
            (
                e["clip_dir"]
                for e in es
                if e.get("clip_dir") and (Path(e["clip_dir"]) / "clip.json").exists()
            ),
            None,
        )
        if clip_dir is not None:
            p = image_grid(
                clip_dir, [(e["label"], e["run_dir"]) for e in es], out_dir / f"grid_{sc}.png"
            )
            if p:
                written.append(p)
        if loss:
            for e in es:
                p = loss_figure(
                    e["run_dir"], out_dir / f"loss_{sc}_{e['row']}.png", title=f"{sc}: {e['label']}"
                )
                if p:
                    written.append(p)
    return written
