"""The layout the official Mono4DGS-HDR code reads (LiuJF1226/Mono4DGS-HDR), as far as a clip needs.

Facts taken from its data loading (its preprocessing script and its saved-prior loader)::

    train/<name>.png     the alternating-exposure training frames its preprocessing reads; it
                         copies them into images/ of its workspace
    images/<name>.png    the training frames its optimisation reads (sorted by name)
    exposures.json       {"train_exp_num": number of distinct training exposures,
                          "train": {file name: log2 exposure time}, "test": {...},
                          "test_ne": {...}}
    train_exr/<n>.exr    linear HDR ground truth of the training frames (sorted like images/)
    test/<name>.png      test frames at an observed exposure ("test" of exposures.json)
    test_ne/<name>.png   test frames at a novel exposure ("test_ne")
    test_exr/<n>.exr     linear HDR ground truth of the test frames (sorted like test/)
    <mode>_depth/<name>.npz  depth per training frame (key "dep"), <mode> its depth model; a mode
                         it has no model for is read from the folder
    *_tap.npz            point tracks: "tracks" [T, N, 2 or 3] (x, y pixels), "visibility" [T, N]

It takes no camera input: the method estimates its cameras itself (bundle adjustment in its
preprocessing). What this project adds beside it (no other tool reads these):
`cameras_gt.json` (the clip's gt/cameras.json: ground truth, for evaluation), `test_levels/<level>/`
(every test frame at every observed and novel level) and m4dgs_clip.json (the source clip.json).
Frame files are named by their global frame index (00000.png); the official code only sorts
them."""

from __future__ import annotations

import math
from typing import Dict

from m4dgs.core.errors import InputError
from m4dgs.formats import field

TRAIN_DIR = "train"
IMAGES_DIR = "images"
EXPOSURES_FILE = "exposures.json"
TRAIN_EXR_DIR = "train_exr"
TEST_DIR = "test"
TEST_NE_DIR = "test_ne"
TEST_EXR_DIR = "test_exr"
DEPTH_SUFFIX = "_depth"
PRIOR_DEPTH_DIR = "prior_depth"  # the clip's depth prior: run the official code with dep_mode prior
TRACKS_SUFFIX = "_tap.npz"
PRIOR_TRACKS_FILE = "uniform_dep=prior_prior_tap.npz"
CAMERAS_GT_FILE = "cameras_gt.json"
TEST_LEVELS_DIR = "test_levels"


def exposures_json(
    train: Dict[str, float], test: Dict[str, float], test_ne: Dict[str, float], n_observed: int
) -> dict:
    """exposures.json from exposure times (relative units) per file name."""

    def log2(d):
        return {k: math.log2(v) for k, v in d.items()}

    return {
        "train_exp_num": int(n_observed),
        "train": log2(train),
        "test": log2(test),
        "test_ne": log2(test_ne),
    }


def exposure_times(d: dict, key: str, path) -> Dict[str, float]:
    """{file name: exposure time} of exposures.json's `key` ("train", "test", "test_ne")."""
    table = field(d, key, path, dict)
    out = {}
    for name, v in table.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"{path}: field '{key}.{name}': expected a log2 exposure, got {v!r}")
        out[name] = 2.0 ** float(v)
    return out
