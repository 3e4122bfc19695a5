"""Ctrl-C in the command line: the run ends with exit 130 and every file as it was.

SIGTERM (``kill``, a service manager, a closed session) is handled the same way: the run
ends with exit 143 (128 + 15) and every file as it was, or finishes the writing it had begun.

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

#: The signals handled as Ctrl-C is (where the platform has them).
SIGNALS = (signal.SIGINT, *([signal.SIGTERM] if hasattr(signal, "SIGTERM") else []))


class _State:
    active = False  # recording_interrupts() is in force
    received = False  # a SIGINT or SIGTERM came while active
    signum = signal.SIGINT  # the last one that came
    deferred = False  # in deferred(): record only
    writing = False  # outputs are being written: SIGINT no longer stops the run


def _on_sigint(signum, frame) -> None:
    _State.received = True
    _State.signum = signum
    if not (_State.deferred or _State.writing):
        raise KeyboardInterrupt


def _default_handler(signum, frame) -> None:
    # A server's SIGTERM ends it as its Ctrl-C does (Python's default handler for SIGINT).
    raise KeyboardInterrupt


def stopped_by() -> tuple[str, int]:
    """What ended the run after a KeyboardInterrupt: ``("interrupted", 130)`` for Ctrl-C,
    ``("terminated", 143)`` for SIGTERM (the word for the message, the exit status)."""
    if _State.signum == getattr(signal, "SIGTERM", None):
        return "terminated", 128 + int(_State.signum)
    return "interrupted", 130


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
    """Record SIGINT and SIGTERM (and raise KeyboardInterrupt) until the block ends; then
    restore the previous handlers. Only in the main thread, where Python runs signal
    handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, _on_sigint) for s in SIGNALS}
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_unraisable(previous_hook)
    _State.active, _State.received, _State.writing = True, False, False
    _State.signum = signal.SIGINT
    try:
        yield
    finally:
        _State.active = False
        sys.unraisablehook = previous_hook
        for s, handler in previous.items():
            if handler is not None:  # None: set outside Python, cannot be restored
                signal.signal(s, handler)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Record SIGINT without raising until the block ends, then :func:`check`: for imports,
    where a KeyboardInterrupt inside a C extension's initialisation can crash the process."""
    outer = _State.deferred  # nested: the outermost block checks
    _State.deferred = True
    try:
        yield
    finally:
        _State.deferred = outer
    if not outer:
        check()


def stop_recording() -> None:
    """Give SIGINT back to Python's default handler for the rest of the block, and have
    SIGTERM do the same: for a command that Ctrl-C ends normally (a server), whose writes
    happen while it runs."""
    if _State.active and threading.current_thread() is threading.main_thread():
        _State.active = False
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for s in SIGNALS[1:]:
            signal.signal(s, _default_handler)


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
