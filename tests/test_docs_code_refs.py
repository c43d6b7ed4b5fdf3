"""Every dotted code name the README and docs/ cite in backticks (`eval.inspect.pairs`,
`m4dgs.outputs.render.render_run`, ...), and every one the code's comments and docstrings name, is
a module or an attribute of one that imports here, so the docs keep up when code moves
(docs/results.md, generated, is left out)."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
GENERATED = {"results.md"}
# names that look dotted but are not code: a lock file's name, a click context key
NOT_CODE = {"m4dgs.flock", "m4dgs.debug"}
REF = re.compile(r"`((?:eval|m4dgs|benchgen)(?:\.[A-Za-z_][A-Za-z_0-9]*)+)")
# in code: a dotted name not inside a path or another name; file names (x.py, x.yaml) left out
CODE_REF = re.compile(r"(?<![A-Za-z_0-9./-])((?:eval|m4dgs|benchgen)(?:\.[A-Za-z_][A-Za-z_0-9]*)+)")
FILE_SUFFIXES = (".py", ".yaml", ".json", ".md", ".pt", ".csv", ".png", ".txt")
SOURCES = [ROOT / d for d in ("eval", "m4dgs", "benchgen", "bench")]


def resolves(ref: str) -> bool:
    """Whether `ref` is a module, or an attribute path under the longest importable prefix."""
    parts = ref.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        try:
            for name in parts[k:]:
                obj = getattr(obj, name)
        except AttributeError:
            return False
        return True
    return False


def test_resolves_tells_a_moved_name_from_a_present_one():
    assert resolves("eval.inspect.pairs") and resolves("eval.stats.holm")
    assert not resolves("eval.pairs") and not resolves("eval.stats.no_such_name")


def test_every_dotted_code_name_in_the_docs_resolves():
    bad = []
    for page in PAGES:
        if page.name in GENERATED:
            continue
        for m in REF.finditer(page.read_text(encoding="utf-8")):
            ref = m.group(1)
            if ref not in NOT_CODE and not resolves(ref):
                bad.append(f"{page.relative_to(ROOT)}: {ref}")
    assert not bad, "names that no longer import:\n" + "\n".join(sorted(set(bad)))


def test_every_dotted_code_name_in_the_code_resolves():
    bad = []
    for top in SOURCES:
        for path in sorted(top.rglob("*.py")):
            for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if line.lstrip().startswith(("import ", "from ")):
                    continue
                for m in CODE_REF.finditer(line):
                    ref = m.group(1)
                    if ref in NOT_CODE or ref.endswith(FILE_SUFFIXES) or resolves(ref):
                        continue
                    bad.append(f"{path.relative_to(ROOT)}:{i}: {ref}")
    assert not bad, "names that no longer import:\n" + "\n".join(bad)
