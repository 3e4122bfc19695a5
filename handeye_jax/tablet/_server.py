"""The tablet server's start-up: check the inputs, bind, print the page's URL, serve.

:func:`make_server` checks every file the posts will write and binds a :class:`TabletServer`
(HTTP: :mod:`._http`; answers: :mod:`._handler`; state: :mod:`._app`); :func:`serve` runs it
until Ctrl-C and prints the trials' summary.

Only the operator can use it (:mod:`._guard`, as Jupyter does): each start makes a random
secret, printed in the page's URL and as a QR code; the first load with it sets a cookie and
redirects to the URL without it. A request without the secret, whose ``Host`` is not this
server's address (DNS rebinding) or whose ``Origin`` is another site's page, gets a 403.
Posts are bounded: a body over ``MAX_BODY_BYTES`` is answered 413 at once (before it is
read), a run holds at most ``MAX_TOUCHES`` touches and the trials file at most
``MAX_TRIALS`` trials. No client can stall it: connections are capped and each request must
arrive whole within :attr:`Listen.request_timeout_s` (:mod:`._http`).
"""

from __future__ import annotations

import errno
import ipaddress
import socket
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._core import InputError, check_output
from ..data import load_dataset
from ..geometry import mm_per_tablet_px
from . import _guard as guard
from . import _posts as posts
from . import _trials as trials
from ._app import TabletApp
from ._calibration import MAX_BACKUPS
from ._handler import TabletHandler
from ._http import HTTPServer
from ._log import Log, printable
from ._targets import load_targets

if TYPE_CHECKING:
    from ..data import Dataset

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
# The deadline for a request's head and body together (a tablet sends them in milliseconds).
DEFAULT_REQUEST_TIMEOUT_S = 10.0
# Hosts that mean "every address of this PC": the page's URL needs one of its LAN addresses.
_WILDCARD_HOSTS = ("", "0.0.0.0", "::")
# Private addresses a UDP socket is "connected" to (nothing is sent) to learn which local
# address the PC would use to reach each private network: its LAN address(es).
_PROBE_ADDRESSES = ("10.254.254.254", "172.31.254.254", "192.168.254.254")
_BACKUPS = f"<UTC time>.bak beside it (the first and the last {MAX_BACKUPS})"


@dataclass(frozen=True)
class Listen:
    """Where the tablet server listens, and the secret that lets a browser in.

    Checked when made: ``InputError`` (a ``ValueError``) naming the field.

    Attributes:
        host: the address to listen on; ``127.0.0.1`` (this machine only) by default,
            ``0.0.0.0`` to let a tablet on the LAN load the page.
        port: the TCP port, 0 to 65535; 0 picks a free one (see ``server.url``).
        token: the secret a browser or script must show (``server.secret_url`` carries it);
            ``None``: a new random one (:func:`~.guard.new_token`) at each start. Give one only
            for scripts: at least 32 URL-safe characters. Not shown by ``repr``.
        request_timeout_s: the deadline, s, for each request's head and body together, from
            the connection's start (or the previous answer): then the server answers 408, or
            closes a connection that sent nothing. > 0.
    """

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    token: str | None = field(default=None, repr=False)  # a secret: kept out of logs
    request_timeout_s: float = DEFAULT_REQUEST_TIMEOUT_S

    def __post_init__(self) -> None:
        if self.token is not None:
            try:
                guard.check_token(self.token)
            except ValueError as e:
                raise InputError(None, "token", str(e)) from None
        if not 0 <= self.port <= 65535:
            raise InputError(None, "port", f"must be 0 to 65535 (got {self.port})")
        if not self.request_timeout_s > 0:
            raise InputError(None, "request_timeout_s",
                             f"must be > 0 s (got {self.request_timeout_s})")  # fmt: skip


@dataclass(frozen=True)
class EvaluationFiles:
    """The files of evaluation mode: what the page offers to touch, the result it evaluates,
    and where its trials go. Each is a path, or ``None``.

    Attributes:
        targets: evaluation targets, a targets JSON or a dataset TOML (tablet px).
        result: the calibration result being evaluated (recorded with each trial).
        trials: where evaluation trials are saved (JSON); ``None``:
            ``DATASET_STEM.trials.json`` beside the dataset, or ``tablet-trials.json``.
    """

    targets: str | Path | None = None
    result: str | Path | None = None
    trials: str | Path | None = None


class TabletServer(HTTPServer):
    """The HTTP server (:class:`~._http.HTTPServer`) of one :class:`~._app.TabletApp`, for
    whoever has its secret ``token``.

    ``host_names`` are names (not addresses) the operator bound it to, e.g. ``localhost``:
    requests may name the server by them as well as by the address they reached.
    """

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
        self.host_names = () if _is_ip(address[0]) else (address[0].lower(),)
        super().__init__(address, TabletHandler(self), Log(quiet), request_timeout_s,
                         posts.MAX_BODY_BYTES)  # fmt: skip

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


