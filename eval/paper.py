"""The paper's numbers (eval/paper_values.yaml) for the "Paper" columns of the result tables.

    load_paper_values()  -> {table key: PaperTable(key, source, rows {row: {metric: value}},
    paper_rows {row: label})} paper_records()      -> [{"table", "row", "paper_row", "metric",
    "value", "source"}, ...] (flat form)

Row names are the rows of our suites (eval/suites/*/*.yaml); a suite table refers to a paper table
with `paper: KEY`."""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Dict, List, Optional

from m4dgs.core.io import read_yaml


@dataclass
class PaperTable:
    key: str
    source: str
    rows: Dict[str, Dict[str, float]] = field(default_factory=dict)
    paper_rows: Dict[str, str] = field(default_factory=dict)

    def value(self, row: str, metric: str) -> Optional[float]:
        return self.rows.get(row, {}).get(metric)


def paper_values_path() -> Path:
    return Path(str(resources.files("eval"))) / "paper_values.yaml"


def load_paper_values(path=None) -> Dict[str, PaperTable]:
    """Parse the paper-values file; raises ValueError naming the table/row/key of a malformed
    entry."""
    path = Path(path) if path is not None else paper_values_path()
    data = read_yaml(path) or {}
    out: Dict[str, PaperTable] = {}
    for key, t in data.items():
        if (
            not isinstance(t, dict)
            or not isinstance(t.get("source"), str)
            or not isinstance(t.get("rows"), dict)
        ):
            raise ValueError(f"{path}: table {key!r} needs 'source' (text) and 'rows' (mapping)")
        pt = PaperTable(str(key), " ".join(t["source"].split()))
        for row, vals in t["rows"].items():
            if not isinstance(vals, dict):
                raise ValueError(f"{path}: {key}.rows.{row}: expected a mapping")
            pt.paper_rows[str(row)] = str(vals.get("paper_row", row))
            metrics = {}
            for m, v in vals.items():
                if m == "paper_row":
                    continue
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ValueError(f"{path}: {key}.rows.{row}.{m}: expected a number, got {v!r}")
                metrics[str(m)] = float(v)
            pt.rows[str(row)] = metrics
        out[str(key)] = pt
    return out


def paper_records(path=None) -> List[dict]:
    """The paper values as flat records: table, row (our row name), paper_row, metric, value,
    source."""
    return [
        {
            "table": t.key,
            "row": row,
            "paper_row": t.paper_rows[row],
            "metric": m,
            "value": v,
            "source": t.source,
        }
        for t in load_paper_values(path).values()
        for row, vals in t.rows.items()
        for m, v in vals.items()
    ]
