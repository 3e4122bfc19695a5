"""HTTP/1.1 for the tablet server: asyncio's connections, h11's parser, bounds on both.

No stranger on the network may stall the operator, with or without the secret:

* **A cap.** At most ``max_connections`` connections are held (fewer when the process may
  open fewer files: ``ulimit -n``). A new one over the cap closes the oldest connection
  still waiting for its request: the operator's request, sent whole, is read at once,
  whatever slow clients hold. Accepting never stops, so it never fails for want of a file.
* **A deadline.** A request's head and body must arrive within ``request_timeout_s`` of the
  connection's start (or of the previous answer), however slowly they trickle in; else the
  answer is 408 (or, if nothing came, the connection is closed).
* **Bounded bodies.** A ``Content-Length`` over ``max_body_bytes`` is a 413 before a byte of
  the body is read; a chunked body is a 411. h11 refuses a malformed head (400), a head over
  :data:`MAX_HEAD_BYTES` (431) and a ``Content-Length`` that is not plain ASCII digits.

Requests are answered by a :class:`Handler` in a few threads, so a slow disk never blocks
the connections. A dead connection (a reset) is one log line at most, and the log's rate is
bounded (:class:`~._log.Log`).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import socket
import threading
import time
import traceback
from dataclasses import dataclass, field
from http import HTTPStatus
from typing import Protocol

import h11

from ._log import Log, blank_secret

MAX_CONNECTIONS = 256
# Files kept free for what the handlers open: the dataset, its backup, temporary files.
SPARE_FILES = 64
# Connections the kernel completes before the server accepts them: a burst gets in whole.
LISTEN_BACKLOG = 1024
# Connections accepted at a time (asyncio accepts its `backlog` in a row): between batches the
# accepted ones are read, so a whole request is read before a burst of newer connections
# could push its connection out over the cap.
ACCEPT_BATCH = 32
HANDLER_THREADS = 4
MAX_HEAD_BYTES = 16 * 1024
# After an answer with the body unread: read (and drop) what the client still sends, briefly,
# so it reads the answer instead of a reset; a client that keeps sending is cut off.
LINGER_S = 1.0
LINGER_BYTES = 256 * 1024


class Headers:
    """A request's header fields, names in any case; values decoded as Latin-1."""

    def __init__(self, items: list[tuple[bytes, bytes]]):
        self._items = [(k.decode("latin-1").lower(), v.decode("latin-1")) for k, v in items]

    def get(self, name: str, default: str | None = None) -> str | None:
        return next((v for k, v in self._items if k == name.lower()), default)

    def get_all(self, name: str) -> list[str]:
        return [v for k, v in self._items if k == name.lower()]

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and self.get(name) is not None


@dataclass(frozen=True)
class Request:
    """A whole request: ``target`` as sent (path and query), ``client`` the peer's address,
    ``local`` the address of this PC the connection reached."""

    method: str
    target: str
    headers: Headers
    body: bytes
    client: str
    local: str
    version: str = "1.1"


@dataclass
class Response:
    """An answer; ``note`` goes to the log line (e.g. why a request was refused)."""

    status: int
    body: bytes = b""
    content_type: str = "application/json"
    headers: dict[str, str] = field(default_factory=dict)
    note: str = ""


class Handler(Protocol):
    def handle(self, request: Request) -> Response:
        """The answer to a whole request (called in a worker thread)."""
        ...

    def refuse(self, status: int, message: str, field: str = "") -> Response:
        """The answer to a request refused before it was whole (400, 408, 411, 413, 431)."""
        ...


class _Connection:
    __slots__ = ("writer", "h11", "peer", "local", "busy", "received", "closed")

    def __init__(self, writer: asyncio.StreamWriter):
        self.writer = writer
        self.h11 = h11.Connection(h11.SERVER, max_incomplete_event_size=MAX_HEAD_BYTES)
        peer, local = writer.get_extra_info("peername"), writer.get_extra_info("sockname")
        self.peer = str(peer[0]) if peer else "?"
        self.local = str(local[0]) if local else "?"
        self.busy = False  # a request is being answered: never closed for the cap
        self.received = False  # bytes of the current request came
        self.closed = False


class _EarlyAnswer(Exception):
    """A request answered before it was read whole (its head is ``head``, if it came)."""

    def __init__(self, response: Response, head: h11.Request | None = None):
        self.response = response
        self.head = head


def file_limit() -> int | None:
    """How many files this process may open (``ulimit -n``), if the system says."""
    try:
        import resource
    except ImportError:  # Windows
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    return None if soft == resource.RLIM_INFINITY else int(soft)


