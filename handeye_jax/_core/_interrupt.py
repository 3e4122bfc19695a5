"""Ctrl-C in the command line: the run ends with exit 130 and every file as it was.

Python turns SIGINT into a KeyboardInterrupt wherever the main thread happens to be. When that
is a callback run by the garbage collector (JAX's ``_xla_gc_callback``) or by C++, the
exception is printed as "Exception ignored" and swallowed, and the run goes on to write its
output. So while :func:`recording_interrupts` is active, SIGINT is also *recorded*:

* :func:`check` raises KeyboardInterrupt again at a safe point (a progress bar's update, the
  command's end) if one was swallowed, and at the end of a :func:`deferred` block (the
  imports, during which a KeyboardInterrupt inside a C extension can crash the process);
* the atomic writers call :func:`before_writing` before the first byte of any output: an
  interrupt recorded by then stops the run there, with nothing written. From that moment
  on the run no longer stops: it finishes writing (every output, or none on failure), which
  takes milliseconds, and an interrupt that arrives then is too late to change anything.

Outside :func:`recording_interrupts` (a library user's own program) every function here does
nothing, and SIGINT keeps its usual meaning.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator


class _State:
    active = False  # recording_interrupts() is in force
    received = False  # a SIGINT came while active
    deferred = False  # in deferred(): record only
    writing = False  # outputs are being written: SIGINT no longer stops the run


def _on_sigint(signum, frame) -> None:
    _State.received = True
    if not (_State.deferred or _State.writing):
        raise KeyboardInterrupt


def _quiet_unraisable(previous):
    def hook(unraisable) -> None:
        # Our own interrupt, swallowed by a callback: it is recorded and acted on at the next
        # check, so the user needs no "Exception ignored" traceback about it.
        if _State.received and issubclass(unraisable.exc_type, KeyboardInterrupt):
            return
        previous(unraisable)

    return hook


@contextlib.contextmanager
def recording_interrupts() -> Iterator[None]:
    """Record SIGINT (and raise KeyboardInterrupt) until the block ends; then restore the
    previous handler. Only in the main thread, where Python runs signal handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous_handler = signal.signal(signal.SIGINT, _on_sigint)
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_unraisable(previous_hook)
    _State.active, _State.received, _State.writing = True, False, False
    try:
        yield
    finally:
        _State.active = False
        sys.unraisablehook = previous_hook
        if previous_handler is not None:  # None: set outside Python, cannot be restored
            signal.signal(signal.SIGINT, previous_handler)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Record SIGINT without raising until the block ends, then :func:`check`: for imports,
    where a KeyboardInterrupt inside a C extension's initialisation can crash the process."""
    _State.deferred = True
    try:
        yield
    finally:
        _State.deferred = False
    check()


def stop_recording() -> None:
    """Give SIGINT back to Python's default handler for the rest of the block: for a command
    that Ctrl-C ends normally (a server), whose writes happen while it runs."""
    if _State.active and threading.current_thread() is threading.main_thread():
        _State.active = False
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pending() -> bool:
    """Whether a SIGINT came while recording, before any output was written."""
    return _State.active and _State.received and not _State.writing


def check() -> None:
    """Raise KeyboardInterrupt if :func:`pending` (its first one may have been swallowed)."""
    if pending():
        raise KeyboardInterrupt


def before_writing() -> None:
    """Called before an output is written: stop here if a SIGINT came; otherwise the run
    writes its outputs without stopping (see the module's docstring)."""
    if not _State.active or threading.current_thread() is not threading.main_thread():
        return
    check()
    _State.writing = True
