"""The tablet's HTTP server: the page, the dataset's landmarks, and the touches it posts back.

Built on the standard library's :class:`http.server.ThreadingHTTPServer`. Routes:

* ``GET /``, ``/app.js``, ``/style.css``: the page (static files, no build step).
* ``GET /api/session``: the tablet (ppi, scale, mm per px), the dataset's landmarks, the
  targets file, the result being evaluated and the trials so far, as JSON. Files are named by
  their names only, never by a path.
* ``GET /api/grid?cols=3&rows=3&left=400&top=150&right=1040&bottom=550``: a new grid of
  targets, CSS px, snake order.
* ``POST /api/calibration``: every landmark's ``touch_error_px``; written into the dataset
  in place, its comments and layout kept (atomic; the previous file kept as a new
  ``DATASET.<UTC time>.bak`` each time, so every version stays).
* ``POST /api/evaluation``: one trial of touches; appended to the trials file (atomic).

``HEAD`` is answered as ``GET``, without the body.

Only the operator can use it (:mod:`.guard`, as Jupyter does): each start makes a random
secret, printed in the page's URL and as a QR code; the first load with it sets a cookie and
redirects to the URL without it. A request without the secret, whose ``Host`` is not this
server's address (DNS rebinding) or whose ``Origin`` is another site's page, gets a 403 (the
page without the secret says to open the printed URL).

A refused request gets a 4xx JSON answer ``{"error": ..., "field": ..., "status": ...}`` and
changes no file. A post the server could not save (a file it cannot read or write, a full disk)
gets a 500 whose ``error`` is one line naming the user's file and the reason, and changes no
file; the page keeps the run and sends it again. The files the posts write are checked before
the server starts (:func:`make_server`). Posts are bounded: a body over ``MAX_BODY_BYTES`` is
answered 413 at once (before it is read), a run holds at most ``MAX_TOUCHES`` touches and the
trials file at most ``MAX_TRIALS`` trials. A connection that sends nothing, or less body than
its ``Content-Length``, for ``request_timeout_s`` (30 s) is answered 408 or closed, so it
cannot hold a thread forever.
"""

from __future__ import annotations

import errno
import hashlib
import ipaddress
import json
import math
import os
import re
import socket
import sys
import threading
import time
import traceback
import urllib.parse
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .._core import InputError, check_output, reason
from ..data import load_dataset
from ..geometry import mm_per_tablet_px
from . import _guard as guard
from . import _posts as posts
from . import _trials as trials
from ._calibration import apply_touch_errors
from ._targets import grid_targets, load_targets

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
DEFAULT_REQUEST_TIMEOUT_S = 30.0
# Hosts that mean "every address of this PC": the page's URL needs one of its LAN addresses.
_WILDCARD_HOSTS = ("", "0.0.0.0", "::")
# Private addresses a UDP socket is "connected" to (nothing is sent) to learn which local
# address the PC would use to reach each private network: its LAN address(es).
_PROBE_ADDRESSES = ("10.254.254.254", "172.31.254.254", "192.168.254.254")
_HTML = "text/html; charset=utf-8"
_STATIC = {
    "/": ("index.html", _HTML),
    "/index.html": ("index.html", _HTML),
    "/app.js": ("app.js", "text/javascript; charset=utf-8"),
    "/style.css": ("style.css", "text/css; charset=utf-8"),
}
# The page shown without the secret: it says where to get it.
_LOCKED = "locked.html"
# Headers on every answer: no caching, no page of another site may frame it or embed its
# answers, and the URL (with its secret, on the first load) is not sent on as a Referer.
_HEADERS = {
    "Cache-Control": "no-store",
    "Referrer-Policy": "no-referrer",
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Content-Security-Policy": "frame-ancestors 'none'",
    "Cross-Origin-Resource-Policy": "same-origin",
}
# After a refusal with the body unread: read (and drop) what the client still sends, briefly,
# so it reads the answer instead of a reset; a client that keeps sending is cut off.
_LINGER_S = 1.0
_LINGER_BYTES = 4 * posts.MAX_BODY_BYTES
# Connections the kernel holds while the server is busy: 50 concurrent posts get in.
REQUEST_QUEUE_SIZE = 128
_SECRET_IN_URL = re.compile(r"token=[^&\s\"']*")


