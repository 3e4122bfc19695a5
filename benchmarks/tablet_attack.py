"""The tablet server under attack (issue 23, section 1), as a stranger on the network does it.

    python benchmarks/tablet_attack.py [--server tablet|waitress|cheroot|uvicorn]
        [--tree PATH] [--connections 1100] [--seconds 10] [--nofile 1024] [--resets 200]
        [--attacks slow,resets,escapes]

The server runs in its own process with ``RLIMIT_NOFILE = --nofile`` (the desktop's usual
``ulimit -n 1024``): ``tablet`` is ``python -m handeye_jax.cli tablet`` from ``--tree`` (this
checkout by default; give another, e.g. main's, to compare); the others serve a one-line WSGI
or ASGI app with the library's default settings, to weigh a server library against our own
(they are not the project's dependencies: ``pip install waitress cheroot uvicorn`` first).

1. **Slow connections.** ``--connections`` connections each send a request line, then one
   header line every ``--drip`` s, and never finish; a connection the server closes is opened
   again at the next round (as slowloris does). Meanwhile the operator asks for a page every
   0.25 s on a new connection, with a 5 s time-out. Printed: the operator's answers (how many
   came, median and max seconds), and the server's CPU over the attack (utime + stime from
   ``/proc``, in % of one core).
2. **Resets.** ``--resets`` connections send half a request and are reset (``SO_LINGER`` 0);
   printed: the lines and bytes this added to the server's log (standard error).
3. **Escapes.** A request whose path holds ESC, OSC and C1 bytes; printed: whether any control
   byte reached the log.

Everything goes to 127.0.0.1 only, and every loop is bounded in count and time.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "data" / "paper2023.toml"
TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")
# Minimal apps for the libraries, each with its default settings.
_WSGI_APP = (
    "def app(environ, start_response):\n"
    "    start_response('200 OK', [('Content-Type', 'text/plain'), ('Content-Length', '2')])\n"
    "    return [b'ok']\n"
)
_LIBRARIES = {
    "waitress": _WSGI_APP + "import waitress\nwaitress.serve(app, host='127.0.0.1', port=PORT)\n",
    "cheroot": _WSGI_APP + "from cheroot import wsgi\n"
    "wsgi.Server(('127.0.0.1', PORT), app).safe_start()\n",
    "uvicorn": "import uvicorn\n"
    "async def app(scope, receive, send):\n"
    "    if scope['type'] != 'http':\n"
    "        return\n"
    "    await send({'type': 'http.response.start', 'status': 200, 'headers': []})\n"
    "    await send({'type': 'http.response.body', 'body': b'ok'})\n"
    "uvicorn.run(app, host='127.0.0.1', port=PORT, http='h11', log_level='info')\n",
}


# The server's command, run after setting its file limit (no preexec_fn: a fork of a process
# with threads, e.g. JAX's in the test suite, may deadlock).
_LIMITED = (
    "import resource, runpy, sys\n"
    "n = int(sys.argv.pop(1))\n"
    "resource.setrlimit(resource.RLIMIT_NOFILE, (n, n))\n"
    "if sys.argv[1] == '-m':\n"
    "    sys.argv = sys.argv[2:]\n"
    "    runpy.run_module(sys.argv[0], run_name='__main__', alter_sys=True)\n"
    "else:\n"
    "    exec(sys.argv[2])\n"
)


def raise_own_file_limit(need: int) -> None:
    """Let this process (the attacker) open ``need`` sockets."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < need:
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(need, hard), hard))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """A server process under ``RLIMIT_NOFILE = nofile``; its log (standard error) collected.

    ``kind`` ``"tablet"`` runs ``handeye-jax tablet`` from ``tree`` over a copy of the paper's
    dataset in ``folder`` and reads its URL and secret from its first line; a library's name
    runs its minimal app.
    """

    def __init__(self, kind: str, folder: Path, tree: Path = ROOT, nofile: int = 1024):
        env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONUNBUFFERED": "1"}
        self.token = None
        if kind == "tablet":
            dataset = folder / "rig.toml"
            shutil.copy(PAPER, dataset)
            cmd = ["-m", "handeye_jax.cli", "tablet", "--dataset", str(dataset), "--port", "0"]
        else:
            self.port = _free_port()
            cmd = ["-c", _LIBRARIES[kind].replace("PORT", str(self.port))]
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _LIMITED, str(nofile), *cmd],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=folder,
        )  # fmt: skip
        self.log = bytearray()
        self.lines = 0
        threading.Thread(target=self._read_log, daemon=True).start()
        if kind == "tablet":
            first = self.proc.stdout.readline().decode()
            match = re.match(r"tablet page: http://127\.0\.0\.1:(\d+)/\?token=([\w-]+)", first)
            assert match, first
            self.port, self.token = int(match[1]), match[2]
            self.path = "/api/session"
        else:
            self.path = "/"
        threading.Thread(target=self.proc.stdout.read, daemon=True).start()
        self._wait_ready()

    def _read_log(self) -> None:
        for line in self.proc.stderr:
            self.log += line
            self.lines += 1

    def _wait_ready(self, timeout_s: float = 30.0) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            if self.ask(timeout_s=2.0) is not None:
                return
            time.sleep(0.1)
        raise RuntimeError(f"the server did not answer: {bytes(self.log[-500:])!r}")

    def request(self, path: str | None = None) -> bytes:
        """One whole request, with the secret when the server has one."""
        secret = f"X-Handeye-Token: {self.token}\r\n" if self.token else ""
        return (f"GET {path or self.path} HTTP/1.1\r\nHost: 127.0.0.1:{self.port}\r\n{secret}"
                "Connection: close\r\n\r\n").encode()  # fmt: skip

    def ask(self, path: str | None = None, timeout_s: float = 5.0) -> float | None:
        """Seconds until the answer's status line came on a new connection; ``None`` if none
        came within ``timeout_s``."""
        t0 = time.monotonic()
        try:
            with socket.create_connection(("127.0.0.1", self.port), timeout=timeout_s) as s:
                s.sendall(self.request(path))
                s.settimeout(max(0.01, timeout_s - (time.monotonic() - t0)))
                if not s.recv(100).startswith(b"HTTP/1."):
                    return None
        except OSError:
            return None
        return time.monotonic() - t0

    def cpu_s(self) -> float:
        """CPU seconds the server process has used (user + system, all its threads)."""
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) * TICK_S

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


