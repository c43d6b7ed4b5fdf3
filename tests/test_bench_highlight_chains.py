"""bench/highlight_chains.py on the disc clip of bench/small_mover_bench.py, with dynamic masks
drawn here from the disc's known centres: the tracker's chain on the disc is reported on the movers
(distance 0), and with the masks moved 40 px away it is not (distance about 40 less the radii)."""

from __future__ import annotations

import json

import numpy as np

from m4dgs.core.io import write_png


def _masks(clip, centres, radius, dx=0.0):
    H, W = 96, 160
    (clip / "gt" / "masks" / "dynamic").mkdir(parents=True, exist_ok=True)
    for g, c in enumerate(centres):
        y, x = np.mgrid[0:H, 0:W] + 0.5
        m = (x - c[0] - dx) ** 2 + (y - c[1]) ** 2 <= radius**2
        write_png(clip / "gt" / "masks" / "dynamic" / f"{g:05d}.png", m.astype(np.uint8) * 255)


def test_chain_on_the_disc_is_on_the_movers(tmp_path, load_bench, capsys):
    smb = load_bench("small_mover_bench")
    hc = load_bench("highlight_chains")
    clip = smb.make_disc_clip(tmp_path / "disc")  # 160x96, 24 frames, radius 9, 4 px a frame
    disc = json.loads((tmp_path / "disc" / "disc.json").read_text())
    centres, radius = np.asarray(disc["centres"]), disc["radius"]

    _masks(clip, centres, radius)
    rep = hc.chain_report(clip)
    assert rep["train_frames"] == 12
    on = [c for c in rep["chains"] if c["on_movers"]]
    assert len(on) == 1 and on[0]["frames"] >= 9 and on[0]["median_px"] == 0.0, rep
    assert not on[0]["still"]  # it moves 8 px a training frame

    _masks(clip, centres, radius, dx=40.0)  # the true movers elsewhere: no chain on them
    rep = hc.chain_report(clip)
    assert not any(c["on_movers"] for c in rep["chains"])
    d = [c["median_px"] for c in rep["chains"] if c["frames"] >= 9]
    assert len(d) == 1 and 40 - 2 * radius - 2 < d[0] < 40 - radius + 2, rep

    out = tmp_path / "chains.json"
    assert hc.main([str(clip), "--json", str(out)]) == 0
    assert "on the movers: none of 12 training frames" in capsys.readouterr().out
    assert json.loads(out.read_text())[0]["clip"] == "clip"
