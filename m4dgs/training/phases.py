"""Sharing identical trainer phases between the runs of one clip.

The runs of a suite on one clip repeat a lot of work: every row computes the same camera
initialisation, and rows that differ only downstream (ablations (b)-(d), removal controls) the same
stage 1 and V2W transform. Suites repeat whole runs: the full method with its defaults is a row of
paper-main, paper-ablation, the crf suite's HDR-NeRF row and every control suite, so stage 2 is
shared too, between runs whose whole configuration and variant agree (only the final renders, a few
seconds, are made again). With a share folder (`m4dgs.training.pipeline.train(share_dir=...)`;
`m4dgs-eval run` uses OUT/.shared), a phase whose result is already there is copied into the run
instead of being computed, and a computed phase is published there for the next run.

The key of a phase is a SHA-256 of exactly what decides its result:

- the configuration fields the phase and every phase before it read (`PHASE_OF` assigns each
  field of TrainConfig to the first phase that reads it; a test checks that every field is
  assigned, so a new field cannot be silently left out of the keys). The trainer seed is a
  camera-initialisation field: runs of different seeds never share anything;
- the clip's input fingerprint (m4dgs.clip.Clip.input_fingerprint);
- the code: a hash of the m4dgs package's sources (a changed trainer never reuses an old result),
  the torch version, the number of torch threads (sums add up in another order with another
  count), the device type and the resolved rasterizer backend.

A shared phase is bit-for-bit what the run would have computed (every phase reseeds the global torch
generator from the trainer seed when it starts; tests/training/test_phase_sharing.py trains a row
both ways and compares the models). The run records which phases it took from the share folder
(status.json "shared_phases") and keeps the producer's phase seconds in its timings, so a shared run
reports what the method costs, not what the suite saved.

Share entries are written to a temporary folder and renamed into place, and computing a phase holds
an exclusive flock on `<entry>.lock`: two workers that need the same phase at the same time compute
it once (the second waits, then copies)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional, Tuple

from m4dgs.core import io as mio
from m4dgs.core.lock import file_lock

# phases that can be shared, in order (the render phase is cheap and writes the run's own files:
# never shared)
SHARED_PHASES: Tuple[str, ...] = ("camera_init", "stage1", "v2w", "stage2")
ORDER: Tuple[str, ...] = ("camera_init", "stage1", "v2w", "stage2")

# The first phase that reads each configuration field: a dotted field name or section prefix (the
# longest matching prefix wins). When unsure, a field goes to the EARLIER phase: that can only cost
# sharing, never correctness.
PHASE_OF: Dict[str, str] = {
    # the trainer seed: every phase (runs of different seeds are independent draws: nothing shared)
    "seed": "camera_init",
    "preset": "camera_init",
    "width": "camera_init",
    "height": "camera_init",
    "device": "camera_init",
    "checkpoint_every": "camera_init",
    "camera_init": "camera_init",
    "epipolar": "camera_init",
    "masks": "camera_init",
    # stage 1: video Gaussians, their appearance models and exposures
    "raster_backend": "stage1",
    "model": "stage1",  # model.world_scale_* are read by V2W; earlier is safe
    "stage1": "stage1",
    "tonemap": "stage1",
    "exposure": "stage1",
    "ablation.use_video_init": "stage1",
    "ablation.tlr": "stage1",
    "ablation.depth_loss": "stage1",
    "ablation.track_loss": "stage1",
    # V2W transform
    "method": "v2w",  # static-hdr makes every Gaussian static in V2W
    "v2w": "v2w",
    "ablation.occlusion_handling": "v2w",
    "ablation.cov_invariance": "v2w",
    # stage 2 only
    "stage2": "stage2",
    "ablation.occlusion_handling_removal": "stage2",
    "ablation.reproj_loss": "stage2",
}

# what each shared phase leaves in the run folder (files or folders, relative to the run root)
PHASE_OUTPUTS: Dict[str, Tuple[str, ...]] = {
    "camera_init": ("model/camera_init.pt", "cameras_ba.json"),
    "stage1": ("model/stage1.pt", "renders/stage1"),
    "v2w": ("model/v2w.pt",),
    "stage2": ("model/final.pt", "cameras.json"),
}

ENTRY_FILE = "entry.json"


def leaves(d: Mapping[str, Any], prefix: str = "") -> Iterable[Tuple[str, Any]]:
    """(dotted name, value) of every leaf of a nested config dict
    (m4dgs.training.config.to_dict)."""
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            yield from leaves(v, name + ".")
        else:
            yield name, v


def phase_of(field: str) -> str:
    """The phase that first reads config field `field` (dotted), by its longest prefix in PHASE_OF;
    KeyError for a field no entry covers."""
    parts = field.split(".")
    for n in range(len(parts), 0, -1):
        p = ".".join(parts[:n])
        if p in PHASE_OF:
            return PHASE_OF[p]
    raise KeyError(
        f"config field {field!r} is not assigned to a trainer phase: add it to "
        "m4dgs.training.phases.PHASE_OF"
    )


def code_fingerprint() -> str:
    """SHA-256 (hex) of the m4dgs package's source files (.py and the C++/CUDA sources), names and
    contents."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    files = sorted(
        p
        for p in root.rglob("*")
        if p.is_file() and p.suffix in (".py", ".cpp", ".h", ".cu", ".cuh")
    )
    for p in files:
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def phase_keys(
    cfg: Mapping[str, Any], context: Mapping[str, Any], variant: Optional[str] = None
) -> Dict[str, str]:
    """{phase: key} for the shared phases.

    cfg: the resolved config as a dict (to_dict); context: everything outside the config that
    decides a result (clip and code fingerprints, torch version and threads, device, backend),
    JSON-able; variant: the run's variant name, which its final model records (so it is part of
    the stage-2 key only: rows of different variants still share the earlier phases).
    The key of phase P hashes the fields of P and of every phase before it, and the context."""
    fields: Dict[str, List[Tuple[str, Any]]] = {p: [] for p in ORDER}
    for name, value in leaves(cfg):
        fields[phase_of(name)].append((name, value))
    keys, seen = {}, []
    for p in SHARED_PHASES:
        seen = seen + sorted(fields[p], key=lambda kv: kv[0])
        what = {"phase": p, "fields": seen, "context": dict(context)}
        if p == "stage2":
            what["variant"] = variant
        blob = json.dumps(what, sort_keys=True, default=str)
        keys[p] = hashlib.sha256(blob.encode()).hexdigest()
    return keys


