"""docs/new-ideas.md stays true: its example suite parses, its rows resolve to configurations with
the same iteration budget, every override it sets is a configuration field that a trainer phase
reads, and every option its commands use is an option of that command."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

DOC = Path(__file__).resolve().parents[2] / "docs" / "new-ideas.md"


def _blocks(lang: str):
    return re.findall(rf"```{lang}\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)


def test_the_example_suite_is_valid_and_budget_matched(tmp_path):
    from eval.records.suite import check_variants, load_eval_suite
    from m4dgs.training.config import to_dict
    from m4dgs.training.phases import leaves, phase_of
    from m4dgs.training.variants import run_plan

    (text,) = _blocks("yaml")
    path = tmp_path / "my-idea.yaml"
    path.write_text(text)
    s = load_eval_suite(path)
    check_variants(s)
    assert s.name == "my-idea" and s.reference == "full"
    assert [r.name for r in s.rows] == ["full", "full-idea"]
    idea = s.row("full-idea")
    assert idea.overrides  # the idea is a change, not the full row again
    for preset in ("tiny", "small"):
        plans = {r.name: run_plan(preset, r.variant, r.overrides) for r in s.rows}
        assert plans["full"][1:3] == plans["full-idea"][1:3]  # same stage-1 / stage-2 iterations
        assert plans["full"][3] != plans["full-idea"][3]  # and not the same training
    from m4dgs.training.variants import variant_config

    fields = dict(leaves(to_dict(variant_config("tiny", "full", idea.overrides))))
    for key, value in idea.overrides.items():
        assert fields[key] == value and phase_of(key)


def test_the_commands_use_options_their_command_has():
    from eval.cli import main

    lines = []
    for block in _blocks("bash"):
        lines += [ln.split("#")[0] for ln in block.replace("\\\n", " ").splitlines()]
    used = 0
    for ln in lines:
        words = shlex.split(ln)
        if len(words) < 2 or words[0] != "m4dgs-eval":
            continue
        cmd = main.commands[words[1]]
        known = {o for p in cmd.params for o in p.opts}
        opts = [w for w in words[2:] if w.startswith("--")]
        assert set(opts) <= known, (ln, sorted(set(opts) - known))
        used += 1
    assert used == 7
