"""`import eval` finds the project's package however pytest is started.

tests/eval/ has no __init__.py; with the `pytest` console script (which, unlike
`python -m pytest`, does not put the working folder on sys.path) tests/ came first on sys.path
through tests/conftest.py, and `import eval` then found tests/eval/ as a namespace package: every
test that reads a shipped suite failed when run alone. pyproject.toml's `pythonpath = ["."]` puts
the checkout first.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_eval_is_the_package():
    import eval

    assert eval.__file__ is not None, f"eval resolved as a namespace package: {list(eval.__path__)}"
    assert Path(eval.__file__).resolve() == ROOT / "eval" / "__init__.py"


def test_pytest_script_run_alone_finds_the_package():
    script = Path(sys.executable).with_name("pytest")
    if not script.exists():
        pytest.skip(f"no pytest console script beside {sys.executable}")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run(
        [str(script), "-q", "-p", "no:cacheprovider", f"{__file__}::test_eval_is_the_package"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
