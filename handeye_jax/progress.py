"""A tqdm bar that never leaves a half-drawn line behind."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator

from tqdm.auto import tqdm


@contextlib.contextmanager
def progress_bar(total: int, desc: str, enabled: bool, unit: str = "it") -> Iterator[tqdm]:
    """A progress bar on stderr; a run that ends early shrinks the total to what was done,
    so the closed bar reads complete rather than stopping part-way."""
    bar = tqdm(
        total=total, desc=desc, unit=unit, disable=not enabled, file=sys.stderr, leave=True,
        dynamic_ncols=True,
    )  # fmt: skip
    try:
        yield bar
        if not bar.disable and bar.n < bar.total:
            bar.total = bar.n
            bar.refresh()
    finally:
        bar.close()
