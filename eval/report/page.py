"""The published results: a small CSV of per-run metrics, and docs/results.md regenerated from it.

    m4dgs-eval export SUITE [SUITE...] --root RUNS --csv results/runs.csv
    m4dgs-eval results --csv results/runs.csv --out docs/results.md

`export` collects the runs of suites (the records `m4dgs-eval table` aggregates: eval.cli
collect_suite) into one tidy CSV, one row per (suite, scene, row, seed) with the scalar metrics of
eval.records.suite.metric_columns() as columns (6 significant digits), and the learned CRF curves
(mean of RGB on a fixed log2-exposure grid, 3 decimals) into a second CSV beside it
(`<stem>-crf.csv`). It merges with an existing CSV: a scored run replaces the row of the same key, a
run without metrics.json ("missing", or "failed" with its error when the job's last attempt failed:
eval.experiments.runner.record_failure) never replaces a scored row, and rows of other suites,
scenes or seeds stay, so suites run in different sessions accumulate.

`results` renders, for every suite in the CSV, what stands behind it (scenes, seeds, presets,
scored, failed and missing runs), every table of the suite through
eval.records.suite_data.build_tables (the same code as `eval table`: mean +- Student-t 95 %
interval, paired differences to the reference row, the paper's values and the direction-agreement
column) over the (scene, seed) pairs on which every row with runs is scored
(SuiteData.complete_pairs: a suite still running compares every row on the same runs), figures
(per-scene bars of the main metric, learned CRF curves against the true ones, HDR-TAE vs LDR-OE PSNR
per run and as paired differences to the reference row), and a "Findings" section with one table per
finding of the paper (FINDINGS): the paper's difference, ours with its interval and number of
(scene, seed) pairs, and the verdict; then a "Controls" section (CONTROLS): for each control run for
a disagreement, the effect as found, the same effect under the control, and their difference in
differences with its interval. It also replaces the block between README_START and README_END of the
README with the main table. The output depends only on the CSV (no dates), so running it twice
changes nothing. Prose that needs a human (what a verdict or a control's answer means) lives in a
hand-written notes file that the page links."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from eval.records.runs_csv import (
    MAIN_SUITE,
    README_END,
    README_START,
    SCORED,
    SUITE_ORDER,
    crf_csv_path,
    floors_csv_path,
    one_line,
    read_crf_csv,
    read_floors_csv,
    read_runs_csv,
)
from eval.records.suite import (
    builtin_suites,
    load_eval_suite,
    metric_columns,
    suite_display_path,
)
from eval.records.suite_data import SuiteData, suite_data, suite_tables, suites_in
from eval.report.page_figures import (
    FIGURE_KINDS,
    controls_figure,
    finding_figures,
    suite_result_figures,
)
from eval.study.controls import CONTROLS_FIGURE, controls_markdown
from eval.study.findings import (
    FINDING_FIGURE_PREFIX,
    FINDINGS,
    ComparisonResult,
    evaluate_findings,
    findings_glance_markdown,
    findings_markdown,
)
from m4dgs.core import io as mio


# --------------------------------------------------------------------------------------------------
# the page
# --------------------------------------------------------------------------------------------------
def _rel(path, start) -> str:
    return Path(os.path.relpath(Path(path).resolve(), Path(start).resolve())).as_posix()


def _suite_summary(data: SuiteData) -> dict:
    expected = len(data.entries)
    return {
        "scenes": len(data.scenes),
        "all_scenes": len(data.all_scenes),
        "seeds": len(data.seeds),
        "rows": len(data.row_names),
        "scored": len(data.scored),
        "missing": len(data.missing),
        "failed": len(data.failed),
        "pairs": len(data.pairs),
        "complete_pairs": len(data.complete_pairs),
        "left_out": len(data.left_out),
        "expected": expected,
        "presets": data.presets,
        "code": data.provenance("code"),
        "generator": data.provenance("generator"),
        "torch_threads": data.provenance("torch_threads"),
        "host": data.provenance("host"),
    }


def _counts_text(p: Dict[str, int]) -> str:
    """{value: runs} -> "v" when one value, else "v1 (n1 runs), v2 (n2 runs)"."""
    if len(p) == 1:
        return next(iter(p))
    return ", ".join(f"{k} ({v} runs)" for k, v in p.items())


def _presets_text(p: Dict[str, int]) -> str:
    if not p:
        return "n/a"
    if len(p) == 1:
        return next(iter(p))
    return "mixed: " + ", ".join(f"{k} ({v} runs)" for k, v in p.items())


def _partial_text(data: SuiteData) -> str:
    """The line saying which runs the tables of a suite in progress compare."""
    pairs = ", ".join(f"{sc} seed {seed}" for sc, seed in data.complete_pairs)
    return (
        f"- **Incomplete pairs**: the tables and figures use the {len(data.complete_pairs)} of "
        f"{len(data.pairs)} (scene, seed) pairs on which every row with runs is scored ({pairs}), "
        "so that every row is compared on the same runs; the "
        f"{len(data.left_out)} scored run(s) of the other pairs wait for the missing runs above"
        + (" or are left out with the failed run(s) of their pair" if data.failed else "")
    )


def floors_text(data: SuiteData, floors: Dict[tuple, Dict[str, Optional[float]]]) -> Optional[str]:
    """The suite's line on the ground-truth HDR-TAE floors of its scored runs' clips (mean and
    range over its (scene, generator) clips in `floors`), None when none has a recorded floor."""
    clips = sorted(
        {(r["scene"], str(r.get("generator") or "")) for r in data.rows if r["status"] == SCORED}
    )
    have = [floors[c] for c in clips if c in floors]
    if not have:
        return None
    scenes = len({sc for sc, _ in clips})
    # a scene's clips of two generator versions (e.g. 2D rows made on newer clips) are two clips
    of = f"{len(have)} of its {len(clips)} clips" + (
        f" ({scenes} scenes, clips of {len({g for _, g in clips})} generator versions)"
        if scenes < len(clips)
        else ""
    )

    def stat(col):
        v = [f[col] for f in have if f.get(col) is not None]
        return f"{sum(v) / len(v):.3f} ({min(v):.3f}-{max(v):.3f})" if v else "n/a"

    return (
        "- Ground-truth HDR-TAE floor of its clips (clip.json `gt.hdr_tae_floor`: the metric "
        "scored on the ground truth itself, the level a method's HDR-TAE is read against, "
        "docs/rendering.md): "
        f"mean {stat('hdr_tae_floor')} over {of}; edge-excluded "
        f"(`gt.hdr_tae_floor_interior`, for `hdr_tae_interior`) {stat('hdr_tae_floor_interior')}"
    )


# the headline metrics whose seed noise a suite's section gives, with their names there
SEED_NOISE_METRICS = {
    "ldr_oe_psnr": "LDR-OE PSNR",
    "hdr_psnr": "HDR PSNR",
    "hdr_tae": "HDR-TAE",
    "hdr_tce": "HDR-TCE",
}


def seed_noise_text(data: SuiteData) -> Optional[str]:
    """The section's line on how much a run moves with its trainer seed alone (SuiteData.seed_noise
    of the headline metrics), or None when no (scene, row) has runs of two seeds."""
    cols = metric_columns()
    parts, groups = [], 0
    for k in SEED_NOISE_METRICS:
        sn = data.seed_noise(k)
        if sn is None:
            continue
        fmt = cols[k].fmt
        name = SEED_NOISE_METRICS[k]
        parts.append(f"{name} {sn.rms_diff:{fmt}} (largest {sn.largest:{fmt}})")
        groups = max(groups, sn.groups)
    if not parts:
        return None
    return (
        "- Seed noise (the same scene and row trained with another trainer seed; root mean square "
        f"difference of two runs, over {groups} (scene, row) groups with two or more seeds): "
        + ", ".join(parts)
        + "; one (scene, seed) difference between two rows carries noise of this size (less "
        "where the two rows share a trained phase), a mean over n pairs about 1/sqrt(n) of it"
    )


def suite_section(
    data: SuiteData,
    fig_paths: List[Path],
    out_dir: Path,
    floors: Optional[dict] = None,
    partial: Optional[Dict[str, Tuple[int, int]]] = None,
) -> str:
    """The suite's section of the results page; partial: data.partial_metrics() when the caller
    has it."""
    sm = _suite_summary(data)
    desc = data.suite.description if data.suite is not None else "(no suite definition found)"
    lines = [f"## {data.name}", "", desc, ""]
    if data.suite is not None:
        path = data.suite.path
        shown = suite_display_path(path)
        lines += [f"Definition: [{shown}]({_rel(path, out_dir)})."]
        lines.append("")
    missing = data.missing
    miss_txt = f"{sm['missing']}" + (
        " ("
        + ", ".join(f"`{e['run_dir']}`" for e in missing[:8])
        + (f", and {len(missing) - 8} more" if len(missing) > 8 else "")
        + ")"
        if missing
        else ""
    )
    lines += [
        f"- Scenes: {sm['scenes']} of the {sm['all_scenes']} of its scene suite: "
        + ", ".join(data.scenes),
        f"- Rows: {sm['rows']} ("
        + ", ".join(f"`{r}`" for r in data.row_names)
        + f"); reference row: `{data.suite.reference if data.suite is not None else 'n/a'}`",
        f"- Trainer seeds: {sm['seeds']} (" + ", ".join(str(s) for s in data.seeds) + ")",
        f"- Preset: {_presets_text(sm['presets'])}",
        f"- Provenance: m4dgs code {_counts_text(sm['code'])}; clip generator version "
        f"{_counts_text(sm['generator'])}; torch threads {_counts_text(sm['torch_threads'])}; "
        f"host {_counts_text(sm['host'])}",
        f"- Runs: {sm['scored']} scored of {sm['expected']} "
        f"(= {sm['scenes']} scenes x {sm['rows']} rows x {sm['seeds']} seeds); "
        + (f"failed: {sm['failed']}; " if sm["failed"] else "")
        + "missing: "
        + miss_txt,
    ]
    if data.failed:
        lines.append(
            "- **Failed runs** (the job's last attempt stopped with an error; a result of the "
            "configuration when it repeats, and its (scene, seed) pair is left out of every row's "
            "tables): "
            + "; ".join(f"`{e['run_dir']}`: {one_line(e['error'])}" for e in data.failed)
        )
    ft = floors_text(data, floors or {})
    if ft:
        lines.append(ft)
    pm = data.partial_metrics() if partial is None else partial
    if pm:
        lines.append(
            "- Metrics some runs lack (scored before the metric existed, or written back by an "
            "export that did not know it): "
            + ", ".join(f"`{k}` present in {h} of {n} runs" for k, (h, n) in pm.items())
            + "; the tables show n/a for it where a row lacks a run's value, the findings pair "
            "only the runs that have it"
        )
    sn = seed_noise_text(data)
    if sn:
        lines.append(sn)
    if sm["left_out"]:
        lines.append(_partial_text(data))
    lines += [
        "",
        suite_tables(data).rstrip("\n"),
        "",
    ]
    if fig_paths:
        lines += ["Figures:", ""]
        for p in fig_paths:
            lines += [f"![{p.stem}]({_rel(p, out_dir)})", ""]
    return "\n".join(lines)


def readme_block(
    main: Optional[SuiteData],
    results_link: str,
    csv_name: str,
    floors: Optional[dict] = None,
    rows: Optional[List[dict]] = None,
    evaluated: Optional[Dict[str, List[ComparisonResult]]] = None,
) -> str:
    """The README's results block (between the markers); `floors` (read_floors_csv) adds the
    line on the clips' HDR-TAE floor under the table, `rows` (the runs CSV) the findings at a
    glance (findings_glance_markdown; `evaluated`: evaluate_findings(rows) when the caller has
    it) under it."""
    head = [
        README_START,
        "<!-- generated by `m4dgs-eval results`; do not edit between the markers -->",
    ]
    if main is None or not main.scored:
        body = [
            f"The result tables are pending: `{csv_name}` has no scored run of `{MAIN_SUITE}` yet. "
            f"[{results_link}]({results_link}) lists what is there.",
        ]
    elif not main.complete_pairs or {e["row"] for e in main.table_entries if e["metrics"]} != set(
        main.row_names
    ):
        body = [
            f"The result tables are pending: `{csv_name}` has {len(main.scored)} scored run(s) of "
            f"`{MAIN_SUITE}` so far, and not yet a (scene, seed) pair on which every row is "
            f"scored. [{results_link}]({results_link}) lists what is there.",
        ]
    else:
        sm = _suite_summary(main)
        partial = ""
        if sm["left_out"]:
            partial = (
                f" The table compares the {sm['complete_pairs']} (scene, seed) pairs on which "
                f"every row is scored ({sm['left_out']} more run(s) wait for their pairs)."
            )
        body = [
            f"Suite `{MAIN_SUITE}`, preset {_presets_text(sm['presets'])}: {sm['scored']} of "
            f"{sm['expected']} runs scored ({sm['scenes']} scenes x {sm['rows']} rows x "
            f"{sm['seeds']} seeds).{partial} Every suite, the paper's values beside ours, figures "
            f"and the findings: [{results_link}]({results_link}).",
            "",
            suite_tables(main, first_only=True).rstrip("\n"),
        ]
        ft = floors_text(main, floors or {})
        if ft:
            body.append(ft)
    if rows and any(r.get("status") == SCORED for r in rows):
        if evaluated is None:
            evaluated = evaluate_findings(rows)
        glance = findings_glance_markdown(rows, evaluated, f"{results_link}#findings")
        body += ["", glance.rstrip("\n")]
    return "\n".join(head + [""] + body + ["", README_END])


def replace_readme_block(text: str, block: str, path="README") -> str:
    from m4dgs.core.errors import InputError

    i, j = text.find(README_START), text.find(README_END)
    if i < 0 or j < i:
        raise InputError(
            f"{path}: no {README_START} ... {README_END} markers; add them where the results "
            "table goes, or pass --no-readme"
        )
    return text[:i] + block + text[j + len(README_END) :]


def _is_results_figure(name: str) -> bool:
    """Whether a file name is one `suite_result_figures` writes: <suite>_<kind>.png, the suite a
    shipped suite (eval/suites/*/*.yaml)."""
    if name == CONTROLS_FIGURE:
        return True
    if name.startswith(FINDING_FIGURE_PREFIX) and name.endswith(".png"):
        return name[len(FINDING_FIGURE_PREFIX) : -len(".png")] in {f.key for f in FINDINGS}
    for kind in sorted(FIGURE_KINDS, key=len, reverse=True):
        tail = f"_{kind}.png"
        if name.endswith(tail):
            return name[: -len(tail)] in builtin_suites()
    return False


def render_results(
    csv_path,
    out_md,
    *,
    figures_dir=None,
    readme=None,
    notes=None,
    command: Optional[str] = None,
    title: str = "Results",
    suite_files: Sequence = (),
) -> dict:
    """Write out_md (and the figures, and the README block) from the runs CSV.

    suite_files: YAML files of suites that are not built in (your own rows against full), so that
    their sections show the definition, the reference row and the row order; a CSV with none of
    the paper's suites then gets no findings or controls sections (they would all lack data).

    figures_dir None: no figures (else PNGs in it named as this page's figures, <suite>_<kind>.png,
    that the page no longer makes are removed). readme: a README path whose marked block is
    replaced (None: none). notes: the hand-written notes file linked from the page (None: no
    link). title: the page's heading. Returns {"suites", "figures", "readme"}."""
    csv_path, out_md = Path(csv_path), Path(out_md)
    out_dir = out_md.parent
    rows = read_runs_csv(csv_path)
    curves = read_crf_csv(crf_csv_path(csv_path))
    floors = read_floors_csv(floors_csv_path(csv_path))
    names = suites_in(rows)

    definitions = {d.name: d for d in (load_eval_suite(p) for p in suite_files)}
    datas = {n: suite_data(n, rows, definitions) for n in names}
    partial = {n: d.partial_metrics() for n, d in datas.items()}
    # a page of only your own suites: the paper's findings and controls would all lack data
    own_only = bool(names) and not set(names) & set(builtin_suites())
    notes_link = _rel(notes, out_dir) if notes else None
    csv_link = _rel(csv_path, out_dir)
    cmd = command or f"m4dgs-eval results --csv {csv_path} --out {out_md}"
    digest = hashlib.sha256(csv_path.read_bytes()).hexdigest()[:12] if csv_path.exists() else None
    lines = [
        f"# {title}",
        "",
        f"<!-- generated by `{cmd}` from {csv_path.as_posix()}; do not edit by hand -->",
        "",
        (
            f"Generated by `{cmd}` from [{csv_path.as_posix()}]({csv_link}) (sha256 {digest}, "
            f"with the CRF curves in `{crf_csv_path(csv_path).name}`"
            + (
                f" and the clips' HDR-TAE floors in `{floors_csv_path(csv_path).name}`)."
                if floors
                else ")."
            )
            if digest
            else f"Generated by `{cmd}` from `{csv_path.as_posix()}` (the file does not exist yet)."
        ),
        "The CSV is written by `m4dgs-eval export SUITE --root RUNS --csv "
        f"{csv_path.as_posix()}` (docs/eval.md); the runs themselves stay out of git.",
        "Tables: mean ± the half-width of the Student-t 95 % interval over a row's (scene, seed) "
        "runs, Δ the paired difference to the suite's reference row († where its interval "
        "excludes 0), the paper's value and the direction agreement where the paper has the "
        'table (docs/eval.md, "m4dgs-eval table").',
    ]
    if notes_link:
        lines.append(
            f"Hand-written notes (what the verdicts mean, controls for disagreements): "
            f"[{Path(notes_link).name}]({notes_link})."
        )
    lines.append("")
    if not any(d.scored for d in datas.values()):
        lines += [
            "**The runs are pending**: "
            + (
                f"`{csv_path.as_posix()}` does not exist yet."
                if not csv_path.exists()
                else f"`{csv_path.as_posix()}` has no scored run yet."
            )
            + " Fill it with `m4dgs-eval run SUITE --preset small --seeds 2 --root "
            "experiments-small` and `m4dgs-eval export SUITE --root experiments-small --csv "
            f"{csv_path.as_posix()}`, then run `{cmd}` again.",
            "",
        ]
    if names:
        lines += [
            "| suite | scenes | rows | seeds | preset | scored | failed | missing |",
            "|:---|---:|---:|---:|:---|---:|---:|---:|",
        ]
        for n in names:
            sm = _suite_summary(datas[n])
            lines.append(
                f"| [{n}](#{n}) | {sm['scenes']} of {sm['all_scenes']} | {sm['rows']} | "
                f"{sm['seeds']} | {_presets_text(sm['presets'])} | {sm['scored']} of "
                f"{sm['expected']} | {sm['failed']} | {sm['missing']} |"
            )
        lines.append("")
    absent = [n for n in SUITE_ORDER if n not in names]
    if absent and not own_only:
        lines += [
            "Suites without runs in the CSV: " + ", ".join(f"`{n}`" for n in absent) + ".",
            "",
        ]
    figs = []
    for n in names:
        fp = suite_result_figures(datas[n], curves, figures_dir) if figures_dir else []
        figs += fp
        lines += [suite_section(datas[n], fp, out_dir, floors, partial[n]), ""]
    evaluated = {} if own_only else evaluate_findings(rows)
    if own_only:
        lines.append(
            "No suite of this CSV is one of the project's, so the paper's findings and the "
            "controls of its disagreements are not evaluated here (docs/results.md has them)."
        )
    else:
        ffigs = finding_figures(evaluated, figures_dir) if figures_dir else {}
        figs += list(ffigs.values())
        links = {k: _rel(p, out_dir) for k, p in ffigs.items()}
        lines.append(findings_markdown(rows, notes_link, links, evaluated))
        cfig = controls_figure(rows, Path(figures_dir) / CONTROLS_FIGURE) if figures_dir else None
        if cfig is not None:
            figs.append(cfig)
        lines += ["", controls_markdown(rows, notes_link, _rel(cfig, out_dir) if cfig else None)]
    text = "\n".join(lines).rstrip("\n") + "\n"
    mio.write_bytes_atomic(out_md, text.encode())
    if figures_dir:
        # figures of suites no longer in the CSV go with them; only files named as this function
        # names its figures are touched, so a shared folder keeps everything else
        made = {Path(p).resolve() for p in figs}
        for old_fig in Path(figures_dir).glob("*.png"):
            if old_fig.resolve() not in made and _is_results_figure(old_fig.name):
                old_fig.unlink()
    res = {
        "suites": names,
        "figures": [str(p) for p in figs],
        "readme": None,
        "partial_metrics": {n: pm for n, pm in partial.items() if pm},
    }
    if readme:
        rp = Path(readme)
        block = readme_block(
            datas.get(MAIN_SUITE),
            _rel(out_md, rp.parent),
            csv_path.as_posix(),
            floors,
            rows,
            evaluated,
        )
        old = rp.read_text(encoding="utf-8")
        new = replace_readme_block(old, block, rp)
        if new != old:
            mio.write_bytes_atomic(rp, new.encode())
        res["readme"] = str(rp)
    return res
