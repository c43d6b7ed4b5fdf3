"""A run's learned camera response against the clip's true one: how far, whether the curve slid
along the exposure axis or bent, and where along the exposure range.

crf_error (eval.metrics.crf; every metrics.json has it) is one number: the mean |learned - true| in
8-bit codes over the exposures the training frames recorded. Two runs with the same crf_error can
differ in kind: a curve slid along log x (the HDR scale set wrong; the trainer anchors it only
softly, through the unit-exposure term) or a curve of another shape (e.g. steeper mid-tones: the
wrong contrast). This reads the learned tone mapper of each run folder and prints, per run:

- ``crf_error``: as in metrics.json;
- ``shift`` / ``crf_error_shifted``: the exposure shift (EV, shared by the channels) that fits the
  learned curve best to the true one, and the error left after it (eval.metrics.crf_error_shifted;
  s > 0: the learned curve is darker, it needs s EV more exposure for the same code);
- ``crf_error_per_channel_shift``: the error left with one shift per channel (a white balance);
- ``bands``: the signed learned - true error in codes over equal log2 bands of the recorded range,
  dark to bright, the mean over the channels (eval.metrics.crf_error_bands).

`m4dgs-eval crf RUN [RUN ...]` prints them as a table and can draw the curves (docs/eval.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from eval.experiments.run_files import resolve_clip_dir
from eval.experiments.runner import read_failure
from eval.metrics.crf import (
    CRF_ERROR_SAMPLES,
    crf_error,
    crf_error_bands,
    crf_error_shifted,
    curve_channel,
    observed_exposure_range,
)
from m4dgs.clip import Clip
from m4dgs.core.crf import get_crf
from m4dgs.core.errors import InputError

#: samples of the drawn curves (log2-uniform over the recorded range)
PLOT_SAMPLES = 200


def clip_ranges(clip: Clip):
    """(true CRF, per-channel recorded exposure ranges) of a clip, as crf_error uses them. Raises
    InputError when the clip has no true response (a real clip; Clip.open already rejects an
    unknown name) or no ground-truth HDR training frames."""
    if not clip.meta.crf:
        raise InputError(f"{clip.root / 'clip.json'}: field 'crf' is empty: no true response")
    f = get_crf(clip.meta.crf)
    if not (clip.has_gt and clip.has_gt_part("hdr") and clip.train_frames):
        raise InputError(f"{clip.root}: no ground-truth HDR training frames (gt/hdr)")
    frames = (clip.load_gt_hdr(g) for g in clip.train_frames)
    return f, observed_exposure_range(frames, clip.meta.exposures.train_dt, f)


def response_report(
    curve, clip: Clip, bands: int = 6, samples: int = CRF_ERROR_SAMPLES, ranges=None
) -> Dict:
    """The figures of one learned response against clip's true one.

    Args:
        curve: log2 exposures [n] (numpy) -> LDR values [n, C] or [n] (torch or numpy).
        clip: the clip whose true response (clip.json "crf") and recorded ranges are the reference.
        bands: how many equal log2 bands the signed error is given in. samples: log2-uniform
        samples per channel.
        ranges: the clip's recorded ranges when already known (clip_ranges), else computed.
    Returns:
        {"clip_name", "crf", "crf_error", "per_channel", "shift", "crf_error_shifted",
        "per_channel_shift", "crf_error_per_channel_shift", "bands", "ranges_log2", "plot"}; "plot"
        holds the channel-mean learned and true curves and their signed difference (codes) on
        PLOT_SAMPLES log2 x over the range every channel recorded.
    """
    if ranges is None:
        f, ranges = clip_ranges(clip)
    else:
        f = get_crf(clip.meta.crf)
    if all(r is None for r in ranges):
        raise InputError(f"{clip.root}: no channel recorded an unclipped exposure (gt/hdr)")
    err = crf_error(curve, f, ranges, n=samples)
    sh = crf_error_shifted(curve, f, ranges, n=samples)
    bd = crf_error_bands(curve, f, ranges, bands=bands, n=samples)
    have = [(c, r) for c, r in enumerate(ranges) if r is not None]
    lo = max(np.log2(r[0]) for _, r in have)
    hi = min(np.log2(r[1]) for _, r in have)
    if not hi > lo:  # disjoint channel ranges: draw over their union
        lo, hi = min(np.log2(r[0]) for _, r in have), max(np.log2(r[1]) for _, r in have)
    z = np.linspace(lo, hi, PLOT_SAMPLES)
    learned = np.mean([curve_channel(curve, z, c) for c, _ in have], axis=0)
    true = np.mean([np.asarray(f.channel(c)(np.exp2(z)), np.float64) for c, _ in have], axis=0)
    return {
        "clip_name": clip.meta.name,
        "crf": str(clip.meta.crf),
        "crf_error": err["crf_error"],
        "per_channel": err["per_channel"],
        "shift": sh["shift"],
        "crf_error_shifted": sh["crf_error"],
        "per_channel_shift": sh["per_channel_shift"],
        "crf_error_per_channel_shift": sh["crf_error_per_channel_shift"],
        "bands": bd["bands"],
        "ranges_log2": [
            None if r is None else [float(np.log2(r[0])), float(np.log2(r[1]))] for r in ranges
        ],
        "plot": {
            "log2_x": z.tolist(),
            "learned": learned.tolist(),
            "true": true.tolist(),
            "difference_codes": (255.0 * (learned - true)).tolist(),
        },
    }


def run_response(run_dir, clip: Optional[Clip] = None, bands: int = 6, ranges=None) -> Dict:
    """response_report of a run folder's learned tone mapper (model/final.pt, loaded on the CPU)
    with "run" added. clip: default the run's (run.json "clip"). Raises InputError for a run
    without a final model (e.g. a failed run, named with its recorded error) or a clip without a
    true response or ground truth."""
    import torch

    from m4dgs.model.trained import load_model

    run_dir = Path(run_dir)
    clip = clip if clip is not None else Clip.open(resolve_clip_dir(run_dir))
    if not (run_dir / "model" / "final.pt").exists():
        failed = read_failure(run_dir)
        if failed is not None:
            raise InputError(f"{run_dir}: no final model; its last attempt failed: {failed}")
        raise InputError(f"{run_dir / 'model' / 'final.pt'}: missing (an unfinished run?)")
    model = load_model(run_dir, device="cpu", clip=clip)

    def curve(log2_x):
        with torch.no_grad():
            return model.tonemap_curve(torch.tensor(np.asarray(log2_x), dtype=torch.float32))

    out = {"run": str(run_dir)}
    out.update(response_report(curve, clip, bands=bands, ranges=ranges))
    return out


def _f(v, fmt):
    return "" if v is None else format(v, fmt)


def format_responses(results: List[Dict]) -> str:
    """A Markdown table of run_response results, one row per run."""
    n_bands = max((len(r["bands"]) for r in results if r.get("bands")), default=0)
    lines = [
        "| run | clip | true CRF | CRF error (codes) | best shift (EV) | error after the shift | "
        "after a shift per channel | signed error per band, dark -> bright (codes) |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in results:
        bands = " ".join(_f(v, "+.2f") for v in (r["bands"] or []))
        lines.append(
            f"| {r['run']} | {r['clip_name']} | {r['crf']} | {_f(r['crf_error'], '.2f')} | "
            f"{r['shift']:+.2f} | {_f(r['crf_error_shifted'], '.2f')} | "
            f"{_f(r['crf_error_per_channel_shift'], '.2f')} | {bands} |"
        )
    note = (
        f"\nBands: {n_bands} equal log2 intervals of each channel's recorded range (the "
        "exposures the training frames recorded unclipped), the signed mean of learned - true, "
        "then the mean over the channels. Shift > 0: the learned curve needs that many EV more "
        "exposure for the same code (darker).\n"
    )
    return "\n".join(lines) + "\n" + note


def plot_responses(results: List[Dict], path) -> Path:
    """Two panels, one line per run: the learned response (channel mean) over the true one, and
    their signed difference in 8-bit codes, against log2 exposure. Written atomically as PNG."""
    from eval.figures import pyplot, save_png

    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    first = results[0]["plot"]
    a.plot(first["log2_x"], first["true"], color="black", lw=2.0, label="true")
    for r in results:
        p = r["plot"]
        label = Path(r["run"]).name
        (line,) = a.plot(p["log2_x"], p["learned"], lw=1.0, label=label)
        b.plot(p["log2_x"], p["difference_codes"], lw=1.0, color=line.get_color(), label=label)
    b.axhline(0.0, color="black", lw=0.8)
    a.set_xlabel("log2 exposure (H dt)")
    a.set_ylabel("LDR value")
    a.set_title("learned response (mean over channels)")
    b.set_xlabel("log2 exposure (H dt)")
    b.set_ylabel("learned - true (8-bit codes)")
    b.set_title("signed difference over the recorded range")
    a.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    save_png(fig, path)
    return path
