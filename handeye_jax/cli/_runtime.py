"""What a command needs before JAX's first computation: XLA's flags, the persistent compilation
cache, and the command's modules imported while Ctrl-C waits."""

from __future__ import annotations

import importlib
import os
import sys

from .._core import interrupts


def start_jax(*modules: str, announce: bool = False) -> None:
    """Before JAX's first computation: XLA's flags and the persistent compilation cache (and
    ``announce`` each program compiled for it); the command's ``modules`` imported: each
    ``folder.name`` (of this package) loads what the folder's ``name`` needs."""
    with interrupts.deferred():  # the imports take a second or more: Ctrl-C waits for them
        from .._jax import vectorise_small_loops

        vectorise_small_loops()
        _enable_compilation_cache(announce)
        for name in modules:
            folder, _, attribute = name.rpartition(".")
            getattr(importlib.import_module(f"..{folder}", __package__), attribute)


def _enable_compilation_cache(announce: bool = False) -> None:
    """Keep XLA's compiled programs between runs, so only the first run pays for compiling.

    The command line owns its process, so it may set this global JAX option; the library does
    not. ``HANDEYE_JAX_CACHE_DIR`` moves the cache; ``HANDEYE_JAX_CACHE_DIR=off`` turns it off.
    """
    where = os.environ.get("HANDEYE_JAX_CACHE_DIR")
    if where == "off":
        return
    if where is None:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        where = os.path.join(base, "handeye-jax", "xla")
    try:
        os.makedirs(where, exist_ok=True)
    except OSError:
        return  # an unwritable cache only costs time
    import jax

    from .._jax import store_programs

    jax.config.update("jax_compilation_cache_dir", where)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    # Beside XLA's compiled code, the programs themselves: a warm run neither traces nor lowers.
    store_programs(os.path.join(where, "programs"), _announce if announce else None)


def _announce(name: str) -> None:
    from tqdm import tqdm  # above a progress bar, if one is drawn

    short = name.rsplit(".", 1)[-1].lstrip("_")
    tqdm.write(f"compiling {short} for this machine (once: later runs load it)", file=sys.stderr)