@dataclass
class TabletApp:
    """What the server serves; every file path is fixed when the server starts.

    Attributes:
        dataset_path: the dataset whose touch errors calibration mode writes, or ``None``.
        ppi, scale: the tablet's px per inch and display scale (eq. 9).
        trials_path: the evaluation trials file (JSON).
        targets_path, targets_px: the targets file and its points (CSS px), or ``None``.
        result: what is being evaluated (result file, model, seed, dataset), or ``None``.

    What it answers names files by their names, never by a path: the page needs no more, and
    the PC's folders are nobody else's business.
    """

    dataset_path: Path | None
    ppi: float
    scale: float
    trials_path: Path
    targets_path: Path | None = None
    targets_px: np.ndarray | None = None
    result: dict[str, Any] | None = None
    trials_doc: dict[str, Any] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def session(self) -> dict[str, Any]:
        """The page's start-up data, read afresh (the dataset may have changed on disk)."""
        mm = mm_per_tablet_px(self.ppi, self.scale)
        out: dict[str, Any] = {
            "tablet": {"ppi": self.ppi, "scale": self.scale, "mm_per_px": mm},
            "dataset": None,
            "targets_file": None,
            "result": _public_result(self.result),
            "trials": {"file": self.trials_path.name, "summary": []},
            "limits": {
                "max_body_bytes": posts.MAX_BODY_BYTES,
                "max_touches": posts.MAX_TOUCHES,
                "max_trials": posts.MAX_TRIALS,
                "pointer_types": list(posts.POINTER_TYPES),
            },
        }
        if self.dataset_path is not None:
            ds = load_dataset(self.dataset_path)
            out["dataset"] = {
                "file": self.dataset_path.name,
                "backups": f"{self.dataset_path.name}.<UTC time>.bak",
                "name": ds.name,
                "tablet_px": ds.tablet_px.tolist(),
                "touch_error_px": ds.touch_error_px.tolist(),
                "key": self._dataset_key(ds.tablet_px),
                "version": ds.version,
                "captures": [
                    {
                        "hand_position_mm": c.hand_position_mm.tolist(),
                        "hand_angle_deg": c.hand_angle_deg,
                        "landmarks": c.landmarks.tolist(),
                    }
                    for c in ds.captures
                ],
            }
        if self.targets_px is not None:
            assert self.targets_path is not None
            out["targets_file"] = {
                "file": self.targets_path.name,
                "tablet_px": self.targets_px.tolist(),
                "key": _key(str(self.targets_path), self.targets_px.tolist()),
            }
        with self.lock:
            out["trials"]["summary"] = trials.summarise(self.trials_doc)
        return out

    def post_calibration(self, doc: Any) -> dict[str, Any]:
        if self.dataset_path is None:
            raise posts.PostError(404, "", "no dataset: start the server with --dataset")
        with self.lock:
            ds = load_dataset(self.dataset_path)
            post = posts.parse_calibration(doc, ds.n_landmarks)
            if post.key is not None and post.key != self._dataset_key(ds.tablet_px):
                raise posts.PostError(
                    409, "key",
                    f"these touches were measured on another dataset's landmarks, not on "
                    f"{self.dataset_path.name}'s; discard them, or serve that dataset again",
                )  # fmt: skip
            backup = apply_touch_errors(self.dataset_path, post)
        dist = np.linalg.norm(post.touch_error_px, axis=1)
        mm = mm_per_tablet_px(self.ppi, self.scale)
        return {
            "saved": self.dataset_path.name,
            "written": backup is not None,
            "backup": backup.name if backup is not None else None,
            "mean_px": float(dist.mean()),
            "mean_mm": float(dist.mean() * mm),
            "pointer_types": {
                k: post.pointer_types.count(k) for k in sorted(set(post.pointer_types))
            },
        }

    def post_evaluation(self, doc: Any) -> dict[str, Any]:
        post = posts.parse_evaluation(doc)
        expected = {"dataset": self._dataset_points, "file": lambda: self.targets_px}
        if post.targets in expected:
            want = expected[post.targets]()
            if want is None or not np.array_equal(want, post.target_px):
                raise posts.PostError(
                    409, "touches", f"the targets are not the {post.targets}'s; reload the page"
                )
        with self.lock:
            trial = trials.find_trial(self.trials_doc, post.run_id)
            if trial is None:
                held = len(self.trials_doc["trials"])
                if held >= posts.MAX_TRIALS:
                    raise posts.PostError(
                        409, "trials",
                        f"{self.trials_path.name} holds {held} trials, the limit of "
                        f"{posts.MAX_TRIALS}; restart the server with another --trials file",
                    )  # fmt: skip
                trial = trials.make_trial(post, self.trials_doc, self.result)
                doc_new = {**self.trials_doc, "trials": [*self.trials_doc["trials"], trial]}
                trials.save_trials(doc_new, self.trials_path)
                self.trials_doc = doc_new
            summary = trials.summarise(self.trials_doc)
        keep = ("trial", "label", "mean_px", "max_px", "mean_mm", "max_mm")
        return {"saved": self.trials_path.name, **{k: trial[k] for k in keep}, "summary": summary}

    def public_error(self, e: InputError, message: str | None = None) -> str:
        """``e`` as one line for a client: its file by name, and no folder of this PC."""
        text = message if message is not None else e.message
        for path in (self.dataset_path, self.trials_path, self.targets_path):
            if path is not None:
                for folder in {str(path.parent), str(path.resolve().parent)} - {"."}:
                    text = text.replace(folder + os.sep, "")
        name = Path(e.path).name if e.path is not None and str(e.path) else None
        return str(InputError(name, e.field, text))

    def _dataset_key(self, tablet_px: np.ndarray) -> str:
        assert self.dataset_path is not None
        return _key(str(self.dataset_path.resolve()), tablet_px.tolist())

    def _dataset_points(self) -> np.ndarray | None:
        if self.dataset_path is None:
            return None
        return load_dataset(self.dataset_path).tablet_px


