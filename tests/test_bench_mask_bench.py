"""bench/mask_bench.py on a run folder built from a tiny oracle clip: the saved masks are the
ground truth (IoU 1), the epipolar ones empty (recall 0), and the rigidity test recomputed from the
true cameras and the exact depth and flow priors flags only ground-truth dynamic pixels (about 40 %
of them: the rest move by less than its threshold between the frames of a pair)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
import yaml


def _run_from_gt(clip_dir: Path, run: Path) -> None:
    from m4dgs.clip import Clip
    from m4dgs.run import save_torch

    clip = Clip.open(clip_dir)
    cams = clip.load_gt_cameras()
    index = {int(g): i for i, g in enumerate(cams.frames)}
    train = clip.train_frames
    gt = np.stack([clip.load_gt_dynamic_mask(g) for g in train])
    # the prior's units: one scale per frame, the median ratio of true to prior depth
    scale = [
        float(np.median(clip.load_gt_depth(g)[m] / clip.load_depth_prior(g)[m]))
        for g in train
        for m in [clip.load_depth_prior(g) > 0]
    ]
    (run / "model").mkdir(parents=True)
    save_torch(
        run / "model" / "camera_init.pt",
        {
            "K": torch.as_tensor(cams.K[index[train[0]]], dtype=torch.float32),
            "c2w": torch.as_tensor(cams.c2w[[index[g] for g in train]], dtype=torch.float32),
            "depth_scale": torch.tensor(scale, dtype=torch.float32),
            "masks": torch.from_numpy(gt),
            "masks_epipolar": torch.zeros(gt.shape, dtype=torch.bool),
        },
    )
    (run / "run.json").write_text(json.dumps({"clip": str(Path(clip_dir).resolve())}))
    masks = {"method": "union", "median_factor": 3.0, "min_threshold": 1e-3, "combine": "mean"}
    (run / "config.yaml").write_text(yaml.safe_dump({"masks": masks}))


def test_mask_bench_on_a_run_with_true_cameras(tiny_clip_oracle, tmp_path, load_bench, capsys):
    mb = load_bench("mask_bench")
    run = tmp_path / "run"
    _run_from_gt(Path(tiny_clip_oracle), run)
    rows = {(r["masks"], r["delta"]): r for r in mb.bench_run(run, [0.0, 0.2])}
    assert rows[("saved", None)]["iou"] == 1.0
    assert rows[("epipolar", None)]["recall"] == 0.0 and rows[("epipolar", None)]["fraction"] == 0
    for delta in (0.0, 0.2):
        rig = rows[("rigidity", delta)]
        assert rig["precision"] > 0.95 and rig["recall"] > 0.3, rig
        # the epipolar masks are empty here, so the union is the rigidity test alone
        assert rows[("union", delta)]["iou"] == rig["iou"]
    # saved (the gt) is not what the recomputation makes, so it is not reported as reproduced
    assert not rows[("union", 0.0)].get("reproduces_saved")
    out = tmp_path / "rows.json"
    assert mb.main([str(run), "--depth-tolerance", "0", "--json", str(out)]) == 0
    assert "| rigidity | 0.0 |" in capsys.readouterr().out
    assert len(json.loads(out.read_text())) == 4