class SlowAttack:
    """``n`` connections that send a request line, then a header line per :meth:`drip`, and
    never end it; one the server closed is opened again at the next :meth:`drip`."""

    def __init__(self, port: int, n: int):
        self.port = port
        self.socks: list[socket.socket | None] = [None] * n
        self.started = [False] * n
        self.reopened = 0

    def drip(self) -> None:
        head = f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{self.port}\r\n".encode()
        for i, s in enumerate(self.socks):
            if s is None:
                s = self.socks[i] = socket.socket()
                s.setblocking(False)
                s.connect_ex(("127.0.0.1", self.port))
                self.started[i] = False
                self.reopened += 1
                continue  # the line goes once the connection is made
            try:
                s.send(b"X-Slow: 1\r\n" if self.started[i] else head)
                self.started[i] = True
            except (BlockingIOError, InterruptedError):
                pass  # not connected yet, or its buffer is full: next round
            except OSError:  # closed by the server (reset, broken pipe): open it again
                s.close()
                self.socks[i] = None

    def open(self) -> int:
        """How many connections are open (as this side sees them)."""
        return sum(s is not None for s in self.socks)

    def close(self) -> None:
        for s in self.socks:
            if s is not None:
                s.close()
        self.socks = [None] * len(self.socks)


def slow_attack(server: Server, n: int, seconds: float, drip_s: float = 2.0) -> dict:
    """The operator's answers and the server's CPU while ``n`` slow connections hold on."""
    attack = SlowAttack(server.port, n)
    t_end = time.monotonic() + 2 * drip_s
    while time.monotonic() < t_end:  # open them all, and send their first lines
        attack.drip()
        time.sleep(0.2)
    latencies: list[float | None] = []
    stop = threading.Event()

    def operator() -> None:
        while not stop.is_set():
            latencies.append(server.ask(timeout_s=5.0))
            stop.wait(0.25)

    cpu0, t0 = server.cpu_s(), time.monotonic()
    worker = threading.Thread(target=operator)
    worker.start()
    next_drip = t0
    while time.monotonic() - t0 < seconds:
        if time.monotonic() >= next_drip:
            attack.drip()
            next_drip += drip_s
        time.sleep(0.05)
    stop.set()
    worker.join()
    cpu = (server.cpu_s() - cpu0) / (time.monotonic() - t0)
    held = attack.open()
    attack.close()
    answered = [t for t in latencies if t is not None]
    return {
        "asked": len(latencies),
        "answered": len(answered),
        "median_s": statistics.median(answered) if answered else None,
        "max_s": max(answered) if answered else None,
        "cpu_core": cpu,
        "open_at_end": held,
        "reopened": attack.reopened,
    }


