"""Suite files: which scenes make a benchmark and with which exposure settings
(scenes/suites/<name>.yaml).

Built-in suites and scenes ship as package data of the ``scenes`` package;
``load_suite('syn-exp-3')`` finds them through importlib.resources,
``load_suite('path/to/suite.yaml')`` reads any file. Scene entries are names (``lamp-room-orbit`` ->
``<scenes dir>/lamp-room-orbit.yaml``, where the scenes dir is the suite folder's parent) or paths
relative to the suite file."""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import List, Union

from m4dgs.core import io as mio

from .spec import SpecError, read_yaml, validate_suite


@dataclass
class Suite:
    name: str
    scenes: List[Path]  # resolved scene YAML paths, in order
    observed: List[float]  # observed exposure levels (training frames cycle through them)
    novel: List[float] = field(default_factory=list)  # novel levels (test frames only)
    schedule: str = "alternating"  # benchgen.exposure.SCHEDULES
    description: str = ""
    path: Path = Path()
    placement: str = (
        "require"  # "require": clips must meet the exposure-placement targets; "warn": only warn
    )

    @property
    def scene_names(self) -> List[str]:
        return [p.stem for p in self.scenes]


def builtin_scenes_dir() -> Path:
    """Folder of the shipped scene specs (the ``scenes`` package)."""
    return Path(str(resources.files("scenes")))


def builtin_suites() -> List[str]:
    """Names of the shipped suites."""
    return sorted(p.stem for p in (builtin_scenes_dir() / "suites").glob("*.yaml"))


def find_scene_suite(name_or_path: Union[str, Path]) -> Path:
    """A benchgen scene suite: a suite YAML file by path, or the name of a shipped one
    (scenes/suites/<name>.yaml). Raises SpecError naming the shipped suites."""
    path = mio.find_file(name_or_path, builtin_scenes_dir() / "suites")
    if path is None:
        raise SpecError(
            str(name_or_path),
            "<suite>",
            f"a suite file or one of the built-in suites {builtin_suites()}",
        )
    return path


def load_suite(name_or_path: Union[str, Path]) -> Suite:
    """Load and validate a suite by built-in name or path; every listed scene file must exist."""
    path = find_scene_suite(name_or_path)
    spec = validate_suite(read_yaml(path), file=str(path))
    scenes_dir = path.resolve().parent.parent
    resolved = []
    for i, entry in enumerate(spec["scenes"]):
        if entry.endswith((".yaml", ".yml")):
            p = (path.resolve().parent / entry).resolve()
        else:
            p = scenes_dir / f"{entry}.yaml"
        if not p.exists():
            raise SpecError(str(path), f"scenes[{i}]", f"an existing scene file ({p})", entry)
        resolved.append(p)
    ex = spec["exposures"]
    return Suite(
        spec["name"],
        resolved,
        list(ex["observed"]),
        list(ex["novel"]),
        ex["schedule"],
        spec["description"],
        path,
        spec["placement"],
    )


def builtin_scene_suites(scene_path: Union[str, Path]) -> List[Suite]:
    """The shipped suites that list a scene spec; [] for a spec outside the shipped scenes folder
    (the user's own)."""
    p = Path(scene_path).resolve()
    if p.parent != builtin_scenes_dir().resolve():
        return []
    suites = [load_suite(name) for name in builtin_suites()]
    return [s for s in suites if p in {q.resolve() for q in s.scenes}]


def is_builtin_scene(scene_path: Union[str, Path]) -> bool:
    """True for a scene spec shipped with the project (the ``scenes`` package's folder)."""
    p = Path(scene_path).resolve()
    return p.parent == builtin_scenes_dir().resolve() and p.suffix in (".yaml", ".yml")