def _public_result(result: dict[str, Any] | None) -> dict[str, Any] | None:
    """The result being evaluated as the page sees it: its file by name."""
    if result is None:
        return None
    out = {k: v for k, v in result.items() if k != "path"}
    return {"file": Path(result["path"]).name, **out}


def _key(*parts: Any) -> str:
    """A short fingerprint the page uses to keep runs of different landmark sets apart."""
    return hashlib.sha256(json.dumps(parts).encode()).hexdigest()[:16]


class TabletServer(ThreadingHTTPServer):
    """A :class:`ThreadingHTTPServer` that serves one :class:`TabletApp` to whoever has its
    secret ``token``.

    ``host_names`` are names (not addresses) the operator bound it to, e.g. ``localhost``:
    requests may name the server by them as well as by the address they reached.
    """

    daemon_threads = True
    request_queue_size = REQUEST_QUEUE_SIZE

    def __init__(
        self,
        address: tuple[str, int],
        app: TabletApp,
        token: str,
        quiet: bool = False,
        request_timeout_s: float = DEFAULT_REQUEST_TIMEOUT_S,
    ):
        self.app = app
        self.token = token
        self.quiet = quiet
        self.request_timeout_s = request_timeout_s
        self.host_names = () if _is_ip(address[0]) else (address[0].lower(),)
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        super().__init__(address, _Handler)

    @property
    def port(self) -> int:
        return self.server_address[1]

    @property
    def url(self) -> str:
        """The page's URL on the address the server is bound to, without the secret."""
        host = self.server_address[0]
        return f"http://{_url_host(host)}:{self.port}/"

    @property
    def secret_url(self) -> str:
        """:attr:`url` with the secret: opening it lets a browser in."""
        return f"{self.url}?token={self.token}"


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return host in _WILDCARD_HOSTS
    return True


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def lan_addresses() -> list[str]:
    """This PC's IPv4 addresses on its local networks, found without sending anything.

    A UDP socket ``connect`` only asks the routing table which local address would reach a
    private network; no packet leaves the PC. Loopback addresses are left out.
    """
    found: list[str] = []
    for probe in _PROBE_ADDRESSES:
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.connect((probe, 9))
                found.append(s.getsockname()[0])
        except OSError:
            continue
    if not found:  # no route to any private network: the name in /etc/hosts, if any
        try:
            found.append(socket.gethostbyname(socket.gethostname()))
        except OSError:
            pass
    return [a for a in dict.fromkeys(found) if not a.startswith("127.") and a != "0.0.0.0"]