class HTTPServer:
    """A listening socket, bound at once (so a bind error is raised here), served by
    :meth:`serve_forever` until :meth:`shutdown`.

    Args:
        address: ``(host, port)``; port 0 picks a free one (``server_address`` tells).
        handler: what answers the requests.
        log: where the access log and connection errors go.
        request_timeout_s: the deadline for each request's head and body, s.
        max_body_bytes: the largest body read.
        max_connections: the cap on connections held at once.
    """

    def __init__(
        self,
        address: tuple[str, int],
        handler: Handler,
        log: Log,
        request_timeout_s: float,
        max_body_bytes: int,
        max_connections: int = MAX_CONNECTIONS,
    ):
        self.handler = handler
        self.log = log
        self.request_timeout_s = request_timeout_s
        self.max_body_bytes = max_body_bytes
        files = file_limit()
        room = max_connections if files is None else max(8, files - SPARE_FILES)
        self.max_connections = min(max_connections, room)
        family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.socket = socket.socket(family, socket.SOCK_STREAM)
        try:
            self.socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.socket.bind(address)
            self.socket.listen(LISTEN_BACKLOG)
        except BaseException:
            self.socket.close()
            raise
        self.server_address = self.socket.getsockname()
        self._open: dict[_Connection, None] = {}  # oldest first
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._pool: concurrent.futures.ThreadPoolExecutor | None = None
        self._state = threading.Lock()  # the fields below, between serve_forever and shutdown
        self._stop_asked = False
        self._done = threading.Event()
        self._done.set()

    # -- running -------------------------------------------------------------------------
    def serve_forever(self, poll_interval: float = 0.5) -> None:
        """Serve until :meth:`shutdown` (or Ctrl-C). ``poll_interval`` is not used: the
        event loop wakes when there is something to do."""
        with self._state:
            if self._stop_asked:  # shut down before it began
                self._stop_asked = False
                return
            self._done.clear()
        try:
            asyncio.run(self._serve())
        finally:
            with self._state:
                self._loop = self._stop = None
                self._stop_asked = False
                self._done.set()

    async def _serve(self) -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(self._loop_error)
        with self._state:
            self._loop, self._stop = loop, asyncio.Event()
            if self._stop_asked:
                self._stop.set()
        with concurrent.futures.ThreadPoolExecutor(HANDLER_THREADS) as self._pool:
            server = await asyncio.start_server(
                self._connection, sock=self.socket, backlog=ACCEPT_BATCH
            )
            self.socket.listen(LISTEN_BACKLOG)  # start_server set the kernel's queue to the batch
            try:
                await self._stop.wait()
            finally:
                server.close()
                for conn in list(self._open):
                    self._close(conn)

    def shutdown(self) -> None:
        """Stop :meth:`serve_forever` (from another thread) and wait until it has."""
        with self._state:
            self._stop_asked = True
            loop, stop = self._loop, self._stop
        if loop is not None and stop is not None:
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:  # the loop has ended already
                pass
        self._done.wait()

    def server_close(self) -> None:
        """Close the listening socket."""
        self.socket.close()

    def _loop_error(self, loop: asyncio.AbstractEventLoop, context: dict) -> None:
        # e.g. "socket.accept() out of system resource": asyncio retries a second later.
        error = context.get("exception")
        self.log.line(f"server: {context.get('message')}: {error!r}")

    # -- connections ---------------------------------------------------------------------
    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        conn = _Connection(writer)
        self._admit(conn)
        try:
            await self._converse(conn, reader)
        except (ConnectionError, TimeoutError) as e:  # a reset, or a client that does not read
            if not conn.closed:
                self.log.line(f"{conn.peer} - connection ended: {type(e).__name__}")
        except Exception:  # a bug: the traceback, as one line of the bounded log
            self.log.block(traceback.format_exc())
        finally:
            self._close(conn)

    def _admit(self, conn: _Connection) -> None:
        """Hold ``conn``; over the cap, close the oldest connection waiting for a request."""
        self._open[conn] = None
        if len(self._open) > self.max_connections:
            victim = next((c for c in self._open if not c.busy), conn)
            self._close(victim)

    def _close(self, conn: _Connection) -> None:
        self._open.pop(conn, None)
        if not conn.closed:
            conn.closed = True
            conn.writer.transport.abort()  # its file is freed now; its reader sees the end

    async def _converse(self, conn: _Connection, reader: asyncio.StreamReader) -> None:
        """Answer requests on ``conn`` until either side closes it."""
        while not conn.closed:
            conn.busy = conn.received = False
            try:
                request = await self._read_within_deadline(conn, reader)
            except _EarlyAnswer as e:
                await self._answer(conn, e.response, e.head, close=True)
                await self._linger(conn, reader)
                return
            if request is None:
                return
            conn.busy = True
            loop = asyncio.get_running_loop()
            response = await loop.run_in_executor(self._pool, self.handler.handle, request)
            await self._answer(conn, response, request)
            if conn.h11.our_state is not h11.DONE or conn.h11.their_state is not h11.DONE:
                return
            conn.h11.start_next_cycle()

    async def _read_within_deadline(
        self, conn: _Connection, reader: asyncio.StreamReader
    ) -> Request | None:
        """The next whole request, or ``None`` when the connection ended before one began
        (or was closed); a refusal is raised as :class:`_EarlyAnswer`."""
        t = self.request_timeout_s
        try:
            async with asyncio.timeout(t):
                return await self._read_request(conn, reader)
        except TimeoutError:
            if not conn.received or conn.closed:
                return None  # silent since its last answer: closed without a word
            why = f"the request did not arrive whole within {t:g} s"
            if conn.h11.their_state is h11.SEND_BODY:
                why = f"the body stopped short of its Content-Length for {t:g} s"
            raise _EarlyAnswer(self.handler.refuse(408, why)) from None
        except h11.RemoteProtocolError as e:
            if conn.closed or conn.h11.their_state is h11.CLOSED or not conn.received:
                return None  # ended mid-request: nobody to answer
            status = e.error_status_hint
            raise _EarlyAnswer(self.handler.refuse(status, f"malformed request: {e}")) from None

    async def _read_request(
        self, conn: _Connection, reader: asyncio.StreamReader
    ) -> Request | None:
        head = await self._next_event(conn, reader)
        if not isinstance(head, h11.Request):
            return None  # ConnectionClosed
        headers = Headers(head.headers)
        if "chunked" in (headers.get("Transfer-Encoding") or "").lower():
            why = "send a Content-Length, not a chunked body"
            raise _EarlyAnswer(self.handler.refuse(411, why), head)
        length = int(headers.get("Content-Length") or 0)  # h11 checked: ASCII digits only
        if length > self.max_body_bytes:  # refused before reading a byte of it
            why = f"body of {length} bytes is over the limit of {self.max_body_bytes}"
            raise _EarlyAnswer(self.handler.refuse(413, why), head)
        body = bytearray()
        while not isinstance(event := await self._next_event(conn, reader), h11.EndOfMessage):
            body += event.data  # h11.Data; h11 stops at the Content-Length
        return Request(
            method=head.method.decode("ascii"),
            target=head.target.decode("latin-1"),
            headers=headers,
            body=bytes(body),
            client=conn.peer,
            local=conn.local,
            version=head.http_version.decode("ascii"),
        )

    async def _next_event(self, conn: _Connection, reader: asyncio.StreamReader):
        while (event := conn.h11.next_event()) is h11.NEED_DATA:
            data = await reader.read(65536)
            conn.received = conn.received or bool(data)
            conn.h11.receive_data(data)  # b"": the client closed its side
        return event

    # -- answers -------------------------------------------------------------------------
    async def _answer(
        self, conn: _Connection, response: Response, request: Request | h11.Request | None = None,
        close: bool = False,
    ) -> None:  # fmt: skip
        """Send ``response`` (no body to a HEAD) and log it; ``close`` ends the connection."""
        if conn.closed:
            return
        headers = [
            ("Content-Type", response.content_type),
            ("Content-Length", str(len(response.body))),
            *response.headers.items(),
        ]
        if close:
            headers.append(("Connection", "close"))
        phrase = HTTPStatus(response.status).phrase.encode()
        data = conn.h11.send(h11.Response(status_code=response.status, headers=headers,
                                          reason=phrase))  # fmt: skip
        if response.body and _method(request) != "HEAD":
            data += conn.h11.send(h11.Data(data=response.body))
        data += conn.h11.send(h11.EndOfMessage())
        self._log(conn, request, response)
        conn.writer.write(data)
        async with asyncio.timeout(self.request_timeout_s):  # a client that does not read
            await conn.writer.drain()

    async def _linger(self, conn: _Connection, reader: asyncio.StreamReader) -> None:
        """Close after an answer sent with the body unread, without resetting the client.

        Closing a socket with unread bytes sends a reset, and the client may lose the answer
        it was sent; so stop sending, and read what comes for up to :data:`LINGER_S`.
        """
        try:
            conn.writer.write_eof()
            async with asyncio.timeout(LINGER_S):
                left = LINGER_BYTES
                while left > 0 and (chunk := await reader.read(65536)):
                    left -= len(chunk)
        except (OSError, TimeoutError):
            pass

    def _log(self, conn: _Connection, request: Request | h11.Request | None,
             response: Response) -> None:  # fmt: skip
        when = time.strftime("%d/%b/%Y %H:%M:%S")
        if request is None:
            line = "-"
        else:
            method, target = _method(request), _text(request.target)
            version = _text(request.http_version if isinstance(request, h11.Request)
                            else request.version)  # fmt: skip
            line = f"{method} {blank_secret(target)} HTTP/{version}"
        note = f" {response.note}" if response.note else ""
        self.log.line(f'{conn.peer} - - [{when}] "{line}" {response.status} '
                      f"{len(response.body)}{note}")  # fmt: skip


def _text(x: str | bytes) -> str:
    return x.decode("latin-1") if isinstance(x, bytes) else x


def _method(request: Request | h11.Request | None) -> str:
    return "" if request is None else _text(request.method)
