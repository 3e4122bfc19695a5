"""The transform chain: pluggable models of the camera mount, tablet pose and pen (HTM, DH),
the stage-2 correction, the known :class:`Rig` they run on, and the hand command they give
(eqs. 8 and 25). A new model is a final :class:`AbstractModel` subclass with a unique
``name``, its parameters' units, ranges and groups, found by :func:`model_registry` once its
class exists (in a private module here or in the user's own code)."""

from __future__ import annotations

from ._affine import AffinePair
from ._base import AbstractCorrection, AbstractModel, AbstractParametric
from ._command import Targets, hand_command
from ._dh import DHModel
from ._htm import HTMModel
from ._rig import Rig


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
    "Rig",
    "Targets",
    "get_model",
    "hand_command",
    "model_registry",
]
