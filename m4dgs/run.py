"""The run folder: resolved config, JSON-lines log, checkpoints, status; all writes atomic. The
layout is below; docs/method.md lists the trainer phases that fill it, docs/outputs.md the renders.

<run>/
  config.yaml            fully resolved configuration (written once; a resumed run must match it)
  status.json            {"stage": "stage1" | "v2w" | "stage2" | "done", "step": int,
                          "clip_fingerprint": SHA-256 of the clip's inputs at the start, ...}
  log.jsonl              one JSON object per logged step (losses, Gaussian counts, timings)
  model/ckpt.pt          the latest resumable checkpoint (written atomically; the one before it
                         is kept as model/ckpt.prev.pt, the fallback when ckpt.pt is unreadable)
  model/stage1.pt        final stage-1 model;  model/final.pt  final model
  cameras.json           estimated cameras (BA, then refined)
  renders/...            written by m4dgs.outputs.render
  failure.json           {"error", "time"}: written by `m4dgs-eval run` / `campaign` when the job's
                         last attempt failed (eval.experiments.runner.record_failure), removed
                         once it scores
"""

from __future__ import annotations

import io as _io
import json
import os
import time
import warnings
from pathlib import Path
from typing import Any, Dict, List, Optional

import torch
import yaml

from m4dgs.core import io as mio
from m4dgs.core.errors import with_path


def save_torch(path, obj: Any) -> None:
    """torch.save to a temporary file, then rename: a crash never leaves a truncated checkpoint."""
    buf = _io.BytesIO()
    torch.save(obj, buf)
    mio.write_bytes_atomic(path, buf.getvalue())


def load_torch(path, map_location="cpu") -> Any:
    return torch.load(path, map_location=map_location, weights_only=False)


def checkpoint_tensors(obj, prefix: str = "") -> Dict[str, torch.Tensor]:
    """{dotted path: tensor} of every tensor in a nested checkpoint (dicts, lists, tuples), e.g.
    "params.means" or "optimizers.ctrl.state.0.exp_avg"; for comparing two saved models."""
    out: Dict[str, torch.Tensor] = {}
    if torch.is_tensor(obj):
        out[prefix] = obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            out.update(checkpoint_tensors(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            out.update(checkpoint_tensors(v, f"{prefix}[{i}]"))
    return out


class RunDir:
    def __init__(self, root):
        self.root = Path(root)

    # -- layout
    # ----------------------------------------------------------------------------------------------
    def path(self, *parts) -> Path:
        return self.root.joinpath(*parts)

    @property
    def config_path(self) -> Path:
        return self.root / "config.yaml"

    @property
    def ckpt_path(self) -> Path:
        return self.root / "model" / "ckpt.pt"

    @property
    def prev_ckpt_path(self) -> Path:
        return self.root / "model" / "ckpt.prev.pt"

    # -- checkpoints
    # ----------------------------------------------------------------------------------------------
    def write_checkpoint(self, obj: Any) -> None:
        """Write model/ckpt.pt atomically; the checkpoint it replaces is kept as ckpt.prev.pt (the
        fallback of `read_checkpoint`)."""
        p = self.ckpt_path
        if p.exists():
            os.replace(p, self.prev_ckpt_path)
        save_torch(p, obj)

    def read_checkpoint(self, map_location="cpu") -> Optional[Any]:
        """The newest readable checkpoint: ckpt.pt, else ckpt.prev.pt (with a warning naming the
        unreadable file and why); None when neither exists or can be read."""
        for p in (self.ckpt_path, self.prev_ckpt_path):
            if not p.exists():
                continue
            try:
                return load_torch(p, map_location=map_location)
            except Exception as e:  # truncated / damaged file: any unpickling or zip error
                warnings.warn(
                    f"{p}: unreadable checkpoint ({type(e).__name__}: {e}); trying an older one",
                    RuntimeWarning,
                    stacklevel=2,
                )
        return None

    # -- config
    # ----------------------------------------------------------------------------------------------
    def write_config(self, cfg: Dict[str, Any]) -> None:
        mio.write_text_atomic(self.config_path, yaml.safe_dump(cfg, sort_keys=False))

    def read_config(self) -> Optional[Dict[str, Any]]:
        if not self.config_path.exists():
            return None
        return mio.read_yaml(self.config_path)

    # -- status
    # ----------------------------------------------------------------------------------------------
    def status(self) -> Dict[str, Any]:
        p = self.root / "status.json"
        return mio.read_json(p) if p.exists() else {"stage": "new", "step": 0}

    def set_status(self, **kw) -> None:
        s = self.status()
        s.update(kw)
        s["updated"] = time.strftime("%Y-%m-%dT%H:%M:%S")
        mio.write_json(self.root / "status.json", s)

    @property
    def done(self) -> bool:
        return self.status().get("stage") == "done"

    # -- log
    # ----------------------------------------------------------------------------------------------
    def log(self, record: Dict[str, Any]) -> None:
        """Append one JSON line (flushed and fsynced: the log survives a kill)."""
        self.log_records([record])

    def log_records(self, records: List[Dict[str, Any]]) -> None:
        """Append JSON lines in one write, then one fsync. A failed write (no space, a file-size
        limit) is raised naming log.jsonl; the torn line it may leave is skipped by `read_log`
        and dropped by the resumed run's `truncate_log`."""
        if not records:
            return
        self.root.mkdir(parents=True, exist_ok=True)
        p = self.root / "log.jsonl"
        try:
            with open(p, "a") as f:
                f.write("".join(json.dumps(r) + "\n" for r in records))
                f.flush()
                os.fsync(f.fileno())
        except OSError as e:
            new = with_path(e, p)
            if new is e:
                raise
            raise new from e

    def read_log(self) -> List[Dict[str, Any]]:
        """Records of log.jsonl in order ([] without a log); blank lines and an unparsable line (the
        torn last line of a killed run) are skipped."""
        p = self.root / "log.jsonl"
        if not p.exists():
            return []
        out = []
        for line in p.read_text().splitlines():
            line = line.strip()
            if line:
                try:
                    out.append(json.loads(line))
                except json.JSONDecodeError:  # a torn last line after a hard kill
                    continue
        return out

    def truncate_log(self, stage: str, step: int) -> None:
        """Drop the log lines of `stage` past `step` (the resumed run writes them again; step -1
        drops all of the stage's), and a torn line; the file is left alone when nothing goes."""
        p = self.root / "log.jsonl"
        if not p.exists():
            return
        text = p.read_text()
        recs = [
            r for r in self.read_log() if not (r.get("stage") == stage and r.get("step", -1) > step)
        ]
        new = "".join(json.dumps(r) + "\n" for r in recs)
        if new != text:
            mio.write_text_atomic(p, new)
