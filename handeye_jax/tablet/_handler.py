"""The tablet server's answers: who may ask (:mod:`._guard`), then the page and the API.

Routes (``HEAD`` is answered as ``GET``, without the body):

* ``GET /``, ``/app.js``, ``/style.css``: the page (static files, no build step).
* ``GET /api/session``: the tablet, the dataset's landmarks, the targets, the result being
  evaluated and the trials so far, as JSON (:meth:`~._app.TabletApp.session`).
* ``GET /api/grid?cols=3&rows=3&left=400&top=150&right=1040&bottom=550``: a new grid of
  targets, CSS px, snake order; each value plain ASCII digits (``-``, one ``.``).
* ``POST /api/calibration``: every landmark's ``touch_error_px``, into the dataset.
* ``POST /api/evaluation``: one trial of touches, into the trials file.

A refused request gets a 4xx JSON answer ``{"error": ..., "field": ..., "status": ...}`` and
changes no file; a post the server could not save (a file it cannot write, a full disk) gets
a 500 whose ``error`` is one line naming the user's file, and changes no file.
"""

from __future__ import annotations

import json
import math
import re
import traceback
import urllib.parse
from collections.abc import Callable
from http import HTTPStatus
from importlib import resources
from typing import Any, Protocol

import numpy as np

from .._core import InputError, reason
from . import _guard as guard
from . import _posts as posts
from ._app import TabletApp
from ._http import Request, Response
from ._log import Log
from ._targets import grid_targets


class ServerState(Protocol):
    """What a handler reads of its server (:class:`~._server.TabletServer`): named here so
    that the handler does not import the server that imports it."""

    app: TabletApp
    log: Log
    port: int
    token: str
    host_names: tuple[str, ...]

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
HEADERS = {
    "Cache-Control": "no-store",
    "Referrer-Policy": "no-referrer",
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Content-Security-Policy": "frame-ancestors 'none'",
    "Cross-Origin-Resource-Policy": "same-origin",
}
# A number in a query: ASCII digits, an optional sign and point (not "３", "1_0" or "+10",
# which Python's float() takes).
_NUMBER = re.compile(r"-?[0-9]+(\.[0-9]+)?", re.ASCII)
_GRID = ("cols", "rows", "left", "top", "right", "bottom")

Route = Callable[[Request, urllib.parse.SplitResult], Response]


