"""The operator's terminal: what the server logs is printable, bounded in rate, and secret-free.

A request's path, a trial's label or a header is whoever sent it's text: each character that
is not printable (ESC, BEL, C1 controls, bidi overrides, lone surrogates) is shown as an
escape (``\\x1b``), so none can move the cursor, retitle the window or break the encoding of
standard output. The ``token`` in a URL's query is blanked however it is spelt
(``%74oken=``). A client can make the server log as fast as it can connect: past a burst, the
log keeps a steady rate and says how many lines it left out.
"""

from __future__ import annotations

import re
import sys
import threading
import time
import urllib.parse
from typing import TextIO

# A burst of lines, then at most this many a second; more are counted, not printed.
BURST_LINES = 50
LINES_PER_S = 10.0
_QUERY_FIELD = re.compile(r"([?&;])([^=&;#]*)=([^&;#]*)")


def printable(text: str, stream: TextIO | None = None) -> str:
    """``text`` with each non-printable character escaped (``\\x1b``, ``\\u202e``,
    ``\\ud800``), and what ``stream``'s encoding cannot write as a backslash escape."""
    out = "".join(c if c.isprintable() else _escape(c) for c in text)
    encoding = getattr(stream, "encoding", None)
    if encoding:
        out = out.encode(encoding, "backslashreplace").decode(encoding)
    return out


def _escape(c: str) -> str:
    code = ord(c)
    if code < 0x100:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}"


def blank_secret(target: str) -> str:
    """A request target with the value of every query field named ``token`` (after decoding:
    ``%74oken`` too) replaced by ``[secret]``."""

    def blank(m: re.Match[str]) -> str:
        name = urllib.parse.unquote_plus(m[2], errors="replace")
        return f"{m[1]}{m[2]}=[secret]" if name == "token" else m[0]

    return _QUERY_FIELD.sub(blank, target)


class Log:
    """Lines to ``stream`` (standard error), escaped, at most :data:`BURST_LINES` at once and
    :data:`LINES_PER_S` a second; ``quiet`` prints nothing. Safe from any thread."""

    def __init__(self, quiet: bool = False, stream: TextIO | None = None):
        self.quiet = quiet
        self.stream = stream
        self._tokens = float(BURST_LINES)
        self._last = time.monotonic()
        self._dropped = 0
        self._lock = threading.Lock()

    def line(self, text: str) -> None:
        """Write one line (its own newlines escaped too), if the rate allows."""
        if self.quiet:
            return
        stream = self.stream or sys.stderr
        with self._lock:
            now = time.monotonic()
            self._tokens = min(BURST_LINES, self._tokens + (now - self._last) * LINES_PER_S)
            self._last = now
            if self._tokens < 1:
                self._dropped += 1
                return
            self._tokens -= 1
            out = printable(text, stream) + "\n"
            if self._dropped:
                out = f"({self._dropped} log lines not shown: too many at once)\n" + out
                self._dropped = 0
            try:
                stream.write(out)
                stream.flush()
            except (OSError, ValueError):  # a closed terminal: nothing to tell
                pass

    def block(self, text: str) -> None:
        """A traceback or other text of several lines, as one entry of the rate."""
        self.line(text.rstrip("\n").replace("\n", " | "))
