"""A pair of things, one per stage, by name: the stage-1 model's and the stage-2 correction's."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")
U = TypeVar("U")


@dataclass(frozen=True)
class Stages(Generic[T]):
    """One ``T`` per stage: ``stage1`` (the model) and ``stage2`` (the affine correction)."""

    stage1: T
    stage2: T

    def map(self, f: Callable[[T], U]) -> Stages[U]:
        """``f`` of each stage's value."""
        return Stages(f(self.stage1), f(self.stage2))

    def items(self) -> tuple[tuple[str, T], tuple[str, T]]:
        """``("stage1", stage1), ("stage2", stage2)``: for the places that write both by name."""
        return ("stage1", self.stage1), ("stage2", self.stage2)
