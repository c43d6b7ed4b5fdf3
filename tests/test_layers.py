"""The package layers and their dependency rule (docs/architecture.md), checked on every import,
and the absence of import cycles anywhere in m4dgs/, benchgen/ and eval/.

Every `import` / `from ... import` in m4dgs/, benchgen/ and eval/ (module level or inside a
function, relative imports resolved) is mapped to the layer of the importing and of the imported
module; an import a layer is not allowed to make fails the test with file, line and module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# layer of a module: the longest matching prefix wins
LAYERS = {
    "m4dgs.core": "core",
    "m4dgs.clip": "formats",
    "m4dgs.formats": "formats",  # other projects' layouts: names and conversions, both directions
    "m4dgs.run": "formats",
    "m4dgs.priors": "priors",
    "m4dgs.footage": "priors",  # own footage -> clip: frames, exposures and priors
    "m4dgs.footage_options": "priors",  # the command-line options of the prior files it reads
    "m4dgs.footage_formats": "priors",  # other projects' dataset folders -> clip
    "m4dgs.raster": "raster",
    "m4dgs.losses": "losses",
    "m4dgs.model": "model",
    "m4dgs.outputs": "outputs",
    "m4dgs.training": "training",
    "m4dgs.viewer": "viewer",  # `m4dgs view`: the browser viewer of a run or a clip
    "m4dgs.cli": "app",
    "m4dgs.__main__": "app",
    "m4dgs": "package",
    "benchgen": "benchgen",
    # eval, bottom to top (docs/architecture.md, "eval's layers")
    "eval": "eval",  # metrics/, stats, paper values, table and figure rendering, conventions
    "eval.records": "eval-records",  # suite definitions, the runs CSV, a suite's data and tables
    "eval.experiments": "eval-experiments",  # score, run, campaign, export run folders
    "eval.study": "eval-study",  # the paper's findings and the controls (data + verdicts)
    "eval.inspect": "eval-inspect",  # pairs, repeats, regions, error maps, peaks, responses
    "eval.report": "eval-report",  # the results page and its figures
    "eval.cli": "eval-cli",  # `m4dgs-eval`: one module per command group
    "eval.__main__": "eval-cli",
}

EVAL_LAYERS = {
    "eval-records",
    "eval-experiments",
    "eval-study",
    "eval-inspect",
    "eval-report",
}

# which layers each layer may import (its own layer is always allowed)
ALLOWED = {
    "package": set(),
    "core": set(),
    "formats": {"core"},
    "priors": {"core", "formats"},
    "raster": {"core"},
    "losses": {"core"},
    "model": {"core", "formats", "raster"},
    "outputs": {"core", "formats", "raster", "model"},
    "training": {"core", "formats", "priors", "raster", "losses", "model", "outputs"},
    "viewer": {"core", "formats", "raster", "model", "outputs"},
    "app": {"core", "formats", "priors", "raster", "losses", "model", "outputs", "training"}
    | {"viewer"},
    # benchgen renders clips: it shares only the maths and the clip format with the method
    "benchgen": {"core", "formats"},
    # eval's metrics, statistics, tables and figures score files: no model, no trainer
    "eval": {"core", "formats"},
    # each eval layer may import the eval layers below it (and benchgen's suites and clips)
    "eval-records": {"core", "formats", "eval", "benchgen"},
    "eval-experiments": {"core", "formats", "eval", "benchgen", "eval-records"},
    "eval-study": {"core", "formats", "eval", "eval-records"},
    "eval-inspect": {"core", "formats", "eval", "benchgen", "eval-records", "eval-experiments"}
    | {"eval-study"},
    "eval-report": {"core", "formats", "eval", "eval-records", "eval-study"},
    "eval-cli": {"core", "formats", "eval", "benchgen"} | EVAL_LAYERS,
}

# the only modules of upper layers that eval's drivers may import: the trainer, the renderer,
# the trained model and the variant registry (`m4dgs-eval run` trains and renders suites)
DRIVER_ENTRY_POINTS = {
    "m4dgs.training.pipeline",
    "m4dgs.training.variants",
    "m4dgs.outputs.render",
    "m4dgs.outputs.views",
    "m4dgs.model.trained",
}

# the only module of an upper layer benchgen may import: the readers of a user's prior files
# (`benchgen from-hdr` reads depth, tracks and flow as `m4dgs import-clip` does)
BENCHGEN_ENTRY_POINTS = {"m4dgs.footage", "m4dgs.footage_options"}


def entry_point_ok(src_layer: str, target: str) -> bool:
    """Whether an import outside the layer rule is one of the named entry points."""
    points = {
        # a suite's rows name variants: the registry checks them (eval.records.suite)
        "eval-records": {"m4dgs.training.variants"},
        "eval-experiments": DRIVER_ENTRY_POINTS,
        "eval-inspect": DRIVER_ENTRY_POINTS,
        "eval-cli": DRIVER_ENTRY_POINTS,
        "benchgen": BENCHGEN_ENTRY_POINTS,
    }.get(src_layer, set())
    return any(target == e or target.startswith(e + ".") for e in points)


def layer_of(module: str) -> str | None:
    best = None
    for prefix, layer in LAYERS.items():
        if (module == prefix or module.startswith(prefix + ".")) and (
            best is None or len(prefix) > len(best[0])
        ):
            best = (prefix, layer)
    return best[1] if best else None


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(path: Path):
    """(line, imported module) for every import of the file, relative ones resolved."""
    mod = module_name(path)
    pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            # `from m4dgs.core import camera` imports the module m4dgs.core.camera
            for a in node.names:
                sub = f"{target}.{a.name}"
                yield node.lineno, sub if layer_of(sub) and _is_module(sub) else target


def _is_module(name: str) -> bool:
    p = ROOT / Path(*name.split("."))
    return p.with_suffix(".py").exists() or (p / "__init__.py").exists()


SOURCES = sorted(p for top in ("m4dgs", "benchgen", "eval") for p in (ROOT / top).rglob("*.py"))


def violations():
    out = []
    for path in SOURCES:
        src_layer = layer_of(module_name(path))
        for line, target in imports_of(path):
            dst_layer = layer_of(target)
            if dst_layer is None or dst_layer == src_layer:
                continue
            if target == "m4dgs":  # `import m4dgs` itself
                continue
            ok = dst_layer in ALLOWED[src_layer]
            ok = ok or entry_point_ok(src_layer, target)
            if not ok:
                out.append(
                    f"{path.relative_to(ROOT)}:{line}: {src_layer} imports {target} ({dst_layer})"
                )
    return out


def test_every_source_file_has_a_layer():
    assert SOURCES, "no sources found"
    missing = [str(p.relative_to(ROOT)) for p in SOURCES if layer_of(module_name(p)) is None]
    assert not missing
    # a module directly under m4dgs/ falls back to "package" unless LAYERS names it: name it
    unnamed = [
        str(p.relative_to(ROOT))
        for p in SOURCES
        if layer_of(module_name(p)) == "package" and module_name(p) != "m4dgs"
    ]
    assert not unnamed, f"modules without a layer of their own in LAYERS: {unnamed}"


def test_import_layers():
    bad = violations()
    assert not bad, "imports against the layer rule (docs/architecture.md):\n" + "\n".join(bad)


@pytest.mark.parametrize(
    "src, target, expect_ok",
    [
        ("m4dgs.core.camera", "m4dgs.training.config", False),
        ("m4dgs.model.gaussians", "m4dgs.training.densify", False),
        ("m4dgs.model.trained", "m4dgs.core.io", True),
        ("benchgen.render", "eval.metrics.temporal", False),
        ("benchgen.make", "m4dgs.clip", True),
        ("eval.metrics.hdr", "m4dgs.model.trained", False),
        ("eval.experiments.score", "m4dgs.model.trained", True),
        ("eval.experiments.score", "m4dgs.training.stage2", False),
        ("eval.records.runs_csv", "eval.cli", False),
        ("eval.report.page", "eval.cli", False),
        ("eval.inspect.pairs", "eval.report.page", False),
        ("eval.study.findings", "eval.inspect.pairs", False),
        ("eval.records.suite", "eval.experiments.runner", False),
        ("eval.stats", "eval.records.runs_csv", False),
        ("eval.report.page", "eval.study.controls", True),
        ("eval.inspect.repeats", "eval.experiments.runner", True),
        ("eval.cli.inspect", "eval.inspect.pairs", True),
        ("benchgen.from_hdr", "m4dgs.footage", True),
        ("benchgen.cli", "m4dgs.footage_options", True),
        ("benchgen.cli", "m4dgs.cli", False),
        ("benchgen.from_hdr", "m4dgs.priors.camera_init", False),
    ],
)
def test_rule_itself(src, target, expect_ok):
    """The checker's own verdicts on known cases (so a broken checker cannot pass silently)."""
    s, d = layer_of(src), layer_of(target)
    ok = s == d or d in ALLOWED[s]
    ok = ok or entry_point_ok(s, target)
    assert ok is expect_ok


def _module_of(name: str) -> str | None:
    """The source module an imported name lives in (the longest existing prefix), or None when
    it is not one of the repository's."""
    parts = name.split(".")
    while parts:
        if _is_module(".".join(parts)):
            return ".".join(parts)
        parts.pop()
    return None


def import_graph() -> dict:
    """{module: {imported module}} over every import of the sources (module level or in a
    function), a package's __init__ counting as the package."""
    graph = {}
    for path in SOURCES:
        mod = module_name(path)
        deps = graph.setdefault(mod, set())
        for _line, target in imports_of(path):
            dst = _module_of(target)
            if dst and dst != mod:
                deps.add(dst)
    return graph


def cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    found = cycles(import_graph())
    assert not found, "import cycles (a module reaches itself through its imports):\n" + "\n".join(
        " <-> ".join(c) for c in found
    )


def test_cycle_finder_itself():
    """The cycle finder on known graphs (so a broken finder cannot pass silently)."""
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set(), "c": {"b"}}) == []