def make_server(
    dataset: str | Path | None = None,
    *,
    listen: Listen = Listen(),
    files: EvaluationFiles = EvaluationFiles(),
    ppi: float | None = None,
    scale: float | None = None,
    quiet: bool = False,
) -> TabletServer:
    """Check the inputs and bind the tablet server; call ``serve_forever()`` on it to run.

    Args:
        dataset: the dataset (TOML) to draw and to write touch errors into; optional.
        listen: the address, port, secret and request deadline (:class:`Listen`; by default
            ``127.0.0.1:8765``, this machine only, with a new random secret).
        files: evaluation mode's targets, result and trials file (:class:`EvaluationFiles`).
        ppi, scale: the tablet's px per inch and display scale; taken from the dataset when
            not given, required without one.
        quiet: do not log requests to standard error.

    Raises :class:`InputError` naming the file or option for bad input: ``--port`` for a port
    in use or not allowed, ``--host`` for an address that is not this PC's, ``--trials`` for a
    trials file (given or the default) that cannot be written, ``--dataset`` for a dataset
    whose folder cannot be written (calibration writes it and a backup beside it) or with
    more landmarks than a run may touch. Every file a post writes is checked here, before the
    server is bound.
    """
    host, port = listen.host, listen.port
    token = guard.new_token() if listen.token is None else listen.token
    targets, result = files.targets, files.result
    ds_path = Path(dataset) if dataset is not None else None
    ds = _dataset(ds_path) if ds_path is not None else None
    ppi, scale = _tablet_scale(ds, ppi, scale)
    default_trials = files.trials is None
    trials_path = Path(_default_trials(ds_path) if default_trials else files.trials)
    _check_outputs(ds_path, trials_path, default_trials, [targets, result])
    info = _result_info(result, ds) if result is not None else None
    app = TabletApp(
        dataset_path=ds_path,
        ppi=ppi,
        scale=scale,
        trials_path=trials_path,
        targets_path=Path(targets) if targets is not None else None,
        targets_px=load_targets(targets) if targets is not None else None,
        result=info,
        trials_doc=trials.load_trials(trials_path, ppi, scale),
    )
    try:
        return TabletServer((host, port), app, token, quiet, listen.request_timeout_s)
    except socket.gaierror as e:
        raise InputError(None, "--host", f"cannot use {host!r}: {e.strerror}") from None
    except OSError as e:
        raise _bind_error(e, host, port) from None


def _dataset(path: Path) -> Dataset:
    """The dataset to draw, with no more landmarks than a run may touch."""
    ds = load_dataset(path)
    if ds.n_landmarks > posts.MAX_TOUCHES:
        raise InputError(path, "landmarks", f"{ds.n_landmarks} landmarks; the tablet page "
                         f"takes at most {posts.MAX_TOUCHES} in a run")  # fmt: skip
    return ds


def _default_trials(dataset: Path | None) -> Path:
    """Where trials go without ``--trials``: beside the dataset, else in the current folder."""
    return (
        dataset.with_name(dataset.stem + ".trials.json") if dataset else Path("tablet-trials.json")
    )


def _tablet_scale(
    ds: Dataset | None, ppi: float | None, scale: float | None
) -> tuple[float, float]:
    """The tablet's px per inch and display scale: as given, else the dataset's."""
    if ppi is None and ds is not None:
        ppi = ds.tablet_ppi
    if scale is None and ds is not None:
        scale = ds.tablet_scale
    for name, v in (("--ppi", ppi), ("--scale", scale)):
        if v is None:
            raise InputError(None, name, "needed without --dataset, to turn tablet px into mm")
        if not np.isfinite(v) or v <= 0:
            raise InputError(None, name, f"must be a finite number > 0 (got {v})")
    return float(ppi), float(scale)


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
        why = (f"calibration writes touch_error_px into {dataset.name} and keeps previous "
               f"versions as {dataset.name}.{_BACKUPS}")  # fmt: skip
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


def _result_info(path: str | Path, ds: Dataset | None) -> dict[str, Any]:
    """What the page shows of the result being evaluated, with a note if it was fitted on
    another dataset than ``ds``."""
    from ..calibration import load_result

    r = load_result(path)
    info = {"path": str(path), "model": r.model_name, "seed": r.seed, "dataset": r.dataset_name}
    if ds is not None and info["dataset"] != ds.name:
        info["note"] = (
            f"the result was fitted on dataset {info['dataset']!r}, not on {ds.name!r}: "
            "its landmarks are not these"
        )
    return info


def serve(
    dataset: str | Path | None = None,
    *,
    listen: Listen = Listen(),
    files: EvaluationFiles = EvaluationFiles(),
    ppi: float | None = None,
    scale: float | None = None,
    quiet: bool = False,
) -> int:
    """Run the tablet server until Ctrl-C; arguments as for :func:`make_server`. Returns 0.

    Prints the page's URL with its secret (one per LAN address when listening on every
    address) and, when another device is to open it, the first as a QR code to scan.
    """
    server = make_server(dataset, listen=listen, files=files, ppi=ppi, scale=scale, quiet=quiet)
    app = server.app
    _announce(server, listen.host)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("stopped")
    finally:
        server.server_close()
    if app.trials_doc["trials"]:  # labels are the page's text: escaped for the terminal
        for line in trials.format_summary(app.trials_doc).splitlines():
            print(printable(line, sys.stdout))
    return 0


def _announce(server: TabletServer, requested: str) -> None:
    """Print the page's URLs with the secret (and a QR code for another device), the tablet's
    scale and where the posts go."""
    app = server.app
    host, port = server.server_address[:2]
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
        print(f"calibration writes touch_error_px (px) into {app.dataset_path}, keeping "
              f"previous versions as {app.dataset_path.name}.{_BACKUPS}")  # fmt: skip
    print(f"evaluation trials go to {app.trials_path}")
    sys.stdout.flush()


def _print_qr(url: str) -> None:
    """``url`` as a QR code on standard output (coloured on a terminal, plain in a file)."""
    tty = sys.stdout.isatty()
    try:
        print(guard.qr_text(url, colour=tty))
    except UnicodeEncodeError:  # an output that cannot show the block characters
        print("  (no QR code: this output cannot show it; type the URL)")
