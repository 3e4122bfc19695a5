"""Who may use the tablet server: its secret, its own Host and Origin, as Jupyter does it.

* **The secret.** Each server start makes a random secret (:func:`new_token`). The URL the
  server prints carries it (``?token=...``), also as a QR code for the tablet to scan
  (:func:`qr_text`). The first page load with it gets an HttpOnly, SameSite=Strict cookie
  (:func:`cookie_header`); scripts send it in an ``X-Handeye-Token`` or
  ``Authorization: token ...`` header instead (:func:`request_token`).
* **The Host.** A request must name this server as the address it connected to, by IP, or
  ``localhost`` on a loopback connection (:func:`host_refusal`). A page on
  ``attacker.example`` whose name was pointed at this PC (DNS rebinding) sends
  ``Host: attacker.example`` and is refused.
* **The Origin.** A request a browser sends from a page must come from this server's own page
  (:func:`origin_refusal`).
"""

from __future__ import annotations

import hmac
import io
import ipaddress
import re
import secrets
import urllib.parse
from email.message import Message

import segno

TOKEN_HEADER = "X-Handeye-Token"
# 32 random bytes, URL-safe base64: 43 characters; a given secret must be as hard to guess.
TOKEN_BYTES = 32
MIN_TOKEN_CHARS = 32
_TOKEN_CHARS = re.compile(r"[A-Za-z0-9_-]+")
_LOOPBACK_NAMES = ("localhost",)
# Compact QR codes use half blocks drawn in the terminal's text colour: white on black, set
# explicitly, reads the same on a light and a dark terminal.
_QR_COLOURS = ("\x1b[97;40m", "\x1b[0m")


def new_token() -> str:
    """A new random secret: 32 bytes from :mod:`secrets`, URL-safe (43 characters)."""
    return secrets.token_urlsafe(TOKEN_BYTES)


def check_token(token: str) -> str:
    """``token`` if it can be a secret: at least 32 URL-safe characters; else ``ValueError``."""
    strong = isinstance(token, str) and len(token) >= MIN_TOKEN_CHARS
    if not strong or not _TOKEN_CHARS.fullmatch(token):
        raise ValueError(
            f"must be at least {MIN_TOKEN_CHARS} characters of A-Z a-z 0-9 _ - (e.g. from "
            "secrets.token_urlsafe(32))"
        )
    return token


def cookie_name(port: int) -> str:
    """The cookie holding the secret; cookies are shared by every port of a host, names not."""
    return f"handeye-jax-token-{port}"


def cookie_header(port: int, token: str) -> str:
    """The ``Set-Cookie`` value: the page's scripts cannot read it, other sites do not send it;
    it lasts until the browser closes."""
    return f"{cookie_name(port)}={token}; Path=/; HttpOnly; SameSite=Strict"


def request_token(headers: Message, port: int) -> str | None:
    """The secret a request carries: its ``X-Handeye-Token`` or ``Authorization: token``
    header, else this server's cookie; ``None`` without one."""
    given = headers.get(TOKEN_HEADER)
    if given:
        return given.strip()
    scheme, _, value = (headers.get("Authorization") or "").partition(" ")
    if scheme.lower() == "token" and value.strip():
        return value.strip()
    name = cookie_name(port)
    # Cookies of other servers on this host come along too: read ours, ignore the rest.
    for header in headers.get_all("Cookie") or ():
        for part in header.split(";"):
            key, eq, value = part.strip().partition("=")
            if eq and key == name:
                return value.strip().strip('"')
    return None


def token_matches(given: str | None, token: str) -> bool:
    """Whether ``given`` is the secret, compared in constant time."""
    return given is not None and hmac.compare_digest(given.encode(), token.encode())


def _split_host(text: str) -> tuple[str, int] | None:
    """``(host, port)`` of a ``Host`` header's ``name[:port]`` (port 80 when not given), lower
    case, IPv6 without brackets; ``None`` if it is not one."""
    if not text or any(c in text for c in "/?#@\\ \t"):
        return None
    try:
        parts = urllib.parse.urlsplit("//" + text)
        host, port = parts.hostname, parts.port
    except ValueError:
        return None
    if not host:
        return None
    return host.lower(), 80 if port is None else port


def _ip(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        ip = ipaddress.ip_address(text.split("%")[0])
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped  # an IPv4 client of a dual-stack socket
    return ip


def host_refusal(
    host: str | None, local_address: str, port: int, names: tuple[str, ...] = ()
) -> str | None:
    """Why a request's ``Host`` is not this server's, or ``None`` if it is.

    Args:
        host: the ``Host`` header, e.g. ``"192.168.1.20:8765"``.
        local_address: the address of this PC that the connection reached (its socket name).
        port: the port the server listens on.
        names: further host names the operator gave (``--host``), lower case.

    This server's own names are the IP address the connection reached, ``localhost`` when that
    is a loopback address, and ``names``; each with the server's port.
    """
    if host is None:
        return "the request has no Host header"
    split = _split_host(host)
    if split is None:
        return f"Host {host[:100]!r} is not a host name"
    name, got_port = split
    if got_port != port:
        return f"Host {host[:100]!r} names port {got_port}, not this server's {port}"
    local = _ip(local_address)
    ip = _ip(name)
    if ip is not None and ip == local:
        return None
    if name in names or (name in _LOOPBACK_NAMES and local is not None and local.is_loopback):
        return None
    return (f"Host {host[:100]!r} is not this server's address; open the URL it printed "
            "(a page of another site pointed at this PC is refused)")  # fmt: skip


def origin_refusal(origin: str | None, host: str) -> str | None:
    """Why a request's ``Origin`` is not this server's own page, or ``None``.

    ``host`` is the request's ``Host``, already checked to be this server's: the page the
    server serves has the origin ``http://HOST``. No ``Origin`` (a script, or a browser
    loading a page) is allowed: the secret guards those.
    """
    if origin is None:
        return None
    parts = urllib.parse.urlsplit(origin)
    own = _split_host(host)
    try:
        theirs = (parts.hostname, parts.port or 80) if parts.scheme == "http" else None
    except ValueError:
        theirs = None
    if theirs is None or own is None or theirs != own or parts.path not in ("", "/"):
        return (f"Origin {origin[:100]!r} is not this server's page (http://{host}); a page of "
                "another site cannot use it")  # fmt: skip
    return None


def qr_text(url: str, colour: bool) -> str:
    """``url`` as a compact QR code in text (two modules per character cell).

    With ``colour``, ANSI escapes paint it white on black, so it scans on a light terminal
    too; without them (output to a file) it is right on a dark one.
    """
    out = io.StringIO()
    segno.make(url, error="l").terminal(out=out, compact=True, border=2)
    lines = out.getvalue().rstrip("\n").split("\n")
    if colour:
        lines = [_QR_COLOURS[0] + line + _QR_COLOURS[1] for line in lines]
    return "\n".join(lines)