def fields_by_phase(cfg: Mapping[str, Any]) -> Dict[str, List[str]]:
    """{phase: [dotted field names]} (for docs and tests)."""
    out: Dict[str, List[str]] = {p: [] for p in ORDER}
    for name, _ in leaves(cfg):
        out[phase_of(name)].append(name)
    return out


# --------------------------------------------------------------------------------------------------
# the share folder
# --------------------------------------------------------------------------------------------------
@dataclasses.dataclass
class Entry:
    """A finished phase in the share folder."""

    folder: Path
    seconds: float
    log: List[Dict[str, Any]]
    producer: str


class PhaseCache:
    """`root/<phase>/<key>/`: the phase's outputs (PHASE_OUTPUTS, same relative paths as in a run)
    and entry.json {"phase", "key", "seconds", "log" (the phase's log.jsonl records), "producer"
    (the run folder that computed it)}."""

    def __init__(self, root):
        self.root = Path(root)

    def folder(self, phase: str, key: str) -> Path:
        return self.root / phase / key

    def lock(self, phase: str, key: str):
        """Exclusive flock held while a phase is looked up and, if missing, computed."""
        return file_lock(self.root / phase / f".{key}.lock")

    def get(self, phase: str, key: str) -> Optional[Entry]:
        f = self.folder(phase, key)
        meta = f / ENTRY_FILE
        if not meta.is_file():
            return None
        m = mio.read_json(meta)
        return Entry(f, float(m.get("seconds", 0.0)), list(m.get("log", [])), m.get("producer", ""))

    def put(
        self, phase: str, key: str, run_root: Path, seconds: float, log: List[Dict[str, Any]]
    ) -> Path:
        """Copy the phase's outputs from `run_root` into a new entry (temporary folder, then one
        rename: an entry is complete or absent)."""
        final = self.folder(phase, key)
        if (final / ENTRY_FILE).is_file():
            return final
        tmp = final.parent / f".{key}.tmp-{os.getpid()}"
        if tmp.exists():
            shutil.rmtree(tmp)
        for rel in PHASE_OUTPUTS[phase]:
            src = Path(run_root) / rel
            if not src.exists():
                raise FileNotFoundError(f"{src}: the {phase} phase did not write it")
            _copy(src, tmp / rel)
        mio.write_json(
            tmp / ENTRY_FILE,
            {
                "phase": phase,
                "key": key,
                "seconds": float(seconds),
                "log": log,
                "producer": str(Path(run_root).resolve()),
            },
        )
        if final.exists():  # a folder without entry.json is not an entry (made by hand?)
            shutil.rmtree(final)
        os.replace(tmp, final)
        return final

    def copy_into(self, entry: Entry, phase: str, run_root: Path) -> None:
        """Put an entry's outputs into a run folder (each file written atomically)."""
        for rel in PHASE_OUTPUTS[phase]:
            dst = Path(run_root) / rel
            if dst.is_dir():
                shutil.rmtree(dst)
            _copy(entry.folder / rel, dst)


def _copy(src: Path, dst: Path) -> None:
    """Copy a file or a folder tree; every file through a temporary name and a rename."""
    if src.is_dir():
        for p in sorted(src.rglob("*")):
            if p.is_file():
                _copy(p, dst / p.relative_to(src))
        return
    mio.write_bytes_atomic(dst, src.read_bytes())
