"""`m4dgs-eval report table|results`: a suite's tables and the results page (eval.records,
eval.report). The old flat names (`table`, `results`) are hidden aliases (eval.cli)."""

from __future__ import annotations

import os
import shlex
from pathlib import Path

import click

from eval.cli._options import DEFAULT_OUT, found_seeds_opt, parse_names, scenes_opt
from eval.experiments.collect import collect_runs_dir, collect_suite
from eval.records.suite_data import build_tables, compact_tables
from m4dgs.core import io as mio


@click.group(
    "report",
    short_help="Tables and the results page: table, results, findings.",
    context_settings={"help_option_names": ["-h", "--help"]},
)
def group():
    """Tables and the results page: a suite's or a folder's tables, the results page
    from the runs CSV, and the findings' verdicts from any runs CSV."""


def _no_scored_runs(target: str, name: str, root, entries: list) -> str:
    """One line for `table SUITE` when none of the suite's runs under ROOT has a metrics.json:
    the folder it searched, what it looked for there, and what to run."""
    where = os.path.join(os.path.abspath(root), "runs", name)
    todo = f"m4dgs-eval run {shlex.quote(target)} --root {shlex.quote(str(root))}"
    made = [e for e in entries if Path(e["run_dir"]).is_dir()]
    if made:
        return (
            f"{len(made)} of the {len(entries)} run folder(s) of suite {name!r} exist under "
            f"{where} but none has a metrics.json yet (searched <scene>/<row>/metrics.json); "
            f"finish and score them with `{todo}`"
        )
    why = ""
    if not os.path.isdir(root):
        why = "; the experiment root does not exist"
    elif not os.path.isdir(where):
        why = "; that folder does not exist"
    return (
        f"no runs of suite {name!r} under {where} (searched <scene>/<row>/metrics.json for its "
        f"{len(entries)} job(s){why}); train them with `{todo}`"
    )


def _complete_scenes_hint(entries: list):
    """For a suite part of whose runs are not scored yet (a campaign under way): the scenes whose
    runs are all scored, as the --scenes option that tabulates them; None when every scene or no
    scene is complete."""
    scenes = list(dict.fromkeys(e["scene"] for e in entries))
    done = [sc for sc in scenes if all(e["metrics"] for e in entries if e["scene"] == sc)]
    if not done or len(done) == len(scenes):
        return None
    return (
        f"[table] {len(done)} of {len(scenes)} scenes have every run scored; the rows' means stay "
        f"n/a until the others have theirs, or tabulate those with --scenes {','.join(done)}"
    )