def page_urls(
    host: str, port: int, addresses: list[str] | None = None, token: str | None = None
) -> list[str]:
    """URLs a tablet can open for a server on ``host:port``; a wildcard host gives one per LAN
    address (``addresses``, found by :func:`lan_addresses` when not given), maybe none. With
    ``token``, each carries the secret (``?token=...``)."""
    query = f"?token={token}" if token is not None else ""
    if host not in _WILDCARD_HOSTS:
        return [f"http://{_url_host(host)}:{port}/{query}"]
    addresses = lan_addresses() if addresses is None else addresses
    return [f"http://{_url_host(a)}:{port}/{query}" for a in addresses]


class _Handler(BaseHTTPRequestHandler):
    server: TabletServer
    server_version = "handeye-jax-tablet"

    def setup(self) -> None:
        # Every read and write on the connection times out: a client that stops sending
        # (a short body, a half-open link) frees its thread after request_timeout_s.
        self.timeout = self.server.request_timeout_s
        self.unread_body = False
        super().setup()

    def log_message(self, format: str, *args: Any) -> None:
        if not self.server.quiet:  # the secret stays out of the log
            sys.stderr.write(_SECRET_IN_URL.sub("token=[secret]", self._log_line(format, args)))

    def _log_line(self, format: str, args: tuple[Any, ...]) -> str:
        when = self.log_date_time_string()
        return f"{self.address_string()} - - [{when}] {format % args}\n"

    def finish(self) -> None:
        super().finish()
        if self.unread_body:
            self._linger()

    def _linger(self) -> None:
        """Close after an answer sent with the body unread, without resetting the client.

        Closing a socket with unread bytes sends a reset, and the client may lose the answer
        it was sent; so stop sending, and read what comes for up to ``_LINGER_S``.
        """
        try:
            self.connection.shutdown(socket.SHUT_WR)
            deadline = time.monotonic() + _LINGER_S
            left = _LINGER_BYTES
            while left > 0 and (wait := deadline - time.monotonic()) > 0:
                self.connection.settimeout(wait)
                chunk = self.connection.recv(min(left, 65536))
                if not chunk:
                    break
                left -= len(chunk)
        except OSError:
            pass

    # -- answers -------------------------------------------------------------------------
    def _send(
        self, status: int, body: bytes, content_type: str, headers: dict[str, str] | None = None
    ) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        for key, value in {**_HEADERS, **(headers or {})}.items():
            self.send_header(key, value)
        if self.unread_body:
            self.close_connection = True
            self.send_header("Connection", "close")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, doc: Any) -> None:
        body = json.dumps(doc, allow_nan=False).encode()
        self._send(status, body, "application/json")

    def _refuse(self, status: int, field: str, message: str) -> None:
        self._json(status, {"error": message, "field": field, "status": status})

    # -- who may ask ---------------------------------------------------------------------
    def _check(self, url: urllib.parse.SplitResult) -> bool:
        """Refuse (and answer) a request that is not the operator's; ``True`` to go on.

        The Host and Origin come first: a page of another site gets nothing, not even the
        login. Then the secret: from the URL on a page's first load (set as a cookie, and
        redirected to the URL without it), else from the cookie or a header.
        """
        host = self.headers.get("Host")
        local = self.connection.getsockname()[0]
        why = guard.host_refusal(host, local, self.server.port, self.server.host_names)
        if why is None:
            why = guard.origin_refusal(self.headers.get("Origin"), host or "")
            field = "Origin"
        else:
            field = "Host"
        api = url.path.startswith("/api/")
        fetch_site = self.headers.get("Sec-Fetch-Site")
        if why is None and api and fetch_site not in (None, "same-origin", "none"):
            why, field = f"a {fetch_site} request is not this server's page's", "Sec-Fetch-Site"
        if why is not None:
            self.log_error("refused %s %s: %s", self.command, url.path, why)
            self._refuse(HTTPStatus.FORBIDDEN, field, why)
            return False
        token = self.server.token
        query = _query(url.query)
        if not api and self.command in ("GET", "HEAD") and "token" in query:
            if guard.token_matches(query["token"][0], token):
                rest = [(k, v) for k, vs in query.items() if k != "token" for v in vs]
                where = url.path + ("?" + urllib.parse.urlencode(rest) if rest else "")
                cookie = guard.cookie_header(self.server.port, token)
                headers = {"Location": where, "Set-Cookie": cookie}
                self._send(HTTPStatus.SEE_OTHER, b"", _HTML, headers)
                return False
            self._locked("the secret in this link is not this server's (was it restarted?)")
            return False
        if guard.token_matches(guard.request_token(self.headers, self.server.port), token):
            return True
        if not api and self.command in ("GET", "HEAD"):
            self._locked("this browser does not have the server's secret")
        else:
            self.log_error("refused %s %s: no secret", self.command, url.path)
            self._refuse(
                HTTPStatus.FORBIDDEN, "token",
                "this browser does not have the server's secret: open the URL the server "
                "printed (or scan its QR code); runs kept in this browser are not lost",
            )  # fmt: skip
        return False

    def _locked(self, why: str) -> None:
        page = resources.files(__package__).joinpath("static", _LOCKED).read_text("utf-8")
        body = page.replace("{why}", why).encode()
        self._send(HTTPStatus.FORBIDDEN, body, _HTML)

    # -- routes --------------------------------------------------------------------------
    def do_GET(self) -> None:
        self._serve(self._get)

    def do_HEAD(self) -> None:
        self._serve(self._get)

    def do_POST(self) -> None:
        self._serve(self._post)

    def do_OPTIONS(self) -> None:
        self._serve(self._no_such_method)

    def do_PUT(self) -> None:
        self._serve(self._no_such_method)

    def do_DELETE(self) -> None:
        self._serve(self._no_such_method)

    def _serve(self, route: Any) -> None:
        """Check who asks, then answer; whatever fails, an answer (never a dropped line)."""
        length = self.headers.get("Content-Length", "0")
        self.unread_body = length.strip() not in ("", "0") or "Transfer-Encoding" in self.headers
        try:
            if not self.path.startswith("/"):  # an absolute URL names another host
                raise posts.PostError(400, "", "the request must name a path, e.g. /")
            url = urllib.parse.urlsplit(self.path)
            if self._check(url):
                route(url)
        except posts.PostError as e:
            self._refuse(e.status, e.field, e.message)
        except InputError as e:  # nothing written, either way
            failed = _server_failure(e)
            public = self.server.app.public_error(e, failed)
            if failed is not None:  # a file the server cannot read or write: the page retries
                self._refuse(HTTPStatus.INTERNAL_SERVER_ERROR, "", public)
            else:  # the dataset on disk is invalid: the page shows it as refused
                self._refuse(HTTPStatus.CONFLICT, e.field, public)
        except OSError as e:  # the OSError's file names may be temporary files: left out
            why = f"the server could not save this post: {reason(e)}"
            self._refuse(HTTPStatus.INTERNAL_SERVER_ERROR, "", why)
        except Exception as e:  # a bug: the client gets a 500, the operator the traceback
            if not self.server.quiet:
                traceback.print_exc()
            why = f"internal error: {type(e).__name__}"
            self._refuse(HTTPStatus.INTERNAL_SERVER_ERROR, "", why)

    def _get(self, url: urllib.parse.SplitResult) -> None:
        if url.path in _STATIC:
            name, kind = _STATIC[url.path]
            body = resources.files(__package__).joinpath("static", name).read_bytes()
            self._send(HTTPStatus.OK, body, kind)
        elif url.path == "/api/session":
            self._json(HTTPStatus.OK, self.server.app.session())
        elif url.path == "/api/grid":
            self._json(HTTPStatus.OK, {"tablet_px": _grid(url.query).tolist()})
        else:
            self._refuse(HTTPStatus.NOT_FOUND, "", f"no such page: {url.path[:100]}")

    def _post(self, url: urllib.parse.SplitResult) -> None:
        routes = {
            "/api/calibration": self.server.app.post_calibration,
            "/api/evaluation": self.server.app.post_evaluation,
        }
        if url.path not in routes:
            raise posts.PostError(404, "", f"no such endpoint: {url.path[:100]}")
        doc = posts.parse_json_body(self._read_body())
        self._json(HTTPStatus.OK, routes[url.path](doc))

    def _no_such_method(self, url: urllib.parse.SplitResult) -> None:
        raise posts.PostError(405, "", f"{self.command} is not answered here; GET, HEAD or POST")

    def _read_body(self) -> bytes:
        if "chunked" in self.headers.get("Transfer-Encoding", "").lower():
            raise posts.PostError(411, "", "send a Content-Length, not a chunked body")
        kind = self.headers.get("Content-Type", "").split(";")[0].strip().lower()
        length_text = self.headers.get("Content-Length")
        try:
            length = int(length_text) if length_text is not None and len(length_text) < 20 else -1
        except ValueError:
            length = -1
        if length < 0:
            raise posts.PostError(411, "", "a Content-Length header (bytes) is required")
        if length > posts.MAX_BODY_BYTES:  # refused before reading a byte of it
            raise posts.PostError(
                413, "", f"body of {length} bytes is over the limit of {posts.MAX_BODY_BYTES}"
            )
        try:
            body = self.rfile.read(length)
        except TimeoutError:
            raise posts.PostError(
                408, "", f"the body stopped short of its Content-Length ({length} bytes) for "
                f"{self.server.request_timeout_s:g} s",
            ) from None  # fmt: skip
        if len(body) < length:
            self.close_connection = True
            raise posts.PostError(400, "", f"body of {len(body)} bytes, not {length}")
        self.unread_body = False
        if kind != "application/json":
            raise posts.PostError(415, "", f"Content-Type must be application/json (got {kind!r})")
        return body


