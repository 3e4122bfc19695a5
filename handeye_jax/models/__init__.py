"""Pluggable models. A new model is one new file in this folder defining a final
:class:`AbstractModel` subclass with a unique ``name``; it is found here automatically."""

from __future__ import annotations

import importlib
import pkgutil

from ._base import AbstractCorrection, AbstractModel, AbstractParametric
from .affine import AffinePair
from .dh import DHModel
from .htm import HTMModel

for _info in pkgutil.iter_modules(__path__):
    if not _info.name.startswith("_"):
        importlib.import_module(f"{__name__}.{_info.name}")


def _final_subclasses(cls: type) -> list[type]:
    out = []
    for sub in cls.__subclasses__():
        out.extend(_final_subclasses(sub) if sub.__subclasses__() else [sub])
    return out


def model_registry() -> dict[str, type[AbstractModel]]:
    """Every stage-1 model class by its ``name``."""
    return {cls.name: cls for cls in _final_subclasses(AbstractModel)}


def get_model(name: str) -> type[AbstractModel]:
    """The model class called ``name`` (``"htm"``, ``"dh"``, …)."""
    registry = model_registry()
    if name not in registry:
        raise KeyError(f"unknown model {name!r}; known: {', '.join(sorted(registry))}")
    return registry[name]


__all__ = [
    "AbstractCorrection",
    "AbstractModel",
    "AbstractParametric",
    "AffinePair",
    "DHModel",
    "HTMModel",
    "get_model",
    "model_registry",
]
