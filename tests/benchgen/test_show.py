"""`benchgen show`: the summary of a generated clip, and rel_std read the same way whichever
version of benchgen.groundtruth.render_noise recorded it."""

import json
import math
from pathlib import Path

from click.testing import CliRunner

from benchgen.cli import main
from benchgen.show import render_noise_view, summary
from m4dgs.clip import Clip


def test_render_noise_view_converts_the_two_sample_value_of_older_clips():
    old = {"rel_std": 0.04, "tae_two_seeds": 0.1, "mu_psnr": 45.0}
    v = render_noise_view(old)
    assert v["rel_std"] == 0.04 * math.sqrt(math.pi / 2) and v["rel_std_two_sample"] == 0.04
    assert "converted" in v["rel_std_note"] and old["rel_std"] == 0.04  # the input is not changed
    new = {"rel_std": 0.05, "rel_std_two_sample": 0.05 * math.sqrt(2 / math.pi), "mu_psnr": 45.0}
    assert render_noise_view(new) == new


def test_show_summary_of_a_generated_clip(tiny_clip_oracle):
    root = Path(tiny_clip_oracle)
    s = summary(Clip.open(root))
    meta = json.loads((root / "clip.json").read_text())
    assert s["frames"] == len(meta["frames"]) and s["priors"]["profile"] == "oracle" and s["has_gt"]
    noise = meta["gt"]["render_noise"]
    assert s["render_noise"]["rel_std"] == noise["rel_std"]
    assert math.isclose(noise["rel_std"], noise["rel_std_two_sample"] * math.sqrt(math.pi / 2))
    r = CliRunner().invoke(main, ["show", "--no-sheet", str(root)])
    assert r.exit_code == 0, r.output
    printed = json.loads(r.output[r.output.index("{") : r.output.rindex("}") + 1])
    assert printed["render_noise"]["rel_std"] == noise["rel_std"]