def _server_failure(e: InputError) -> str | None:
    """For an :class:`InputError` raised over an OSError (a file the server could not read or
    write), what failed and the reason (e.g. ``"cannot write: No space left on device"``);
    else ``None``.

    The OSError's own text is left out: it names the temporary file of an atomic write.
    """
    cause = e.__context__  # set even by ``raise ... from None``
    while cause is not None and not isinstance(cause, OSError):
        cause = cause.__context__
    if cause is None:
        return None
    what = e.message.split(": ", 1)[0] or "cannot write"
    return f"{what}: {reason(cause)}"


def _query(query: str) -> dict[str, list[str]]:
    """The query's fields; a query of more than 20 fields is refused (400)."""
    try:
        return urllib.parse.parse_qs(query, max_num_fields=20)
    except ValueError:
        raise posts.PostError(400, "", "the query has too many fields") from None


def _grid(query: str) -> np.ndarray:
    q = _query(query)
    names = ("cols", "rows", "left", "top", "right", "bottom")
    values: list[float] = []
    for name in names:
        if len(q.get(name, [])) != 1:
            raise posts.PostError(400, name, "give exactly one value")
        text = q[name][0]
        if len(text) > 50:
            raise posts.PostError(400, name, f"not a number: {len(text)} characters")
        try:
            v = float(text)
        except ValueError:
            raise posts.PostError(400, name, f"not a number: {text!r}") from None
        if not math.isfinite(v):  # nan, inf, 1e400
            raise posts.PostError(400, name, f"must be a finite number (got {text!r})")
        if name in ("cols", "rows") and v != int(v):
            raise posts.PostError(400, name, f"must be a whole number (got {text!r})")
        values.append(v)
    try:
        return grid_targets(int(values[0]), int(values[1]), *values[2:])
    except ValueError as e:
        field_, _, message = str(e).partition(": ")
        raise posts.PostError(400, field_, message) from None


