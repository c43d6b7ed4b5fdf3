"""`m4dgs-eval` (also `python -m eval`; a plain `eval` typed in a shell runs the shell's builtin):
score runs, run experiment suites, print paper-style tables. The commands come in three groups
beside the two scorers (docs/eval.md, "Commands"):

    m4dgs-eval score RUN
        write RUN/metrics.json (renders what is missing through m4dgs)
    m4dgs-eval score-frames --clip C --pred D --name N
        score another method's frames (no m4dgs model)
    m4dgs-eval calibration CLIP ROW --out D
        a 2D calibration row's prediction (copy-nearest, flow-merge, dibr) for score-frames
    m4dgs-eval suite list
        the shipped experiment suites and their rows
    m4dgs-eval suite run tiny --preset tiny
        make clips, train and score every (scene, row) of a suite (resumable); --seeds 3 adds
        trainer seeds; --list-jobs prints the job list; `suite job` runs ONE job (docs/cluster.md)
    m4dgs-eval suite campaign NAME | suite export SUITE ...
        run the suites of a campaign in steps; collect a suite's runs into the runs CSV
    m4dgs-eval report table tiny
        the suite's tables (Markdown; --format latex|csv) and figures: mean +- 95 % CI over
        scenes x seeds, paired differences to the reference row, the paper's values and
        direction agreement
    m4dgs-eval report results
        the results page and the README's block from the runs CSV
    m4dgs-eval inspect pairs|repeats|regions|region-pairs|peaks|crf|error-maps ...
        look closer at runs: paired differences, repeats, where the error sits, runaways, CRFs

The flat names of before (`run`, `job`, `suites`, `table`, `results`, `campaign`, `export`,
`pairs`, `repeats`, `regions`, `region-pairs`, `peaks`, `crf`, `error-maps`) stay as hidden
aliases of the grouped commands (OLD_NAMES): scripts, the Makefile and campaign files keep working.

Each command imports the modules it runs when it runs: `m4dgs-eval --help` and the listing
commands stay free of torch (scoring), the trainer and the renderer stack, and tests can replace
the trainer's entry points.

Details: docs/eval.md.
"""

from __future__ import annotations

import copy
import os

import click

from eval.cli import calibration, inspect, report, score, suite
from m4dgs.core.errors import ReportingGroup

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

GROUPS = (suite.group, report.group, inspect.group)

# old flat name -> (group, command name in it)
OLD_NAMES = {
    "suites": ("suite", "list"),
    "run": ("suite", "run"),
    "job": ("suite", "job"),
    "campaign": ("suite", "campaign"),
    "export": ("suite", "export"),
    "table": ("report", "table"),
    "results": ("report", "results"),
    "pairs": ("inspect", "pairs"),
    "repeats": ("inspect", "repeats"),
    "regions": ("inspect", "regions"),
    "region-pairs": ("inspect", "region-pairs"),
    "peaks": ("inspect", "peaks"),
    "crf": ("inspect", "crf"),
    "error-maps": ("inspect", "error-maps"),
}


@click.group(cls=ReportingGroup, context_settings={"help_option_names": ["-h", "--help"]})
def main():
    """Evaluation of Mono4DGS-HDR runs: metrics, experiment suites, paper-style tables and
    figures."""


def hidden_alias(cmd: click.Command, name: str) -> click.Command:
    """A copy of CMD under NAME that `--help` does not list (same options, same callback)."""
    alias = copy.copy(cmd)
    alias.name, alias.hidden = name, True
    return alias


main.add_command(score.score)
main.add_command(score.score_frames_cmd)
main.add_command(calibration.calibration_cmd)
for _g in GROUPS:
    main.add_command(_g)
_by_name = {g.name: g for g in GROUPS}
for _old, (_group, _cmd) in OLD_NAMES.items():
    main.add_command(hidden_alias(_by_name[_group].commands[_cmd], _old))


if __name__ == "__main__":  # pragma: no cover
    main()