@group.command()
@click.argument("target")
@click.option(
    "--root",
    "out",
    default=DEFAULT_OUT,
    show_default=True,
    type=click.Path(file_okay=False),
    metavar="ROOT",
    help="Experiment root of a suite (runs in ROOT/runs/<suite>, figures to ROOT/figures/<suite>).",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["md", "latex", "csv"]),
    default="md",
    show_default=True,
    help="Table format (Markdown with bold best values; LaTeX booktabs; CSV without bold).",
)
@click.option(
    "--out",
    "out_file",
    default=None,
    type=click.Path(dir_okay=False),
    help="Write the tables to this file (atomically) instead of stdout.",
)
@click.option(
    "--columns",
    type=click.Choice(["compact", "all"]),
    default="compact",
    show_default=True,
    help="compact: one table of LDR-OE PSNR, the held-out views' LDR-OE mPSNR (clips with views), "
    "HDR PSNR, HDR-TAE and training time, the `full` row "
    "labelled as the method, columns without any value left out; all: every table of the suite "
    "(or of the folder of runs) with every column.",
)
@scenes_opt
@found_seeds_opt("tabulate")
@click.option(
    "--no-figures",
    is_flag=True,
    help="Do not write the figures (CRF curves, loss curves, image grids).",
)
@click.option(
    "--figures-dir",
    default=None,
    type=click.Path(file_okay=False),
    help="Folder for the figures (default ROOT/figures/<suite>, or <runs dir>/../figures/<name>).",
)
def table(target, out, fmt, columns, out_file, scenes, seeds, no_figures, figures_dir):
    """Print the paper-style tables of TARGET: a suite (name or YAML; runs under ROOT) or a folder
    of runs (linked run and scene folders count like real ones)."""
    from eval.records.suite import TableDef, load_eval_suite
    from m4dgs.core.errors import InputError

    if Path(target).is_dir():
        entries = collect_runs_dir(target)
        if not entries:
            raise InputError(
                f"no scored runs under {os.path.abspath(target)} (searched it and every folder "
                "below it, links included, for metrics.json); score a run folder with "
                "`m4dgs-eval score RUN`, or give a suite's name with --root ROOT"
            )
        reference = "full" if any(e["row"] == "full" for e in entries) else None
        defs = [
            TableDef(f"Runs under {target}", "paper"),
            TableDef("Training frames", "train"),
            TableDef("Geometry", "geometry"),
            TableDef("Cost", "cost"),
        ]
        # beside the folder as named (a linked folder's figures stay in this tree)
        given = Path(os.path.abspath(target))
        fig_dir = Path(figures_dir) if figures_dir else given.parent / "figures" / given.name
    else:
        if os.sep in target and not Path(target).exists():
            raise InputError(
                f"{target}: no such folder of runs ({os.path.abspath(target)}) nor suite file; "
                "give a folder of runs, a suite YAML file or a built-in suite's name "
                "(`m4dgs-eval suites`)"
            )
        s = load_eval_suite(target)
        entries = collect_suite(target, out, parse_names(scenes), seeds=seeds)
        defs, reference = s.tables, s.reference
        fig_dir = Path(figures_dir) if figures_dir else Path(out) / "figures" / s.name
        if not any(e["metrics"] for e in entries):
            raise InputError(_no_scored_runs(target, s.name, out, entries))
    if columns == "compact":
        entries, defs = compact_tables(entries, defs[0].title if defs else str(target))
    text = build_tables(entries, defs, fmt, reference)
    hint = _complete_scenes_hint(entries) if not Path(target).is_dir() and not scenes else None
    if hint:
        click.echo(hint, err=True)
    if out_file:
        mio.write_text_atomic(out_file, text)
        click.echo(f"wrote {out_file}", err=True)
    else:
        click.echo(text, nl=False)
    if not no_figures:
        from eval.figures import suite_figures

        # seed 0 only
        paths = suite_figures([e for e in entries if e["metrics"] and not e.get("seed")], fig_dir)
        click.echo(f"wrote {len(paths)} figure(s) to {fig_dir}", err=True)


@group.command()
@click.option(
    "--csv",
    "csv_path",
    default="results/runs.csv",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="Runs CSV written by `export`, with its <name>-crf.csv and <name>-floors.csv beside it "
    "(a missing file gives a page that says the runs are pending).",
)
@click.option(
    "--out",
    "out_md",
    default="docs/results.md",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="The results page to write.",
)
@click.option(
    "--figures",
    "figures_dir",
    default=None,
    type=click.Path(file_okay=False),
    help="Folder for the figures; PNGs in it named as the page's figures (<suite>_<kind>.png) that "
    "it no longer makes are removed (default: <folder of --out>/figures/<name of --out without "
    ".md>, e.g. docs/figures/results).",
)
@click.option("--no-figures", is_flag=True, help="Write no figures (and link none).")
@click.option(
    "--readme",
    default="README.md",
    show_default=True,
    type=click.Path(dir_okay=False),
    help="README whose block between <!-- results:main:start --> and <!-- results:main:end --> "
    "is replaced by the main table.",
)
@click.option("--no-readme", is_flag=True, help="Leave the README alone.")
@click.option(
    "--title",
    default="Results",
    show_default=True,
    help="The page's heading (e.g. for a page of runs on an earlier benchmark version).",
)
@click.option(
    "--notes",
    default=None,
    type=click.Path(dir_okay=False),
    help="Hand-written notes linked from the page (default: results-notes.md beside --out, else "
    "the research record's lab/results-notes.md in the folder above --out's, when it exists).",
)
@click.option(
    "--suite",
    "suite_files",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="YAML file of a suite of the CSV that is not built in (repeat for several): its section "
    "then shows the definition, the reference row and the row order. A CSV of only such suites "
    "gets no sections on the paper's findings and controls.",
)
def results(
    csv_path, out_md, figures_dir, no_figures, readme, no_readme, title, notes, suite_files
):
    """Regenerate the results page (every suite's tables with intervals, the paper's values and
    the agreement column, figures, findings) and the README's main table from the runs CSV."""
    from eval.report.page import render_results

    notes_given = notes is not None
    if notes is None:
        here = Path(out_md).parent
        cands = [here / "results-notes.md", here.parent / "lab" / "results-notes.md"]
        notes = next((str(c) for c in cands if c.exists()), None)
    default_fig = str(Path(out_md).parent / "figures" / Path(out_md).stem)
    fig = None if no_figures else (figures_dir or default_fig)
    # the command written into the page regenerates it as it is
    q = shlex.quote
    cmd = f"m4dgs-eval results --csv {q(str(csv_path))} --out {q(str(out_md))}"
    if no_figures:
        cmd += " --no-figures"
    elif figures_dir and figures_dir != default_fig:
        cmd += f" --figures {q(str(figures_dir))}"
    if no_readme:
        cmd += " --no-readme"
    elif readme != "README.md":
        cmd += f" --readme {q(str(readme))}"
    if title != "Results":
        cmd += f" --title {q(title)}"
    if notes_given:
        cmd += f" --notes {q(str(notes))}"
    for f in suite_files:
        cmd += f" --suite {q(str(f))}"
    res = render_results(
        csv_path,
        out_md,
        figures_dir=fig,
        readme=None if no_readme else readme,
        notes=notes,
        command=cmd,
        title=title,
        suite_files=suite_files,
    )
    click.echo(
        f"wrote {out_md} ({len(res['suites'])} suite(s), {len(res['figures'])} figure(s))"
        + (f"; updated {res['readme']}" if res["readme"] else ""),
        err=True,
    )
    for name, pm in res["partial_metrics"].items():
        click.echo(
            f"warning: suite {name}: some scored runs lack metrics their rows report elsewhere: "
            + ", ".join(f"{k} present in {h} of {n} runs" for k, (h, n) in pm.items())
            + " (scored before the metric existed, or rows written back by an older export: "
            "re-export them with `m4dgs-eval export` while their run folders exist)",
            err=True,
        )


