"""The package's layering (pyproject.toml's import-linter contracts), the top level's public
API, and the names and module paths that moved keeping working with a warning."""

from __future__ import annotations

import ast
import importlib
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import elastocap
from elastocap import _moved

PACKAGE = Path(elastocap.__file__).parent
ROOT = Path(__file__).resolve().parents[1]


def test_the_import_contracts_hold():
    lint = shutil.which("lint-imports")
    assert lint is not None, "import-linter is a test dependency (pip install '.[test]')"
    result = subprocess.run([lint, "--config", str(ROOT / "pyproject.toml")], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def _root_imports(path: Path) -> list[str]:
    """What a module takes from the root package ``elastocap`` other than ``_core``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module == "elastocap" and node.level == 0:
            found += [alias.name for alias in node.names if alias.name != "_core"]
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names if alias.name == "elastocap"]
    return found


def test_no_module_imports_the_root_package():
    # The contracts cannot see these (see ignore_imports in pyproject.toml): the root
    # re-exports every layer, so importing it from inside would hide any cycle.
    allowed = {PACKAGE / "pipeline" / "demo.py"}  # the top layer reports the version
    offenders = {
        str(path.relative_to(PACKAGE)): names
        for path in PACKAGE.rglob("*.py")
        if path.name != "__init__.py" and path not in allowed and (names := _root_imports(path))
    }
    assert offenders == {}


def test_the_top_level_holds_what_users_call():
    assert "ElasticModel" in elastocap.__all__ and "visual_hull" in elastocap.__all__
    for name in elastocap.__all__:
        assert getattr(elastocap, name) is not None
    # Synthetic data and solver internals live in their own packages.
    for moved in _moved.MOVED_NAMES:
        assert moved not in elastocap.__all__


@pytest.mark.parametrize("old", sorted(_moved.MOVED_NAMES))
def test_a_moved_name_warns_and_still_works(old):
    module, new = _moved.MOVED_NAMES[old]
    with pytest.warns(DeprecationWarning, match=rf"elastocap\.{old} moved to {module}\.{new}"):
        value = getattr(elastocap, old)
    assert value is getattr(importlib.import_module(module), new)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        elastocap.not_a_name  # noqa: B018


@pytest.mark.parametrize("old", sorted(_moved.MOVED_MODULES))
def test_a_moved_module_path_warns_and_is_the_new_module(old):
    # In a fresh interpreter, so that the first import (which warns) happens here.
    new = _moved.MOVED_MODULES[old]
    code = (
        "import importlib, warnings\n"
        "warnings.simplefilter('error', DeprecationWarning)\n"
        f"new = importlib.import_module({new!r})\n"
        "try:\n"
        f"    importlib.import_module({old!r})\n"
        "except DeprecationWarning as warning:\n"
        f"    assert {new!r} in str(warning), warning\n"
        "else:\n"
        "    raise SystemExit('no warning')\n"
        "warnings.simplefilter('ignore', DeprecationWarning)\n"
        f"assert importlib.import_module({old!r}) is new\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