def reset_flood(server: Server, n: int) -> dict:
    """Lines and bytes ``n`` reset connections add to the server's log."""
    time.sleep(0.5)
    lines0, bytes0 = server.lines, len(server.log)
    for _ in range(n):
        try:
            s = socket.create_connection(("127.0.0.1", server.port), timeout=5)
        except OSError:
            continue
        s.sendall(b"POST /api/calibration HTTP/1.1\r\nContent-Length: 100\r\n")
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        s.close()  # a reset, not a close
    time.sleep(1.5)
    return {"lines": server.lines - lines0, "bytes": len(server.log) - bytes0}


def escapes(server: Server) -> dict:
    """Whether control bytes of a request's path reach the log."""
    before = len(server.log)
    path = "/\x1b]0;pwned\x07\x1b[2J\x9b31m/x"
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.sendall(server.request().replace(server.path.encode(), path.encode("latin-1"), 1))
        try:
            s.recv(65536)
        except OSError:
            pass
    time.sleep(0.5)
    logged = bytes(server.log[before:])
    raw = any(b in logged for b in (b"\x1b", b"\x07", b"\xc2\x9b", b"\x9b"))
    return {"control_bytes_in_log": raw, "log": logged[-300:]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--server", default="tablet", choices=["tablet", *_LIBRARIES])
    p.add_argument("--tree", type=Path, default=ROOT, help="source tree of handeye_jax")
    p.add_argument("--connections", type=int, default=1100)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--drip", type=float, default=2.0, help="seconds between header lines")
    p.add_argument("--nofile", type=int, default=1024, help="the server's RLIMIT_NOFILE")
    p.add_argument("--resets", type=int, default=200)
    p.add_argument("--attacks", default="slow,resets,escapes",
                   help="which attacks, in this order (a server the first stalled may log "
                   "more at the next)")  # fmt: skip
    args = p.parse_args()
    attacks = args.attacks.split(",")
    raise_own_file_limit(args.connections + 200)
    with tempfile.TemporaryDirectory() as tmp:
        server = Server(args.server, Path(tmp), args.tree.resolve(), args.nofile)
        try:
            print(f"server: {args.server} ({args.tree}), RLIMIT_NOFILE {args.nofile}")
            print(f"operator's answer before the attack: {_s(server.ask())}")
            if "slow" in attacks:
                _report_slow(server, args)
            if "resets" in attacks:
                resets = reset_flood(server, args.resets)
                print(f"{args.resets} reset connections: {resets['lines']} log lines, "
                      f"{resets['bytes']} bytes")  # fmt: skip
            if "escapes" in attacks:
                esc = escapes(server)
                print(f"control bytes of a request path in the log: "
                      f"{esc['control_bytes_in_log']}")  # fmt: skip
        finally:
            server.stop()


def _report_slow(server: Server, args: argparse.Namespace) -> None:
    slow = slow_attack(server, args.connections, args.seconds, args.drip)
    print(f"{args.connections} slow connections, {args.seconds:g} s: operator answered "
          f"{slow['answered']} of {slow['asked']}, median {_s(slow['median_s'])}, max "
          f"{_s(slow['max_s'])}; server CPU {100 * slow['cpu_core']:.1f} % of a core; "
          f"connections reopened by the attacker {slow['reopened']}")  # fmt: skip
    time.sleep(1.0)
    print(f"operator's answer after the attack: {_s(server.ask(timeout_s=10.0))}")


def _s(t: float | None) -> str:
    return "none" if t is None else f"{t:.3f} s"


if __name__ == "__main__":
    main()