class TabletHandler:
    """Answers requests for ``server`` (its app, secret, port and host names)."""

    def __init__(self, server: ServerState):
        self.server = server

    def handle(self, request: Request) -> Response:
        """Check who asks, then answer; whatever fails, an answer (never a dropped line)."""
        try:
            if not request.target.startswith("/"):  # an absolute URL names another host
                raise posts.PostError(400, "", "the request must name a path, e.g. /")
            url = urllib.parse.urlsplit(request.target)
            refusal = self._check(request, url)
            if refusal is not None:
                return refusal
            routes: dict[str, Route] = {"GET": self._get, "HEAD": self._get, "POST": self._post}
            return routes.get(request.method, self._no_such_method)(request, url)
        except posts.PostError as e:
            return self.refuse(e.status, e.message, e.field)
        except InputError as e:  # nothing written, either way
            failed = _server_failure(e)
            public = self.server.app.public_error(e, failed)
            if failed is not None:  # a file the server cannot read or write: the page retries
                return self.refuse(HTTPStatus.INTERNAL_SERVER_ERROR, public)
            return self.refuse(HTTPStatus.CONFLICT, public, e.field)  # the dataset is invalid
        except OSError as e:  # the OSError's file names may be temporary files: left out
            why = f"the server could not save this post: {reason(e)}"
            return self.refuse(HTTPStatus.INTERNAL_SERVER_ERROR, why)
        except Exception as e:  # a bug: the client gets a 500, the operator the traceback
            self.server.log.block(traceback.format_exc())
            why = f"internal error: {type(e).__name__}"
            return self.refuse(HTTPStatus.INTERNAL_SERVER_ERROR, why)

    def refuse(self, status: int, message: str, field: str = "") -> Response:
        doc = {"error": message, "field": field, "status": int(status)}
        note = f"refused: {message}" if status == 403 else ""
        return _json(status, doc, note)

    # -- who may ask ---------------------------------------------------------------------
    def _check(self, request: Request, url: urllib.parse.SplitResult) -> Response | None:
        """The refusal of a request that is not the operator's, or ``None`` to go on.

        The Host and Origin come first: a page of another site gets nothing, not even the
        login. Then the secret: from the URL on a page's first load (set as a cookie, and
        redirected to the URL without it), else from the cookie or a header.
        """
        headers, server = request.headers, self.server
        host = headers.get("Host")
        why = guard.host_refusal(host, request.local, server.port, server.host_names)
        field = "Host"
        if why is None:
            why, field = guard.origin_refusal(headers.get("Origin"), host or ""), "Origin"
        api = url.path.startswith("/api/")
        fetch_site = headers.get("Sec-Fetch-Site")
        if why is None and api and fetch_site not in (None, "same-origin", "none"):
            why, field = f"a {fetch_site} request is not this server's page's", "Sec-Fetch-Site"
        if why is not None:
            return self.refuse(HTTPStatus.FORBIDDEN, why, field)
        page_load = not api and request.method in ("GET", "HEAD")
        query = _query(url.query)
        if page_load and "token" in query:
            if guard.token_matches(query["token"][0], server.token):
                return self._login(url, query)
            return self._locked("the secret in this link is not this server's (was it restarted?)")
        if guard.token_matches(guard.request_token(headers, server.port), server.token):
            return None
        if page_load:
            return self._locked("this browser does not have the server's secret")
        return self.refuse(
            HTTPStatus.FORBIDDEN,
            "this browser does not have the server's secret: open the URL the server "
            "printed (or scan its QR code); runs kept in this browser are not lost",
            "token",
        )  # fmt: skip

    def _login(self, url: urllib.parse.SplitResult, query: dict[str, list[str]]) -> Response:
        """The first load with the secret: a cookie, and the same page without it."""
        rest = [(k, v) for k, vs in query.items() if k != "token" for v in vs]
        where = url.path + ("?" + urllib.parse.urlencode(rest) if rest else "")
        cookie = guard.cookie_header(self.server.port, self.server.token)
        headers = {**HEADERS, "Location": where, "Set-Cookie": cookie}
        return Response(HTTPStatus.SEE_OTHER, b"", _HTML, headers)

    def _locked(self, why: str) -> Response:
        page = resources.files(__package__).joinpath("static", _LOCKED).read_text("utf-8")
        body = page.replace("{why}", why).encode()
        return Response(HTTPStatus.FORBIDDEN, body, _HTML, dict(HEADERS), f"refused: {why}")

    # -- routes --------------------------------------------------------------------------
    def _get(self, request: Request, url: urllib.parse.SplitResult) -> Response:
        if url.path in _STATIC:
            name, kind = _STATIC[url.path]
            body = resources.files(__package__).joinpath("static", name).read_bytes()
            return Response(HTTPStatus.OK, body, kind, dict(HEADERS))
        if url.path == "/api/session":
            return _json(HTTPStatus.OK, self.server.app.session())
        if url.path == "/api/grid":
            return _json(HTTPStatus.OK, {"tablet_px": _grid(url.query).tolist()})
        raise posts.PostError(404, "", f"no such page: {url.path[:100]}")

    def _post(self, request: Request, url: urllib.parse.SplitResult) -> Response:
        routes = {
            "/api/calibration": self.server.app.post_calibration,
            "/api/evaluation": self.server.app.post_evaluation,
        }
        if url.path not in routes:
            raise posts.PostError(404, "", f"no such endpoint: {url.path[:100]}")
        if "Content-Length" not in request.headers:
            raise posts.PostError(411, "", "a Content-Length header (bytes) is required")
        kind = (request.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if kind != "application/json":
            raise posts.PostError(415, "", f"Content-Type must be application/json (got {kind!r})")
        doc = posts.parse_json_body(request.body)
        return _json(HTTPStatus.OK, routes[url.path](doc))

    def _no_such_method(self, request: Request, url: urllib.parse.SplitResult) -> Response:
        raise posts.PostError(405, "", f"{request.method[:20]} is not answered here; GET, HEAD "
                              "or POST")  # fmt: skip


def _json(status: int, doc: Any, note: str = "") -> Response:
    body = json.dumps(doc, allow_nan=False).encode()
    return Response(int(status), body, "application/json", dict(HEADERS), note)


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
    values = [_grid_number(q, name) for name in _GRID]
    try:
        return grid_targets(int(values[0]), int(values[1]), *values[2:])
    except ValueError as e:
        field_, _, message = str(e).partition(": ")
        raise posts.PostError(400, field_, message) from None


def _grid_number(q: dict[str, list[str]], name: str) -> float:
    if len(q.get(name, [])) != 1:
        raise posts.PostError(400, name, "give exactly one value")
    text = q[name][0]
    if len(text) > 50:
        raise posts.PostError(400, name, f"not a number: {len(text)} characters")
    if not _NUMBER.fullmatch(text):
        why = "digits 0-9, with an optional - and decimal point"
        raise posts.PostError(400, name, f"not a number: {text!r} ({why})")
    v = float(text)
    if not math.isfinite(v):  # 400 digits
        raise posts.PostError(400, name, f"must be a finite number (got {text[:20]!r}...)")
    if name in ("cols", "rows") and v != int(v):
        raise posts.PostError(400, name, f"must be a whole number (got {text!r})")
    return v
