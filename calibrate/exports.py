"""Sub-package exports resolved on first use (PEP 562): ``calibrate.io.read_c3d`` imports
calibrate.io.c3d only when asked for, so importing one sub-package does not import the others
(and no import cycle arises between sub-packages that use each other's modules)."""

from __future__ import annotations

import importlib
from collections.abc import Callable


def lazy_exports(package: str, spec: str) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """``__getattr__``, ``__dir__`` and ``__all__`` for `package`, exporting names from its modules:
    `spec` is ``.module:name,name .other:name ...`` (module paths relative to the package)."""
    table: dict[str, str] = {}
    for item in spec.split():
        module, _, names = item.partition(":")
        for name in names.split(","):
            table[name] = module

    def __getattr__(name: str) -> object:
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(module, package), name)

    def __dir__() -> list[str]:
        return sorted(table)

    return __getattr__, __dir__, sorted(table)
