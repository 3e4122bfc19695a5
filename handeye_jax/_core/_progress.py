"""A tqdm bar that never leaves a half-drawn line behind, and a safe point for Ctrl-C."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator

from tqdm.auto import tqdm

from . import _interrupt


class _Bar(tqdm):
    def update(self, n: float = 1) -> bool | None:
        # Between two chunks of work: where a Ctrl-C that a callback swallowed stops the run.
        _interrupt.check()
        return super().update(n)


@contextlib.contextmanager
def progress_bar(total: int, desc: str, enabled: bool, unit: str = "it") -> Iterator[tqdm]:
    """A progress bar on stderr; a run that ends early shrinks the total to what was done,
    so the closed bar reads complete rather than stopping part-way."""
    bar = None
    try:
        # A Ctrl-C while the bar draws or closes waits for the line's end, so that the message
        # it prints starts on a line of its own.
        with _interrupt.deferred():
            bar = _Bar(
                total=total, desc=desc, unit=unit, disable=not enabled, file=sys.stderr,
                leave=True, dynamic_ncols=True,
            )  # fmt: skip
        yield bar
        if not bar.disable and bar.n < bar.total:
            bar.total = bar.n
            bar.refresh()
    finally:
        if bar is not None:
            with _interrupt.deferred():
                bar.close()
