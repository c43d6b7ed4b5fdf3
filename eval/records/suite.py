"""Experiment suites (eval/suites/<group>/<name>.yaml, called by <name>): which clips, which trained
variants, which tables.

A suite file names

- ``scenes``: the benchgen scene suite (``syn-exp-3``, ``tiny``, or a path to a benchgen suite
  YAML), or ``{clips: FOLDER}``: clips that already exist (your own, from ``m4dgs import-clip`` or
  ``benchgen from-hdr``), one scene per subfolder holding a clip.json, used as they are (FOLDER
  relative to the suite file; no clip settings beyond the default then);
- ``clips``: named clip settings (optional; default one setting ``default`` = the scene suite as it
  is). A setting may
  change the exposure ``schedule`` (alternating | random-order | random-values |
  random-values-banded), the prior
  ``priors`` profile
  (oracle | realistic | harsh), the ``observed`` / ``novel`` levels, the ``seed`` and the camera
  response ``crf``
  (a name of ``m4dgs.core.crf.CLIP_CRFS``; default the paper's ``hdrnerf``);
- ``rows``: the table rows, each ``{name, label, variant, overrides, clip}``: ``name`` is the run
  folder (default: the variant), ``label`` the text in the table (default: the name), ``variant`` a
  name of ``m4dgs.training.variants.VARIANTS`` (default ``full``), ``overrides`` extra dotted config
  overrides (e.g. ``{"exposure.perturb_ev": 0.5}``), ``clip`` the clip setting (default
  ``default``); or ``{name, label, calibration, clip}``: a calibration row (``calibration`` one of
  ``eval.calibration.ROWS``: ``copy-nearest``, ``flow-merge``, ``dibr``), a 2D prediction that
  reconstructs nothing in 3D, made and scored like another method's frames instead of trained
  (eval.experiments.calibration_rows; no variant or overrides);
- ``tables``: each ``{title, columns, paper}`` with ``columns`` a layout name of ``LAYOUTS``
  (``paper`` is ``eval.tables.paper_table_spec``) or a list of metric keys of ``metric_columns()``,
  and ``paper`` (optional) a table of ``eval/paper_values.yaml`` whose values are shown beside ours
  with the direction agreement;
- ``reference``: the row every other row is compared with (paired differences; default the row named
  ``full``).

The job list is (clip setting, scene, row). Clips are made once per distinct clip setting:
``OUT/clips/<setting id>/<scene>`` where the setting id is the scene suite's name, followed by the
non-default values (``syn-exp-3``, ``syn-exp-3-random-order``, ``syn-exp-3-priors-oracle``), so
suites that use the same clips share them. Runs go to ``OUT/runs/<suite>/<scene>/<row name>``
(trainer seed 0) and ``OUT/runs/<suite>/<scene>/<row name>-seed-<n>`` (seed n > 0, ``eval run
--seeds``), so row names may not end in ``-seed-<n>``. Use one OUT per preset."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Dict, List, Optional

from benchgen.suite import load_suite
from eval.calibration import ROWS as CALIBRATION_ROWS
from eval.calibration import VARIANT as CALIBRATION_VARIANT
from eval.paper import load_paper_values
from eval.tables import Column, TableSpec, paper_table_spec
from m4dgs.core import io as mio
from m4dgs.core.checks import is_integer, is_number, unknown_keys
from m4dgs.core.errors import InputError

SCHEDULES = (
    "alternating",
    "random-order",
    "random-values",
    "random-values-banded",
)  # benchgen.exposure's
# benchgen.priors.PROFILES (a test keeps the two equal; eval does not import benchgen's numerics)
PRIOR_PROFILES = (
    "oracle",
    "realistic",
    "harsh",
    "realistic-exact-depth",
    "realistic-exact-motion",
)
DEFAULT_PRIORS = "realistic"
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
_SEED_SUFFIX_RE = re.compile(r"-seed-[0-9]+$")
# the keys a suite file may use, per level
SUITE_KEYS = ("name", "description", "scenes", "clips", "rows", "tables", "reference")
CLIP_KEYS = ("schedule", "priors", "observed", "novel", "seed", "crf")
ROW_KEYS = ("name", "label", "variant", "overrides", "clip", "calibration")
TABLE_KEYS = ("title", "columns", "paper")


class SuiteError(InputError):
    """A malformed eval suite file; the message names the file and the key."""

    def __init__(self, path, key: str, problem: str):
        self._parts = (str(path), key, problem)
        super().__init__(f"{path}: '{key}': {problem}")

    def __reduce__(self):  # pickles (a worker process's error reaches its driver)
        return (type(self), self._parts)


@dataclass(frozen=True)
class ClipSetting:
    """How the clips of one setting are made (None = the scene suite's value)."""

    key: str
    schedule: Optional[str] = None
    priors: str = DEFAULT_PRIORS
    observed: Optional[tuple] = None
    novel: Optional[tuple] = None
    seed: int = 0
    crf: Optional[str] = (
        None  # camera response (m4dgs.core.crf.CLIP_CRFS); None = the paper's hdrnerf
    )

    def setting_id(self, scene_suite: str) -> str:
        """Folder name under OUT/clips: the scene suite plus every non-default value (shared across
        suites)."""
        parts = [Path(scene_suite).stem]
        if self.schedule not in (None, "alternating"):
            parts.append(self.schedule)
        if self.priors != DEFAULT_PRIORS:
            parts.append(f"priors-{self.priors}")
        if self.observed is not None:
            parts.append("obs-" + "_".join(f"{v:g}" for v in self.observed))
        if self.novel is not None:
            parts.append("novel-" + ("_".join(f"{v:g}" for v in self.novel) or "none"))
        if self.seed != 0:
            parts.append(f"seed-{self.seed}")
        if self.crf not in (None, "hdrnerf"):
            parts.append(f"crf-{self.crf}")
        return "-".join(parts)


@dataclass(frozen=True)
class Row:
    """One table row = one trained variant on one clip setting."""

    name: str
    label: str
    variant: str = "full"
    overrides: Dict[str, Any] = field(default_factory=dict)
    clip: str = "default"
    # a calibration row (eval.calibration.ROWS): a 2D prediction made and scored instead of a
    # trained run; variant is then "calibration"
    calibration: Optional[str] = None


@dataclass
class TableDef:
    title: str
    columns: Any  # layout name (str) or list of metric keys
    paper: Optional[str] = (
        None  # key of eval/paper_values.yaml: "Paper" and agreement columns (eval.paper)
    )


@dataclass
class EvalSuite:
    name: str
    description: str
    scenes: str  # benchgen scene suite name or path
    clips: Dict[str, ClipSetting]
    rows: List[Row]
    tables: List[TableDef]
    path: Path = Path()
    reference: Optional[str] = (
        None  # row of the paired differences in the tables (default: the row named "full")
    )
    # `scenes: {clips: FOLDER}`: existing clips, one per subfolder, used instead of made ones
    clip_folder: Optional[Path] = None

    def row(self, name: str) -> Row:
        for r in self.rows:
            if r.name == name:
                return r
        raise KeyError(
            f"suite {self.name!r} has no row {name!r} (rows: {[r.name for r in self.rows]})"
        )

    @property
    def variants(self) -> List[str]:
        """The trained variants of the rows (calibration rows train nothing)."""
        return sorted({r.variant for r in self.rows if r.calibration is None})


# --------------------------------------------------------------------------------------------------
# table columns
# --------------------------------------------------------------------------------------------------
def metric_columns() -> Dict[str, Column]:
    """Every metrics.json key a table may show -> eval.tables.Column (header, direction, format,
    group, convention).

    The paper's main-table columns come from eval.tables.paper_table_spec (one definition for
    both)."""
    cols = {c.key: c for c in paper_table_spec().columns}
    extra = [
        Column("ldr_train_psnr", "PSNR", True, ".2f", "LDR-OE (train)", "psnr"),
        Column("ldr_train_ssim", "SSIM", True, ".4f", "LDR-OE (train)", "ssim"),
        Column("ldr_train_lpips", "LPIPS", False, ".4f", "LDR-OE (train)", None),
        Column("hdr_train_psnr", "PSNR", True, ".2f", "HDR (train)", "hdr_mu_law"),
        Column("hdr_train_ssim", "SSIM", True, ".4f", "HDR (train)", "ssim"),
        Column("hdr_psnr_ownmax", "PSNR own-max", True, ".2f", "HDR", "hdr_mu_law_own"),
        Column("pu21_psnr", "PU21-PSNR", True, ".2f", "HDR", "pu21"),
        Column("hdr_flip", "FLIP", False, ".4f", "HDR", "hdr_flip"),
        Column("hdr_t_std", "T-std", False, ".4f", "HDR", "hdr_t_std"),
        Column("hdr_tae_interior", "TAE interior", False, ".4f", "HDR", "hdr_tae_interior"),
        Column("hdr_tce", "TCE", False, ".4f", "HDR", "hdr_tce"),
        Column("hdr_tae_train_test", "TAE (train+test)", False, ".4f", "HDR", "hdr_tae_dis_flow"),
        Column("dyn_ldr_psnr", "PSNR", True, ".2f", "Dynamic LDR-OE", "masked"),
        Column("dyn_hdr_psnr", "PSNR", True, ".2f", "Dynamic HDR", "masked"),
        Column("crf_rmse", "CRF RMSE", False, ".4f", None, "crf_rmse"),
        Column("crf_error", "CRF err (codes)", False, ".2f", None, "crf_error"),
        Column("ate", "ATE", False, ".4f", "Cameras", "ate"),
        Column("rpe_trans", "RPE-t", False, ".4f", "Cameras", "rpe"),
        Column("rpe_rot", "RPE-r (deg)", False, ".3f", "Cameras", "rpe"),
        Column("ate_ba", "ATE (BA)", False, ".4f", "Cameras", "ate"),
        Column("depth_absrel", "Depth AbsRel", False, ".4f", None, "depth_absrel_clip"),
        Column("mask_precision", "precision", True, ".3f", "Dynamic masks", "dyn_masks"),
        Column("mask_recall", "recall", True, ".3f", "Dynamic masks", "dyn_masks"),
        Column("mask_iou", "IoU", True, ".3f", "Dynamic masks", "dyn_masks"),
        Column("track_epe", "EPE (px)", False, ".2f", "Tracks", "track"),
        Column("track_epe_median", "median EPE (px)", False, ".2f", "Tracks", "track"),
        Column("track_delta_avg", "<delta avg", True, ".3f", "Tracks", "track"),
        Column("train_minutes", "Train (min)", False, ".1f", None, None),
        Column("fps", "FPS", True, ".1f", None, "fps"),
        Column("fps_864x480", "FPS@864x480", True, ".1f", None, "fps"),
        Column("num_gaussians", "#Gaussians", False, ".0f", None, None),
        Column("peak_memory_mib", "Peak MiB", False, ".0f", None, "peak_mem"),
        # the test frames' HDR over the whole scene and its highlights (eval.metrics.scene_hdr)
        Column("hdr_psnr_p99", "PSNR p99", True, ".2f", "HDR", "hdr_psnr_p99"),
        Column("highlight_stops", "highlight err (stops)", False, ".3f", "HDR", "highlight_stops"),
        # the peak ratio in stops (log2): means, intervals and differences of log ratios
        Column(
            "highlight_peak_ratio",
            "peak (stops)",
            False,
            ".2f",
            "HDR",
            "highlight_peak_stops",
            0.0,
            log2=True,
        ),
        Column(
            "highlight_peak_ratio_resolved",
            "peak, resolved (stops)",
            False,
            ".2f",
            "HDR",
            "highlight_peak_resolved_stops",
            0.0,
            log2=True,
        ),
        # held-out views (eval.experiments.view_scores): means over the views
        Column("nv_ldr_oe_psnr", "PSNR", True, ".2f", "Views LDR-OE", "nv_views"),
        Column("nv_ldr_oe_mpsnr", "mPSNR", True, ".2f", "Views LDR-OE", "nv_masked"),
        Column("nv_ldr_oe_ssim", "SSIM", True, ".4f", "Views LDR-OE", "nv_views"),
        Column("nv_ldr_oe_mssim", "mSSIM", True, ".4f", "Views LDR-OE", "nv_masked"),
        Column("nv_ldr_ne_psnr", "PSNR", True, ".2f", "Views LDR-NE", "nv_views"),
        Column("nv_ldr_ne_mpsnr", "mPSNR", True, ".2f", "Views LDR-NE", "nv_masked"),
        Column("nv_hdr_psnr", "PSNR", True, ".2f", "Views HDR", "hdr_mu_law"),
        Column("nv_hdr_mpsnr", "mPSNR", True, ".2f", "Views HDR", "nv_masked"),
        Column("nv_hdr_psnr_p99", "PSNR p99", True, ".2f", "Views HDR", "hdr_psnr_p99"),
        Column("nv_ldr_oe_dyn_mpsnr", "dyn mPSNR", True, ".2f", "Views LDR-OE", "nv_dynamic"),
        Column("nv_hdr_dyn_mpsnr", "dyn mPSNR", True, ".2f", "Views HDR", "nv_dynamic"),
        *[
            Column(f"nv_{v}_ldr_oe_mpsnr", f"{v} mPSNR", True, ".2f", "Views LDR-OE", "nv_masked")
            for v in DEFAULT_VIEWS
        ],
        # properties of the clip, the same for every row of a scene (context: no arrow, no bold):
        # the views' co-visible fraction and the camera motion (clip.json gt.camera_motion)
        Column("nv_covisible", "co-visible", True, ".3f", "Views", "nv_masked", context=True),
        Column(
            "camera_deg_s", "camera deg/s", True, ".1f", "Motion", "camera_motion", context=True
        ),
        Column("scene_deg_s", "scene deg/s", True, ".1f", "Motion", "camera_motion", context=True),
        Column("emf", "EMF", True, ".2f", "Motion", "camera_motion", context=True),
    ]
    cols.update({c.key: c for c in extra})
    return cols


#: benchgen's default held-out views (benchgen.spec), whose per-view LDR-OE mPSNR the tables show
DEFAULT_VIEWS = ("small", "medium", "large")


LAYOUTS: Dict[str, List[str]] = {
    # the paper's main synthetic table (Table 1 / appendix exposure tables):
    # eval.tables.paper_table_spec
    "paper": [
        "ldr_oe_psnr",
        "ldr_oe_ssim",
        "ldr_oe_lpips",
        "ldr_ne_psnr",
        "ldr_ne_ssim",
        "ldr_ne_lpips",
        "hdr_psnr",
        "hdr_ssim",
        "hdr_lpips",
        "hdr_tae",
    ],
    # the paper's ablation tables (rows a-f, control points): "all metrics PSNR except HDR-TAE"
    "ablation": ["ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae"],
    # exposure studies (schedules / perturbation): the ablation layout plus the learned-CRF error
    "exposure": ["ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae", "crf_rmse", "crf_error"],
    # camera-response study (suite crf): image metrics plus the learned-vs-true response over the
    # observed range
    "crf": [
        "ldr_oe_psnr",
        "ldr_ne_psnr",
        "hdr_psnr",
        "hdr_ssim",
        "hdr_tae",
        "crf_error",
        "crf_rmse",
    ],
    # the GFlow comparison (appendix): training frames
    "train": [
        "ldr_train_psnr",
        "ldr_train_ssim",
        "ldr_train_lpips",
        "hdr_train_psnr",
        "hdr_train_ssim",
        "hdr_tae",
    ],
    # beyond the paper
    "geometry": [
        "ate",
        "rpe_trans",
        "rpe_rot",
        "ate_ba",
        "depth_absrel",
        "track_epe",
        "track_epe_median",
        "track_delta_avg",
        "mask_recall",
        "mask_iou",
    ],
    "hdr-extra": [
        "hdr_psnr_ownmax",
        "pu21_psnr",
        "hdr_flip",
        "hdr_t_std",
        "hdr_tae_interior",
        "hdr_tce",
        "dyn_ldr_psnr",
        "dyn_hdr_psnr",
        "crf_rmse",
        "crf_error",
    ],
    "cost": ["train_minutes", "fps", "fps_864x480", "num_gaussians", "peak_memory_mib"],
    # held-out views (benchgen clips with gt/views/): the means over the views, each default
    # view's LDR-OE mPSNR, the co-visible fraction and the clip's effective multi-view factor
    "views": [
        "nv_ldr_oe_psnr",
        "nv_ldr_oe_mpsnr",
        "nv_ldr_oe_ssim",
        "nv_ldr_oe_mssim",
        "nv_ldr_ne_psnr",
        "nv_ldr_ne_mpsnr",
        "nv_hdr_psnr",
        "nv_hdr_mpsnr",
        "nv_hdr_psnr_p99",
        "nv_ldr_oe_dyn_mpsnr",
        "nv_hdr_dyn_mpsnr",
        *[f"nv_{v}_ldr_oe_mpsnr" for v in DEFAULT_VIEWS],
        "nv_covisible",
        "emf",
    ],
    # HDR over the whole scene beside the paper's GT-max convention
    "hdr-scene": [
        "hdr_psnr",
        "hdr_psnr_p99",
        "pu21_psnr",
        "highlight_stops",
        "highlight_peak_ratio",
    ],
}


def table_spec(
    table: TableDef,
    *,
    lpips_available: bool = True,
    ldr_convention: str = "ldr_float",
    methods: Optional[List[str]] = None,
):
    """eval.tables.TableSpec of a suite table (the `paper` layout is paper_table_spec itself)."""
    lp_key = "lpips" if lpips_available else "lpips_na"
    if table.columns == "paper":
        spec = paper_table_spec(
            table.title, ldr_convention=ldr_convention, lpips_available=lpips_available
        )
        spec.methods = methods
        return spec
    keys = LAYOUTS[table.columns] if isinstance(table.columns, str) else list(table.columns)
    reg = metric_columns()
    cols = []
    for k in keys:
        c = reg[k]
        if k.endswith("_lpips"):
            c = dataclasses.replace(c, convention=lp_key)
        cols.append(c)
    conv = [ldr_convention] if any(k.startswith(("ldr_", "dyn_ldr")) for k in keys) else []
    return TableSpec(columns=cols, title=table.title, conventions=conv, methods=methods)


# --------------------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------------------
def suites_dir() -> Path:
    """Folder of the shipped eval suites (package data of `eval`): eval/suites/<group>/<name>.yaml,
    the groups paper/, controls/ and extra/."""
    return Path(str(resources.files("eval"))) / "suites"


def builtin_suite_paths() -> Dict[str, Path]:
    """Shipped suite name -> its file, from every subfolder of suites_dir(). A name is the file's
    stem, so two files with the same name anywhere under it are a SuiteError naming both."""
    out: Dict[str, Path] = {}
    for p in sorted(suites_dir().rglob("*.yaml")):
        if p.stem in out:
            raise SuiteError(
                p, "<suite>", f"two shipped suites are called {p.stem!r}: {out[p.stem]} and {p}"
            )
        out[p.stem] = p
    return out


def builtin_suites() -> List[str]:
    """Names of the shipped suites (sorted), whatever subfolder of eval/suites holds them."""
    return sorted(builtin_suite_paths())


def builtin_suite_path(name: str) -> Optional[Path]:
    """The file of the shipped suite called `name`, or None."""
    return builtin_suite_paths().get(name)


def is_builtin_suite_file(path) -> bool:
    """Whether `path` is the file of a shipped suite (then it is called by its bare name)."""
    p = Path(str(path)).resolve()
    return any(p == q.resolve() for q in builtin_suite_paths().values())


def suite_display_path(path) -> str:
    """A suite file's path for pages and messages: eval/suites/<group>/<name>.yaml for a shipped
    suite (the path in the repository), else the path as given."""
    p = Path(str(path))
    root = suites_dir().resolve()
    try:
        rel = p.resolve().relative_to(root)
    except ValueError:
        return p.as_posix()
    return (Path("eval/suites") / rel).as_posix()


def find_eval_suite(name_or_path) -> Path:
    """An eval experiment suite: a suite YAML file by path, or the bare name of a shipped one
    (eval/suites/<group>/<name>.yaml). Raises SuiteError naming the shipped suites."""
    p = Path(str(name_or_path))
    if p.is_file():
        return p
    path = builtin_suite_path(str(name_or_path))
    if path is None:
        raise SuiteError(
            name_or_path, "<suite>", f"not a suite file nor a built-in suite {builtin_suites()}"
        )
    return path


def _levels(v, path, key):
    if v is None:
        return None
    if not isinstance(v, list) or not all(is_number(x) and x > 0 for x in v):
        raise SuiteError(path, key, f"expected a list of positive numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _parse_clip(key: str, d: Any, path) -> ClipSetting:
    if d is None:
        d = {}
    if not isinstance(d, dict):
        raise SuiteError(path, f"clips.{key}", "expected a mapping")
    unknown = sorted(unknown_keys(d, CLIP_KEYS))
    if unknown:
        raise SuiteError(path, f"clips.{key}.{unknown[0]}", f"unknown key ({', '.join(CLIP_KEYS)})")
    from m4dgs.core.crf import CLIP_CRFS  # deferred: m4dgs.core.crf imports torch

    crf = d.get("crf")
    if crf is not None and crf not in CLIP_CRFS:
        raise SuiteError(path, f"clips.{key}.crf", f"expected one of {CLIP_CRFS}, got {crf!r}")
    sched = d.get("schedule")
    if sched is not None and sched not in SCHEDULES:
        raise SuiteError(
            path, f"clips.{key}.schedule", f"expected one of {SCHEDULES}, got {sched!r}"
        )
    pri = d.get("priors", DEFAULT_PRIORS)
    if pri not in PRIOR_PROFILES:
        raise SuiteError(
            path, f"clips.{key}.priors", f"expected one of {PRIOR_PROFILES}, got {pri!r}"
        )
    seed = d.get("seed", 0)
    if not is_integer(seed):
        raise SuiteError(path, f"clips.{key}.seed", f"expected an integer, got {seed!r}")
    return ClipSetting(
        key,
        sched,
        pri,
        _levels(d.get("observed"), path, f"clips.{key}.observed"),
        _levels(d.get("novel"), path, f"clips.{key}.novel"),
        seed,
        crf,
    )


def parse_suite(d: dict, path="<suite>") -> EvalSuite:
    """Validate a suite mapping (as read from YAML) -> EvalSuite. Raises SuiteError naming the
    key."""
    if not isinstance(d, dict):
        raise SuiteError(path, "<root>", "expected a mapping")
    unknown = sorted(unknown_keys(d, SUITE_KEYS))
    if unknown:
        raise SuiteError(path, unknown[0], "unknown key")
    for k in ("name", "scenes", "rows"):
        if k not in d:
            raise SuiteError(path, k, "missing")
    name = str(d["name"])
    if not _NAME_RE.match(name):
        raise SuiteError(path, "name", f"expected a folder-safe name, got {name!r}")
    clips_d = d.get("clips") or {"default": {}}
    if not isinstance(clips_d, dict):
        raise SuiteError(path, "clips", "expected a mapping of setting name -> settings")
    clips = {str(k): _parse_clip(str(k), v, path) for k, v in clips_d.items()}
    scenes, clip_folder = d["scenes"], None
    if isinstance(scenes, dict):
        if set(scenes) != {"clips"} or not isinstance(scenes["clips"], str):
            raise SuiteError(path, "scenes", "expected a scene suite name or {clips: FOLDER}")
        clip_folder = Path(scenes["clips"]).expanduser()
        if not clip_folder.is_absolute():
            clip_folder = Path(str(path)).resolve().parent / clip_folder
        made = [k for k, c in clips.items() if c != ClipSetting(k)]
        if made:
            raise SuiteError(
                path,
                f"clips.{made[0]}",
                "a setting of how clips are made, but scenes names existing clips ({clips: ...})",
            )
        scenes = clip_folder.name
    if not isinstance(d["rows"], list) or not d["rows"]:
        raise SuiteError(path, "rows", "expected a non-empty list")
    rows, seen = [], set()
    for i, r in enumerate(d["rows"]):
        if not isinstance(r, dict):
            raise SuiteError(path, f"rows[{i}]", "expected a mapping")
        bad = sorted(unknown_keys(r, ROW_KEYS))
        if bad:
            raise SuiteError(path, f"rows[{i}].{bad[0]}", f"unknown key ({', '.join(ROW_KEYS)})")
        cal = r.get("calibration")
        if cal is not None:
            if cal not in CALIBRATION_ROWS:
                raise SuiteError(
                    path,
                    f"rows[{i}].calibration",
                    f"unknown calibration row {cal!r} (known: {', '.join(CALIBRATION_ROWS)})",
                )
            both = [k for k in ("variant", "overrides") if k in r]
            if both:
                raise SuiteError(
                    path,
                    f"rows[{i}].{both[0]}",
                    "a calibration row trains nothing: it takes no variant or overrides",
                )
        variant = CALIBRATION_VARIANT if cal is not None else str(r.get("variant", "full"))
        rname = str(r.get("name", cal if cal is not None else variant))
        if not _NAME_RE.match(rname):
            raise SuiteError(path, f"rows[{i}].name", f"expected a folder-safe name, got {rname!r}")
        if rname in seen:
            raise SuiteError(path, f"rows[{i}].name", f"duplicate row name {rname!r}")
        # reserved for the run folders of trainer seeds > 0 (eval.experiments.runner)
        if _SEED_SUFFIX_RE.search(rname):
            raise SuiteError(
                path, f"rows[{i}].name", f"a row name may not end in '-seed-<n>', got {rname!r}"
            )
        seen.add(rname)
        ov = r.get("overrides") or {}
        if not isinstance(ov, dict):
            raise SuiteError(
                path, f"rows[{i}].overrides", "expected a mapping of dotted config keys -> values"
            )
        clip = str(r.get("clip", "default"))
        if clip not in clips:
            raise SuiteError(
                path, f"rows[{i}].clip", f"unknown clip setting {clip!r} (have {sorted(clips)})"
            )
        rows.append(Row(rname, str(r.get("label", rname)), variant, dict(ov), clip, cal))
    tables = []
    for i, t in enumerate(
        d.get("tables") or [{"title": d.get("description", name), "columns": "paper"}]
    ):
        if not isinstance(t, dict) or "columns" not in t:
            raise SuiteError(path, f"tables[{i}]", "expected {title, columns}")
        bad = sorted(unknown_keys(t, TABLE_KEYS))
        if bad:
            raise SuiteError(
                path, f"tables[{i}].{bad[0]}", f"unknown key ({', '.join(TABLE_KEYS)})"
            )
        if t.get("paper") is not None:
            known = load_paper_values()
            if t["paper"] not in known:
                raise SuiteError(
                    path,
                    f"tables[{i}].paper",
                    f"unknown paper table {t['paper']!r} (have {sorted(known)})",
                )
        cols = t["columns"]
        if isinstance(cols, str):
            if cols not in LAYOUTS:
                raise SuiteError(
                    path,
                    f"tables[{i}].columns",
                    f"unknown layout {cols!r} (have {sorted(LAYOUTS)})",
                )
        elif isinstance(cols, list):
            reg = metric_columns()
            for k in cols:
                if k not in reg:
                    raise SuiteError(path, f"tables[{i}].columns", f"unknown metric column {k!r}")
        else:
            raise SuiteError(
                path, f"tables[{i}].columns", "expected a layout name or a list of metric keys"
            )
        tables.append(
            TableDef(
                str(t.get("title", name)), cols, None if t.get("paper") is None else str(t["paper"])
            )
        )
    reference = d.get("reference", "full" if "full" in seen else None)
    if reference is not None and str(reference) not in seen:
        raise SuiteError(path, "reference", f"not a row name: {reference!r} (rows: {sorted(seen)})")
    return EvalSuite(
        name,
        str(d.get("description", "")),
        str(scenes),
        clips,
        rows,
        tables,
        Path(str(path)),
        None if reference is None else str(reference),
        clip_folder,
    )


def load_eval_suite(name_or_path) -> EvalSuite:
    """Load a built-in suite by its bare name (eval/suites/<group>/<name>.yaml) or any suite file by
    path."""
    path = find_eval_suite(name_or_path)
    return parse_suite(mio.read_yaml(path), path)


def scene_suite_names(suite: EvalSuite) -> List[str]:
    """Scene names of the suite's benchgen scene suite, or the clip subfolders of its clip folder
    (sorted)."""
    if suite.clip_folder is None:
        return load_suite(suite.scenes).scene_names
    folder = suite.clip_folder
    names = (
        sorted(p.name for p in folder.iterdir() if (p / "clip.json").is_file())
        if folder.is_dir()
        else []
    )
    if not names:
        raise SuiteError(
            suite.path, "scenes.clips", f"{folder}: no clip folders (subfolders with a clip.json)"
        )
    return names


def known_variants() -> Optional[List[str]]:
    """Names in m4dgs.training.variants.VARIANTS, or None while that module does not exist yet."""
    try:
        # the trainer's variant registry: heavy (the whole trainer) and optional here
        from m4dgs.training.variants import VARIANTS
    except ImportError:
        return None
    return sorted(VARIANTS)


def check_variants(suite: EvalSuite) -> List[str]:
    """Variant names of the suite unknown to m4dgs.training.variants ([] when all are known or the
    module is missing)."""
    known = known_variants()
    if known is None:
        return []
    return [v for v in suite.variants if v not in known]
