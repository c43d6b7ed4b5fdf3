"""The findings and controls are data (eval/study/findings.yaml, controls.yaml): they load into
the dataclasses the results page evaluates, their keys are unique, and every suite and row they
name is a row of a shipped suite."""

from __future__ import annotations

from eval.records.suite import load_eval_suite
from eval.study.controls import CONTROLS, Control, load_controls
from eval.study.findings import FINDINGS, Finding, load_findings


def _rows(suite: str) -> set:
    return {r.name for r in load_eval_suite(suite).rows}


def test_findings_load_and_name_real_rows():
    assert load_findings() == FINDINGS and all(isinstance(f, Finding) for f in FINDINGS)
    assert len({f.key for f in FINDINGS}) == len(FINDINGS) == 28
    for f in FINDINGS:
        rows = _rows(f.suite)
        for c in f.comparisons:
            assert {c.row, c.ref} <= rows, (f.key, c)
            assert c.expect in ("better", "worse")


def test_controls_load_and_name_real_rows():
    assert load_controls() == CONTROLS and all(isinstance(c, Control) for c in CONTROLS)
    assert len({c.key for c in CONTROLS}) == len(CONTROLS) == 27
    for c in CONTROLS:
        assert c.arm in ("method", "scale", "benchmark"), c.key
        for e in (c.base, c.control):
            assert {e.row, e.ref} <= _rows(e.suite), (c.key, e)