def make_server(
    dataset: str | Path | None = None,
    *,
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    targets: str | Path | None = None,
    result: str | Path | None = None,
    trials_path: str | Path | None = None,
    ppi: float | None = None,
    scale: float | None = None,
    quiet: bool = False,
    request_timeout_s: float = DEFAULT_REQUEST_TIMEOUT_S,
    token: str | None = None,
) -> TabletServer:
    """Check the inputs and bind the tablet server; call ``serve_forever()`` on it to run.

    Args:
        dataset: the dataset (TOML) to draw and to write touch errors into; optional.
        host: the address to listen on; ``127.0.0.1`` (this machine only) by default,
            ``0.0.0.0`` to let a tablet on the LAN load the page.
        port: the TCP port; 0 picks a free one (see ``server.url``).
        targets: evaluation targets, a targets JSON or a dataset TOML (tablet px).
        result: the calibration result being evaluated (recorded with each trial).
        trials_path: where evaluation trials are saved (JSON); defaults to
            ``DATASET_STEM.trials.json`` beside the dataset, or ``tablet-trials.json``.
        ppi, scale: the tablet's px per inch and display scale; taken from the dataset when
            not given, required without one.
        quiet: do not log requests to standard error.
        request_timeout_s: how long a connection may stay silent (no request, or a body
            shorter than its Content-Length) before the server answers 408 or closes it.
        token: the secret a browser or script must show (``server.secret_url`` carries
            it); a new random one (:func:`~.guard.new_token`) when not given. Give one only
            for scripts: at least 32 URL-safe characters.

    Raises :class:`InputError` naming the file or option for bad input: ``--port`` for a port
    in use or not allowed, ``--host`` for an address that is not this PC's, ``--trials`` for a
    trials file (given or the default) that cannot be written, ``--dataset`` for a dataset
    whose folder cannot be written (calibration writes it and a backup beside it) or with
    more landmarks than a run may touch. Every file a post writes is checked here, before the
    server is bound.
    """
    try:
        token = guard.new_token() if token is None else guard.check_token(token)
    except ValueError as e:
        raise InputError(None, "token", str(e)) from None
    ds_path = Path(dataset) if dataset is not None else None
    ds = load_dataset(ds_path) if ds_path is not None else None
    if ds is not None and ds.n_landmarks > posts.MAX_TOUCHES:
        raise InputError(ds_path, "landmarks", f"{ds.n_landmarks} landmarks; the tablet page "
                         f"takes at most {posts.MAX_TOUCHES} in a run")  # fmt: skip
    if ppi is None and ds is not None:
        ppi = ds.tablet_ppi
    if scale is None and ds is not None:
        scale = ds.tablet_scale
    for name, v in (("--ppi", ppi), ("--scale", scale)):
        if v is None:
            raise InputError(None, name, "needed without --dataset, to turn tablet px into mm")
        if not np.isfinite(v) or v <= 0:
            raise InputError(None, name, f"must be a finite number > 0 (got {v})")
    default_trials = trials_path is None
    if trials_path is None:
        trials_path = (
            ds_path.with_name(ds_path.stem + ".trials.json") if ds_path else "tablet-trials.json"
        )
    trials_path = Path(trials_path)
    _check_outputs(ds_path, trials_path, default_trials, [targets, result])
    info = _result_info(result) if result is not None else None
    if info is not None and ds is not None and info["dataset"] != ds.name:
        info["note"] = (
            f"the result was fitted on dataset {info['dataset']!r}, not on {ds.name!r}: "
            "its landmarks are not these"
        )
    app = TabletApp(
        dataset_path=ds_path,
        ppi=float(ppi),
        scale=float(scale),
        trials_path=trials_path,
        targets_path=Path(targets) if targets is not None else None,
        targets_px=load_targets(targets) if targets is not None else None,
        result=info,
        trials_doc=trials.load_trials(trials_path, float(ppi), float(scale)),
    )
    if not 0 <= port <= 65535:
        raise InputError(None, "--port", f"must be 0 to 65535 (got {port})")
    if not request_timeout_s > 0:
        raise InputError(None, "request_timeout_s", f"must be > 0 s (got {request_timeout_s})")
    try:
        return TabletServer((host, port), app, token, quiet, request_timeout_s)
    except socket.gaierror as e:
        raise InputError(None, "--host", f"cannot use {host!r}: {e.strerror}") from None
    except OSError as e:
        raise _bind_error(e, host, port) from None


