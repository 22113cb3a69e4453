"""Names and modules that moved in 0.2 (the package by stage) keep working for one release,
with a DeprecationWarning that says where they live now."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from types import ModuleType
from typing import Any

# Old module path -> new module path.
MOVED_MODULES = {
    "elastocap.camera": "elastocap.cameras",
    "elastocap.neighbors": "elastocap.geometry.neighbors",
    "elastocap.polar": "elastocap.geometry.polar",
    "elastocap.mesh_distance": "elastocap.geometry.mesh_distance",
    "elastocap.grid": "elastocap.hull.grid",
    "elastocap.sdf": "elastocap.hull.sdf",
    "elastocap.mls": "elastocap.elastic.mls",
    "elastocap.efg": "elastocap.elastic.efg",
    "elastocap.fit": "elastocap.elastic.fit",
    "elastocap.silhouette": "elastocap.silhouettes.background",
    "elastocap.hull_stage": "elastocap.pipeline.hull",
    "elastocap.fit_stage": "elastocap.pipeline.fit",
    "elastocap.body.stage": "elastocap.pipeline.body",
    "elastocap.body.synth": "elastocap.synth.body",
    "elastocap.pictures": "elastocap.pipeline.pictures",
    "elastocap.report": "elastocap.pipeline.report",
    "elastocap.demo": "elastocap.pipeline.demo",
    "elastocap.cli": "elastocap.pipeline.cli",
}

# Old top-level name -> (module, name) where it lives now.
MOVED_NAMES = {
    "Figure": ("elastocap.synth", "CapsuleFigure"),
    "ring_rig": ("elastocap.synth", "ring_rig"),
    "write_synthetic_capture": ("elastocap.synth", "write_synthetic_capture"),
    "conjugate_gradient": ("elastocap.solvers", "conjugate_gradient"),
    "SparseCholesky": ("elastocap.solvers", "SparseCholesky"),
    "SolveStatus": ("elastocap.solvers", "SolveStatus"),
}


def moved_name(name: str) -> Any:
    """The object a moved top-level name refers to, with a DeprecationWarning."""
    if name not in MOVED_NAMES:
        raise AttributeError(f"module 'elastocap' has no attribute {name!r}")
    module, attribute = MOVED_NAMES[name]
    warnings.warn(
        f"elastocap.{name} moved to {module}.{attribute}; the old name goes in the next release",
        DeprecationWarning,
        stacklevel=3,
    )
    return getattr(importlib.import_module(module), attribute)


class _MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports an old module path as its new module (the same object), with a warning."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname in MOVED_MODULES:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec: Any) -> ModuleType:
        new = MOVED_MODULES[spec.name]
        warnings.warn(
            f"module {spec.name} moved to {new}; the old path goes in the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        return importlib.import_module(new)

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the new module is already imported."""


def install() -> None:
    """Make the old module paths importable (once per process)."""
    if not any(isinstance(finder, _MovedModuleFinder) for finder in sys.meta_path):
        sys.meta_path.append(_MovedModuleFinder())
