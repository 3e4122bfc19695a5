"""Folders that load their modules on first use (PEP 562), so that importing a folder costs
nothing until one of its names is used: the command line's ``--help`` and the robot's
``predict`` import no JAX."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping


def lazy_exports(
    package: str,
    exports: Mapping[str, tuple[str, ...]],
    modules: Mapping[str, str] | None = None,
) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """``__getattr__``, ``__dir__`` and ``__all__`` for a package's ``__init__``.

    Args:
        package: the package's ``__name__``.
        exports: each private module of the package (``"_dataset"``) and the names it gives.
        modules: private modules given whole, under a public name (``{"interrupts":
            "_interrupt"}``), for functions best read with their module's name.
    """
    where = {name: module for module, names in exports.items() for name in names}
    whole = dict(modules or {})

    def __getattr__(name: str) -> object:
        module = where.get(name)
        if name in whole:
            value = importlib.import_module(f"{package}.{whole[name]}")
        elif module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        else:
            value = getattr(importlib.import_module(f"{package}.{module}"), name)
        setattr(sys.modules[package], name, value)  # found at once the next time
        return value

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *where, *whole})

    return __getattr__, __dir__, sorted({*where, *whole})