def _check_outputs(
    dataset: Path | None,
    trials_path: Path,
    default_trials: bool,
    inputs: list[str | Path | None],
) -> None:
    """Refuse, before serving, a file the posts would write but could not.

    Calibration rewrites ``dataset`` and keeps each previous version beside it (atomic, via a
    temporary file in its folder); evaluation writes ``trials_path``.
    """
    if dataset is not None:
        why = (f"calibration writes touch_error_px into {dataset.name} and keeps each "
               f"previous version beside it as {dataset.name}.<UTC time>.bak")  # fmt: skip
        try:
            check_output(dataset, "--dataset", inputs)
        except InputError as e:
            raise InputError(e.path, e.field, f"{e.message} ({why})") from None
    try:
        check_output(trials_path, "--trials", [dataset, *inputs])
    except InputError as e:
        if not default_trials:
            raise
        note = "the default trials file, as --trials was not given; choose one with --trials"
        raise InputError(e.path, e.field, f"{e.message} ({note})") from None


def _bind_error(e: OSError, host: str, port: int) -> InputError:
    """The one-line error for a failed bind, naming the option to change."""
    where = f"{_url_host(host)}:{port}"
    if e.errno == errno.EADDRINUSE:
        return InputError(None, "--port", f"{where} is in use by another program; choose "
                          "another --port")  # fmt: skip
    if e.errno in (errno.EACCES, errno.EPERM):
        return InputError(None, "--port", f"no permission to listen on {where} (ports below "
                          f"1024 need administrator rights); choose another --port, e.g. "
                          f"{DEFAULT_PORT}")  # fmt: skip
    if e.errno == errno.EADDRNOTAVAIL:
        return InputError(None, "--host", f"{host!r} is not an address of this PC; use "
                          "127.0.0.1, 0.0.0.0 or one of its LAN addresses")  # fmt: skip
    return InputError(None, "--host", f"cannot listen on {where}: {e.strerror or e}")


