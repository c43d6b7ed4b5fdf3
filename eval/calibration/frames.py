"""A calibration row's prediction folder, in the layout `m4dgs-eval score-frames` reads
(eval.experiments.frames: DIR/test/hdr/<g>.exr and DIR/test/ldr/<level>/<g>.png at every observed
and novel level; for a clip with held-out views the same images again as
DIR/views/<view>/hdr/<g>.exr and DIR/views/<view>/ldr/<level>/<g>.png, since a 2D row predicts the
same image whatever the viewpoint), so that it is scored exactly like another method's frames:

    m4dgs-eval calibration CLIP ROW --out OUT      # ROW: copy-nearest | flow-merge (| dibr)
    m4dgs-eval score-frames --clip CLIP --pred OUT --name ROW

The response is estimated from the clip's training frames (eval.calibration.predict.response_of)
and written beside the frames as response.json (g per channel and code, natural log exposure), so
that the row's LDR frames are the row's own response of its HDR, as a method's are its tone
mapper's."""

from __future__ import annotations

from pathlib import Path

from m4dgs.clip import frame_name, level_name
from m4dgs.core import io as mio

from . import TEMPORAL_ROWS as ROWS
from .predict import ClipFrames, ldr_at, predict, response_of


def response_record(row: str, g_resp) -> dict:
    """response.json of a calibration row: the row, how the response was estimated, and g (natural
    log exposure per channel [3] and code [256])."""
    return {
        "row": row,
        "method": "Debevec-Malik least squares on quantile samples of bracketed training "
        "frames, anchored at clip.json unit_exposure_value (eval.calibration.response)",
        "g": g_resp.tolist(),
    }


def write_prediction(clip, out, row: str) -> Path:
    """Write calibration row `row`'s predictions of every test frame of `clip` (an m4dgs Clip)
    into the folder `out`; returns it."""
    if row not in ROWS:
        raise ValueError(f"unknown calibration row {row!r}; known: {', '.join(ROWS)}")
    out = Path(out)
    cf = ClipFrames.of(clip)
    g_resp = response_of(cf)
    levels = list(clip.meta.exposures.observed) + list(clip.meta.exposures.novel)
    # a 2D row has no notion of viewpoint: at a held-out view it predicts what it predicts at the
    # view's test frame (the dibr row is the one that moves the camera)
    roots = [out / "test"] + [out / "views" / v for v in clip.view_names()]
    for g, hdr in predict(cf, clip.test_frames, row, g_resp).items():
        for root in roots:
            mio.write_exr(root / "hdr" / frame_name(g, "exr"), hdr)
        for lv in clip.meta.test_levels_of(g) if clip.meta.exposures.test_dt else levels:
            ldr = ldr_at(hdr, float(lv), g_resp)
            for root in roots:
                mio.write_png(root / "ldr" / level_name(lv) / frame_name(g, "png"), ldr)
    mio.write_json(out / "response.json", response_record(row, g_resp))
    return out