@group.command()
@click.argument("keys", required=False, metavar="[KEY,KEY...]")
@click.option(
    "--csv",
    "csv_paths",
    multiple=True,
    type=click.Path(dir_okay=False),
    help="Runs CSV to read (repeat for several; rows of a later file replace those of the same "
    "(suite, scene, row, seed) by `suite merge`'s rules, e.g. results/runs.csv then a "
    "campaign's staged CSV).  [default: results/runs.csv]",
)
@click.option("--list", "list_only", is_flag=True, help="Only list the findings and their suites.")
def findings(keys, csv_paths, list_only):
    """Print the verdicts of findings KEY (eval/study/findings.yaml; default: every finding whose
    suite has a scored run in the CSVs) as the results page's Findings section shows them: each
    comparison's paired difference with its interval, the verdict before and after Holm's
    correction within the finding, over scenes, and whether the scenes differ. Reads any runs
    CSV, so a pre-registered finding can be read from a campaign's own CSV before its rows are
    merged into the committed one."""
    from eval.records.runs_csv import SCORED, merge_rows, read_runs_csv
    from eval.study.findings import FINDINGS, evaluate_finding, finding_markdown

    if list_only:
        for f in FINDINGS:
            click.echo(f"{f.key}\tsuite {f.suite}\t{f.title}")
        return
    paths = csv_paths or ("results/runs.csv",)
    rows: list = []
    for p in paths:
        if not Path(p).is_file():
            raise click.BadParameter(f"no such runs CSV: {p}", param_hint="--csv")
        rows = merge_rows(rows, read_runs_csv(p))
    present = {r["suite"] for r in rows if r.get("status") == SCORED}
    by_key = {f.key: f for f in FINDINGS}
    wanted = parse_names(keys)
    if wanted is None:
        chosen = [f for f in FINDINGS if f.suite in present]
        if not chosen:
            raise click.ClickException(
                f"no finding's suite has a scored run in {', '.join(paths)} "
                "(`m4dgs-eval report findings --list` lists the findings and their suites)"
            )
    else:
        unknown = [k for k in wanted if k not in by_key]
        if unknown:
            raise click.BadParameter(
                f"unknown finding(s) {', '.join(unknown)}; known: {', '.join(by_key)}",
                param_hint="KEY",
            )
        chosen = [by_key[k] for k in wanted]
    for f in chosen:
        res = evaluate_finding(f, rows) if f.suite in present else None
        click.echo("\n".join(finding_markdown(f, res)))