def _result_info(path: str | Path) -> dict[str, Any]:
    from ..calibration import load_result

    r = load_result(path)
    return {"path": str(path), "model": r.model_name, "seed": r.seed, "dataset": r.dataset_name}


def serve(dataset: str | Path | None = None, **kwargs: Any) -> int:
    """Run the tablet server until Ctrl-C; arguments as for :func:`make_server`. Returns 0.

    Prints the page's URL with its secret (one per LAN address when listening on every
    address) and, when another device is to open it, the first as a QR code to scan.
    """
    server = make_server(dataset, **kwargs)
    app = server.app
    host, port = server.server_address[:2]
    requested = kwargs.get("host", DEFAULT_HOST)
    urls = page_urls(requested, port, token=server.token)
    loopback = host.startswith("127.") or host == "::1"
    if urls:
        print(f"tablet page: {urls[0]}  (open it on the tablet, full screen, zoom 100%)")
        if not loopback:
            print("scan it with the tablet's camera:")
            _print_qr(urls[0])
        for url in urls[1:]:
            print(f"  or: {url}  (this PC's address on another network)")
    else:
        print(f"tablet page: http://THIS-PC:{port}/?token={server.token}  (no LAN address "
              "found: use this PC's address from `ip addr` or `ipconfig`)")  # fmt: skip
    if requested in _WILDCARD_HOSTS:
        here = f"http://127.0.0.1:{port}/?token={server.token}"
        print(f"  listening on every address of this PC ({requested or 'all'}), port {port}: "
              "the tablet must be on the same network, and a firewall must let TCP port "
              f"{port} in; on this PC itself, {here}")  # fmt: skip
    elif loopback:
        print("  only this PC can open it; to let a tablet in, start with --host 0.0.0.0")
    print("  the secret in the URL is new at each start: whoever has it can write the "
          "dataset and trials; after a restart, open the new URL (runs in the browser "
          "stay)")  # fmt: skip
    print(
        f"tablet: {app.ppi:g} ppi, scale {app.scale:g}: "
        f"1 tablet px = {mm_per_tablet_px(app.ppi, app.scale):.4f} mm"
    )
    if app.dataset_path is not None:
        print(f"calibration writes touch_error_px (px) into {app.dataset_path}, keeping each "
              f"previous version as {app.dataset_path.name}.<UTC time>.bak beside it")  # fmt: skip
    print(f"evaluation trials go to {app.trials_path}")
    sys.stdout.flush()
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("stopped")
    finally:
        server.server_close()
    if app.trials_doc["trials"]:
        print(trials.format_summary(app.trials_doc))
    return 0


def _print_qr(url: str) -> None:
    """``url`` as a QR code on standard output (coloured on a terminal, plain in a file)."""
    tty = sys.stdout.isatty()
    try:
        print(guard.qr_text(url, colour=tty))
    except UnicodeEncodeError:  # an output that cannot show the block characters
        print("  (no QR code: this output cannot show it; type the URL)")
