"""bench/same_bits.py: the checkout against itself trains the same bits (exit 0); a changed tensor
or logged value is found and named (built by hand, independently of any training)."""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_a_checkout_against_itself_and_planted_differences(
    load_bench, tiny_clip_realistic, tmp_path, short_training, capsys
):
    sb = load_bench("same_bits")
    sets = [f"{k}={v}" for k, v in short_training.items()]
    argv = [str(ROOT), str(ROOT), str(tiny_clip_realistic), "--out", str(tmp_path / "runs")]
    assert sb.main(argv + sum((["--set", s] for s in sets), [])) == 0
    assert "same bits" in capsys.readouterr().out
    # a planted difference in one tensor and in one logged value
    from m4dgs.run import checkpoint_tensors, load_torch, save_torch

    final = tmp_path / "runs/new/model/final.pt"
    ck = load_torch(final)
    name, t = next(
        (k, v) for k, v in checkpoint_tensors(ck).items() if v.is_floating_point() and v.numel()
    )
    t.view(-1)[0] += 1.0
    save_torch(final, ck)
    n, differ = sb.compare_models(tmp_path / "runs/old/model/final.pt", final)
    assert differ == [name] and n > 1
    log = tmp_path / "runs/new/log.jsonl"
    rows = [json.loads(x) for x in log.read_text().splitlines()]
    rows[3]["total"] = float(rows[3]["total"]) + 1.0
    rows[5]["sec"] = 99.0  # step times are not compared
    log.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    n, differ = sb.compare_logs(tmp_path / "runs/old/log.jsonl", log)
    assert differ == ["3:total"] and n == len(rows)


def test_a_variant_without_stage_1_and_a_phase_file_on_one_side(
    load_bench, tiny_clip_realistic, tmp_path, short_training, capsys
):
    """--variant world-only: stage 1 is in neither run and left out (exit 0); a phase file that
    only one run has is a difference."""
    sb = load_bench("same_bits")
    sets = sum((["--set", f"{k}={v}"] for k, v in short_training.items()), [])
    runs = tmp_path / "runs"
    argv = [str(ROOT), str(ROOT), str(tiny_clip_realistic), "--out", str(runs)]
    assert sb.main(argv + ["--variant", "world-only"] + sets) == 0
    out = capsys.readouterr().out
    assert "stage1.pt: in neither run" in out and "same bits" in out, out
    assert not (runs / "old/model/stage1.pt").exists()
    (runs / "new/model/v2w.pt").unlink()
    lines = []
    assert sb.compare_runs(runs / "old", runs / "new", say=lines.append) is False
    assert "v2w.pt: only in the old run" in lines
