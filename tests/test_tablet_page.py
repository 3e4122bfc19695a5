"""The tablet page in real headless Chromium: pen touches, screenshots, reloads, lost links,
and who gets in (the secret, another site's page, another host name).

Chromium is Debian's (/usr/bin/chromium, installed by .ci/run); Playwright drives it. Pen
contacts are real input events (DevTools ``Input.dispatchMouseEvent`` with
``pointerType: "pen"``), so they pass through Chromium's input pipeline like a tablet pen's.
Chromium resolves ``attacker.example`` to 127.0.0.1, as a DNS rebinding attack would make it.
"""

import io
import json
import os
import shutil
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import sync_playwright
from scipy import ndimage
from test_tablet_server import ServerProcess

from handeye_jax import Capture, load_dataset, save_dataset
from handeye_jax.tablet import Listen, grid_targets, make_server

PAPER = Path(__file__).resolve().parents[1] / "data" / "paper2023.toml"
# Debian's Chromium (.ci/install-chromium), or another one named by the user (macOS, Fedora).
CHROMIUM = os.environ.get("HANDEYE_JAX_CHROMIUM") or "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--host-resolver-rules=MAP attacker.example 127.0.0.1",
]  # fmt: skip
# The paper's tablet, a Surface Pro 7 (2736 x 1824 px at display scale 2): 1368 x 912 CSS px.
SCALE = 2.0
VIEWPORT = {"width": 1368, "height": 912}
# A landmark pixel is pure black; nothing else on the page is darker than this.
BLACK = 60


@pytest.fixture(scope="module")
def browser():
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def tablet(tmp_path):
    """The server over a copy of the paper's dataset; yields (server, dataset path, bytes)."""
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    server = make_server(ds, listen=Listen(port=0), quiet=True)
    threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True).start()
    yield server, ds, ds.read_bytes()
    server.shutdown()
    server.server_close()


def open_page(browser, url, scale=SCALE):
    context = browser.new_context(viewport=VIEWPORT, device_scale_factor=scale)
    page = context.new_page()
    page.errors = []
    page.on("pageerror", lambda e: page.errors.append(str(e)))
    page.goto(url)
    page.wait_for_selector("#tablet-info:not(:empty)")
    return page


@pytest.fixture
def page(browser, tablet):
    page = open_page(browser, tablet[0].secret_url)
    yield page
    assert page.errors == []
    page.context.close()


def pen(page, xy):
    """A pen contact at CSS px ``xy`` (press and lift), through Chromium's input pipeline."""
    cdp = page.context.new_cdp_session(page)
    for kind in ("mousePressed", "mouseReleased"):
        event = {"type": kind, "x": float(xy[0]), "y": float(xy[1]), "button": "left"}
        cdp.send("Input.dispatchMouseEvent", {**event, "clickCount": 1, "pointerType": "pen"})
    cdp.detach()


def landmark_dots(page):
    """Centres of the pure-black blobs in a screenshot, CSS px, sorted by (y, x)."""
    rgb = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"))
    dark = rgb.max(axis=2) < BLACK
    labels, n = ndimage.label(dark)
    rows_cols = np.array(ndimage.center_of_mass(dark, labels, range(1, n + 1))).reshape(-1, 2)
    xy = (rows_cols[:, ::-1] + 0.5) / page.evaluate("devicePixelRatio")
    return xy[np.lexsort((xy[:, 0], xy[:, 1]))]


def assert_dots_at(page, tablet_px):
    want = np.asarray(tablet_px, dtype=float)
    want = want[np.lexsort((want[:, 0], want[:, 1]))]
    got = landmark_dots(page)
    assert got.shape == want.shape, got
    np.testing.assert_allclose(got, want, atol=0.5)


def wait_saved(page):
    page.wait_for_selector("#status.ok", timeout=15000)
    return page.inner_text("#status")


def offsets(n, seed):
    return np.round(np.random.default_rng(seed).uniform(-6, 6, (n, 2)), 2)


def prompt(page):
    return page.inner_text("#prompt")


def test_calibration_records_pen_touches_and_writes_the_dataset(page, tablet):
    _, ds_path, original = tablet
    ds = load_dataset(ds_path)
    page.click("#start-calibration")
    assert page.is_hidden("#warning")  # devicePixelRatio 2 = the dataset's scale
    assert_dots_at(page, ds.tablet_px)  # the calibration screen, pixel by pixel
    d = offsets(ds.n_landmarks, seed=6)
    pen(page, ds.tablet_px[0] + d[0])
    page.mouse.click(20, 20)  # pen preferred: a mouse (or palm) contact is not a touch
    assert "landmark 1 (1 of 9 done)" in prompt(page)
    for m in range(1, 5):
        pen(page, ds.tablet_px[m] + d[m] + (8 if m == 4 else 0))  # landmark 4: a bad touch
    page.click('#touches tr[data-m="4"] button.retake')
    assert "landmark 4 (5 of 9 done)" in prompt(page)  # the bad touch stays until replaced
    for m in range(4, ds.n_landmarks):
        pen(page, ds.tablet_px[m] + d[m])
    assert "all 9 touched" in prompt(page)
    row = page.locator('#touches tr[data-m="2"] td').all_inner_texts()
    e = np.hypot(*d[2])
    assert row[5] == "pen" and float(row[3]) == pytest.approx(e, abs=0.01)
    assert float(row[4]) == pytest.approx(e * ds.mm_per_tablet_px, abs=0.01)
    assert ds_path.read_bytes() == original  # nothing is written before the operator sends
    page.click("#send")
    assert "9 pen;" in wait_saved(page) and "written to" in page.inner_text("#status")
    saved = load_dataset(ds_path)
    assert np.abs(saved.touch_error_px - d).max() <= 0.5
    assert saved == ds.replace(touch_error_px=saved.touch_error_px)
    [backup] = [p for p in ds_path.parent.iterdir() if p.suffix == ".bak"]
    assert backup.read_bytes() == original and backup.name in page.inner_text("#status")
    assert page.evaluate("localStorage.getItem('handeye-jax.tablet/1:outbox')") == "[]"


def test_a_reload_mid_run_keeps_the_progress(page, tablet):
    _, ds_path, _ = tablet
    ds = load_dataset(ds_path)
    d = offsets(ds.n_landmarks, seed=7)
    page.click("#start-calibration")
    for m in range(4):
        pen(page, ds.tablet_px[m] + d[m])
    page.reload()
    page.wait_for_selector("#tablet-info:not(:empty)")
    assert "landmark 4 (4 of 9 done)" in prompt(page)
    assert page.locator("#touches td", has_text="pen").count() == 4
    for m in range(4, ds.n_landmarks):
        pen(page, ds.tablet_px[m] + d[m])
    page.click("#send")
    wait_saved(page)
    assert np.abs(load_dataset(ds_path).touch_error_px - d).max() <= 0.5


def calibrate_offline(page, ds, d):
    """Touch every landmark at offsets ``d`` and press Send while the Wi-Fi is down."""
    page.route("**/api/**", lambda route: route.abort())
    page.click("#start-calibration")
    for m in range(ds.n_landmarks):
        pen(page, ds.tablet_px[m] + d[m])
    page.click("#send")
    page.wait_for_selector("#status.error")


def test_a_dropped_connection_loses_nothing(page, tablet):
    _, ds_path, original = tablet
    ds = load_dataset(ds_path)
    d = offsets(ds.n_landmarks, seed=8)
    calibrate_offline(page, ds, d)
    assert "unreachable" in page.inner_text("#status")
    page.reload()  # still offline: the page comes back from the last session it saw
    page.wait_for_selector("#outbox li")
    assert "waiting for the server" in page.inner_text("#outbox")
    assert ds_path.read_bytes() == original
    page.unroute("**/api/**")  # back online: the retry delivers it
    wait_saved(page)
    assert np.abs(load_dataset(ds_path).touch_error_px - d).max() <= 0.5
    assert page.locator("#outbox li").count() == 0


def test_evaluation_trials_report_mean_and_max_in_px_and_mm(page, tablet):
    _, ds_path, _ = tablet
    mm = load_dataset(ds_path).mm_per_tablet_px
    page.select_option("#target-source", "grid")
    grid = {"cols": 4, "rows": 2, "left": 300, "top": 200, "right": 1000, "bottom": 600}
    for key, value in grid.items():
        page.fill(f"#grid-{key}", str(value))
    page.fill("#trial-label", "stage 1")
    page.click("#start-evaluation")
    page.wait_for_selector("#run:not([hidden])")
    targets = grid_targets(4, 2, 300.0, 200.0, 1000.0, 600.0)
    assert_dots_at(page, targets)  # the evaluation screen, pixel by pixel
    means = []
    for trial, seed in ((1, 9), (2, 10)):
        if trial == 2:
            page.click("#start-evaluation")
            page.wait_for_selector("#run:not([hidden])")  # the grid comes from the server
        d = offsets(len(targets), seed)
        for t, dt in zip(targets, d, strict=True):
            pen(page, t + dt)
        page.click("#send")
        assert f"stage 1 trial {trial}" in wait_saved(page)
        means.append(np.hypot(*d.T).mean())
        doc = json.loads((ds_path.parent / "rig.trials.json").read_text())
        saved = doc["trials"][-1]
        assert saved["trial"] == trial and saved["targets"] == "grid"
        assert saved["mean_px"] == pytest.approx(means[-1], abs=0.01)
        assert saved["max_px"] == pytest.approx(np.hypot(*d.T).max(), abs=0.01)
        assert saved["mean_mm"] == pytest.approx(means[-1] * mm, abs=0.01)
        assert {t["pointer_type"] for t in saved["touches"]} == {"pen"}
    rows = [r.split("\t") for r in page.inner_text("#summary").splitlines()]
    average_mm = next(r for r in rows if r[0] == "in mm")[-1]
    assert float(average_mm) == pytest.approx(np.mean(means) * mm, abs=0.01)
    max_px = [float(v) for v in next(r for r in rows if r[0] == "max px")[1:]]
    max_mm = [float(v) for v in next(r for r in rows if r[0] == "max mm")[1:]]
    assert max_px[-1] == pytest.approx(np.mean(max_px[:2]), abs=0.01)
    np.testing.assert_allclose(np.array(max_mm), np.array(max_px) * mm, atol=0.01)
    assert max_px[0] == pytest.approx(np.hypot(*offsets(len(targets), 9).T).max(), abs=0.01)


def test_a_display_scale_other_than_the_datasets_is_warned_about(browser, tablet):
    page = open_page(browser, tablet[0].secret_url, scale=1.25)
    try:
        warning = page.inner_text("#warning")
        assert page.is_visible("#warning")
        assert "devicePixelRatio is 1.25" in warning and "scale is 2" in warning
    finally:
        page.context.close()


def marked_pixels(page):
    """How many device pixels of the board, outside the panel, are not white."""
    rgb = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"))
    box = page.locator("#panel").bounding_box()
    dpr = page.evaluate("devicePixelRatio")
    marked = rgb.min(axis=2) < 250
    x0, y0 = int(box["x"] * dpr) - 2, int(box["y"] * dpr) - 2
    x1, y1 = int((box["x"] + box["width"]) * dpr) + 2, int((box["y"] + box["height"]) * dpr) + 2
    marked[max(0, y0) : y1, max(0, x0) : x1] = False
    return int(marked.sum())


def test_rings_and_numbers_can_be_turned_off_leaving_only_the_dots(page, tablet):
    _, ds_path, _ = tablet
    ds = load_dataset(ds_path)
    assert page.is_checked("#marks")  # on by default
    with_marks = marked_pixels(page)
    page.uncheck("#marks")
    assert_dots_at(page, ds.tablet_px)
    dot_side = round(SCALE)  # one tablet px is SCALE x SCALE device px
    assert marked_pixels(page) == ds.n_landmarks * dot_side**2  # nothing but the dots
    assert with_marks > 10 * ds.n_landmarks * dot_side**2  # the rings and numbers were there
    page.click("#start-calibration")  # a run keeps it off: its current ring is not drawn
    assert marked_pixels(page) == ds.n_landmarks * dot_side**2
    page.reload()  # remembered in this browser
    page.wait_for_selector("#tablet-info:not(:empty)")
    assert not page.is_checked("#marks")
    assert_dots_at(page, ds.tablet_px)
    assert marked_pixels(page) == ds.n_landmarks * dot_side**2
    page.check("#marks")
    assert marked_pixels(page) > with_marks  # the current landmark's ring is bigger and blue


class Restartable:
    """A tablet server that restarts on the same port (the page's origin) with a dataset;
    with the same secret (as a script may give it), unless ``new_secret``."""

    def __init__(self, dataset):
        self.server = make_server(dataset, listen=Listen(port=0), quiet=True)
        self.port = self.server.server_address[1]
        threading.Thread(target=self.server.serve_forever, args=(0.05,), daemon=True).start()

    def restart(self, dataset, page=None, new_secret=False):
        token = None if new_secret else self.server.token
        self.stop()
        self.server = make_server(dataset, listen=Listen(port=self.port, token=token), quiet=True)
        threading.Thread(target=self.server.serve_forever, args=(0.05,), daemon=True).start()
        if page is not None:
            page.reload()
            self.wait_session(page)

    def wait_session(self, page):
        """Wait until the page has this server's session (its dataset's fingerprint)."""
        page.wait_for_selector("#tablet-info:not(:empty)")
        page.wait_for_function(
            "k => (JSON.parse(localStorage.getItem('handeye-jax.tablet/1:session')) || {})"
            ".dataset.key === k", arg=self.server.app.session()["dataset"]["key"])  # fmt: skip

    def stop(self):
        self.server.shutdown()
        self.server.server_close()


def two_datasets(tmp_path):
    """Two dataset files with the same landmarks (the paper's), and their bytes."""
    a, b = tmp_path / "a" / "rig.toml", tmp_path / "b" / "rig.toml"
    for path in (a, b):
        path.parent.mkdir()
        shutil.copy(PAPER, path)
    return a, b, {path: path.read_bytes() for path in (a, b)}


def test_a_run_of_another_dataset_is_not_resumed_silently(browser, tmp_path):
    """The server restarted on another dataset: the stored run is shown, kept or discarded."""
    a, b, originals = two_datasets(tmp_path)
    server = Restartable(a)
    page = open_page(browser, server.server.secret_url)
    page.on("dialog", lambda dialog: dialog.accept())

    def restart(dataset):
        server.restart(dataset, page)

    try:
        ds = load_dataset(a)
        page.click("#start-calibration")
        for m in range(3):
            pen(page, ds.tablet_px[m] + 1.0)
        assert "landmark 3 (3 of 9 done)" in prompt(page)

        restart(b)  # another dataset: the run is not resumed
        page.wait_for_selector("#stale:not([hidden])")
        text = page.inner_text("#stale")
        assert "calibration of paper2023, 3 of 9 touched" in text and "rig.toml" in text
        assert str(tmp_path) not in text  # names, never the PC's folders
        assert page.is_hidden("#run") and page.is_hidden("#menu")
        pen(page, ds.tablet_px[3])  # touches go nowhere while the operator decides
        page.click("#stale-keep")
        assert page.is_hidden("#stale") and page.is_visible("#menu")
        assert page.evaluate("localStorage.getItem('handeye-jax.tablet/1:run')") is None

        restart(a)  # its own dataset again: the kept run resumes where it was
        page.wait_for_selector("#run:not([hidden])")
        assert "landmark 3 (3 of 9 done)" in prompt(page) and page.is_hidden("#stale")
        assert "resumed the calibration run" in page.inner_text("#status")

        restart(b)
        page.wait_for_selector("#stale:not([hidden])")
        page.click("#stale-discard")
        assert page.is_hidden("#stale") and page.is_visible("#menu")
        page.click("#start-calibration")  # a fresh run on b's dataset
        assert "landmark 0 (0 of 9 done)" in prompt(page)
        assert page.evaluate("localStorage.getItem('handeye-jax.tablet/1:parked')") == "[]"
        restart(a)  # the run of a was discarded: nothing resumes, b's new run is the stranger
        page.wait_for_selector("#stale:not([hidden])")
        assert "0 of 9 touched" in page.inner_text("#stale")
        assert page.errors == []
    finally:
        page.context.close()
        server.stop()
    assert {path: path.read_bytes() for path in (a, b)} == originals


def test_touches_waiting_for_another_dataset_are_held_not_sent(browser, tmp_path):
    a, b, originals = two_datasets(tmp_path)
    server = Restartable(a)
    page = open_page(browser, server.server.secret_url)
    try:
        ds = load_dataset(a)
        d = offsets(ds.n_landmarks, seed=11)
        calibrate_offline(page, ds, d)
        page.unroute("**/api/**")
        server.restart(b, page)  # back, but serving b: a's touches must not land in b
        page.wait_for_selector("#outbox li.held")
        assert "another dataset" in page.inner_text("#outbox")
        page.wait_for_timeout(500)
        assert b.read_bytes() == originals[b] and not list(b.parent.glob("*.bak"))
        server.restart(a, page)  # a again: delivered
        wait_saved(page)
        assert np.abs(load_dataset(a).touch_error_px - d).max() <= 0.5
        assert page.locator("#outbox li").count() == 0
        assert page.errors == []
    finally:
        page.context.close()
        server.stop()
    assert b.read_bytes() == originals[b]


# -- who gets in: a real server process, as the operator starts it ----------------------------


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("real-page"))
    yield server
    server.stop()


def test_the_page_works_with_the_secret_and_is_refused_without_it(browser, real):
    context = browser.new_context(viewport=VIEWPORT, device_scale_factor=SCALE)
    try:
        page = context.new_page()
        answer = page.goto(real.url)  # without the secret: a page that says where to get it
        assert answer.status == 403
        assert "scan the QR code" in page.inner_text("body") and page.locator("#board").count() == 0
        assert page.evaluate("localStorage.length") == 0  # no app ran
        answer = page.goto(real.url + "?token=" + "z" * 43)
        assert answer.status == 403 and "was it restarted?" in page.inner_text("#why")
        assert context.cookies() == []

        page.goto(real.secret_url)  # the URL the server printed (or its QR code)
        page.wait_for_selector("#tablet-info:not(:empty)")
        assert page.url == real.url  # the secret does not stay in the address bar or history
        [cookie] = context.cookies()
        assert cookie["name"] == f"handeye-jax-token-{real.port}" and cookie["value"] == real.token
        assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
        assert page.evaluate("document.cookie") == ""  # the page's scripts cannot read it
        ds = load_dataset(real.dataset)
        d = offsets(ds.n_landmarks, seed=12)
        page.click("#start-calibration")
        for m in range(ds.n_landmarks):
            pen(page, ds.tablet_px[m] + d[m])
        page.click("#send")
        assert "written to rig.toml; previous file kept as rig.toml.20" in wait_saved(page)
        assert np.abs(load_dataset(real.dataset).touch_error_px - d).max() <= 0.5
        page.reload()  # the cookie lets it in again
        page.wait_for_selector("#tablet-info:not(:empty)")
        assert "paper2023" in page.inner_text("#tablet-info")
    finally:
        context.close()


class _EvilPage(BaseHTTPRequestHandler):
    """Another site's page on this PC (another port: another origin, the same site)."""

    def do_GET(self):
        body = b"<!doctype html><title>another site</title><p>nothing to see"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


ATTACK = """async ([target, body, token]) => {
  const out = {};
  const tries = {
    session: () => fetch(target + "api/session", {credentials: "include"}),
    post: () => fetch(target + "api/calibration", {method: "POST", mode: "no-cors",
      credentials: "include", headers: {"Content-Type": "text/plain"}, body}),
    leaked: () => fetch(target + "api/session", {headers: {"X-Handeye-Token": token}}),
  };
  for (const [name, f] of Object.entries(tries)) {
    try { out[name] = (await f()).status; } catch (e) { out[name] = "failed"; }
  }
  return out;
}"""


def test_a_page_of_another_origin_cannot_use_the_server(browser, real):
    evil = ThreadingHTTPServer(("127.0.0.1", 0), _EvilPage)
    threading.Thread(target=evil.serve_forever, args=(0.05,), daemon=True).start()
    evil_origin = f"http://127.0.0.1:{evil.server_address[1]}"
    context = browser.new_context(viewport=VIEWPORT, device_scale_factor=SCALE)
    try:
        page = context.new_page()
        page.goto(real.secret_url)  # this browser has the secret (its cookie)...
        page.wait_for_selector("#tablet-info:not(:empty)")
        page.goto(evil_origin + "/")  # ...and then opens another site's page
        before = real.dataset.read_bytes()
        ds = load_dataset(real.dataset)
        body = json.dumps(
            {
                "run_id": "evil",
                "touches": [
                    {"m": m, "tablet_px": xy, "touch_error_px": [9.0, 9.0], "pointer_type": "pen"}
                    for m, xy in enumerate(ds.tablet_px.tolist())
                ],
            }  # fmt: skip
        )
        out = page.evaluate(ATTACK, [real.url, body, real.token])
        # The browser sent them all (the server logs each refusal, naming the Origin)...
        for method, path in (("GET", "/api/session"), ("POST", "/api/calibration")):
            real.wait_log(f'"{method} {path} HTTP/1.1" 403', f"refused: Origin '{evil_origin}'")
        # ...and the page got nothing: no readable answer, no change on disk.
        assert out == {"session": "failed", "post": "failed", "leaked": "failed"}, out
        assert real.dataset.read_bytes() == before
        # The cookie it carried is good: the same request from the page's own origin passes.
        [cookie] = context.cookies(real.url)
        status, _ = real.api(
            "POST", "/api/calibration", json.loads(body),
            {"X-Handeye-Token": None, "Cookie": f"{cookie['name']}={cookie['value']}"},
        )  # fmt: skip
        assert status == 200
    finally:
        context.close()
        evil.shutdown()
        evil.server_close()
        real.dataset.write_bytes(PAPER.read_bytes())


def test_a_page_reached_by_another_host_name_is_refused(browser, real):
    """DNS rebinding: a page of attacker.example whose name now points at this PC."""
    attacker = f"http://attacker.example:{real.port}/"
    context = browser.new_context(viewport=VIEWPORT, device_scale_factor=SCALE)
    try:
        page = context.new_page()
        answer = page.goto(attacker + "?token=" + real.token)  # even with the secret
        assert answer.status == 403 and json.loads(page.inner_text("body"))["field"] == "Host"
        assert context.cookies() == []  # no login through another name
        # A script of that origin (the attacker's page, served before the name was rebound;
        # here that origin's document is the refusal) fetches from "its own" server, which is
        # this one now, even with a leaked secret.
        out = page.evaluate(
            """async (token) => {
              const r = await fetch("/api/session", {headers: {"X-Handeye-Token": token}});
              return [r.status, await r.json()];
            }""",
            real.token,
        )
        assert out[0] == 403 and out[1]["field"] == "Host" and "attacker.example" in out[1]["error"]
        real.wait_log('"GET /api/session HTTP/1.1" 403', "refused: Host 'attacker.example:")
    finally:
        context.close()


def test_a_restarted_server_asks_for_its_new_url_and_keeps_the_runs(browser, tmp_path):
    ds_path = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds_path)
    original = ds_path.read_bytes()
    server = Restartable(ds_path)
    page = open_page(browser, server.server.secret_url)
    try:
        ds = load_dataset(ds_path)
        d = offsets(ds.n_landmarks, seed=13)
        calibrate_offline(page, ds, d)  # sent while the link is down: kept, retried every 3 s
        server.restart(ds_path, new_secret=True)  # the operator restarted the server
        page.unroute("**/api/**")
        page.wait_for_selector("#status:has-text('not sent')", timeout=15000)
        assert "does not have the server's secret" in page.inner_text("#status")
        assert "open the URL it printed" in page.inner_text("#warning")
        assert "waiting for the server" in page.inner_text("#outbox")  # kept, not refused
        page.reload()  # the old cookie no longer opens the page: it says where to go
        assert "scan the QR code" in page.inner_text("body")
        assert len(json.loads(page.evaluate(
            "localStorage.getItem('handeye-jax.tablet/1:outbox')"))) == 1  # fmt: skip
        assert ds_path.read_bytes() == original
        page.goto(server.server.secret_url)  # the new URL (its QR code): delivered
        assert "written to rig.toml" in wait_saved(page)
        assert np.abs(load_dataset(ds_path).touch_error_px - d).max() <= 0.5
        assert page.errors == []
    finally:
        page.context.close()
        server.stop()


def test_a_recalibration_run_of_three_landmarks_is_taken_and_saved(browser, tmp_path):
    """After a pen change the operator touches a few landmarks (issue 17): a dataset of three
    is drawn, touched and saved like one of nine."""
    full = load_dataset(PAPER)
    corners = np.array([0, 2, 6])
    fields = ("tablet_px", "image_px", "depth_mm", "hand_xy_mm", "hand_angle_deg",
              "touch_error_px")  # fmt: skip
    ds_path = tmp_path / "pen3.toml"
    save_dataset(full.replace(name="pen3", **{f: getattr(full, f)[corners] for f in fields}),
                 ds_path)  # fmt: skip
    ds = load_dataset(ds_path)
    server = make_server(ds_path, listen=Listen(port=0), quiet=True)
    threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True).start()
    page = open_page(browser, server.secret_url)
    try:
        assert "pen3: 3 landmarks" in page.inner_text("#tablet-info")
        page.click("#start-calibration")
        assert_dots_at(page, ds.tablet_px)  # three dots, where the dataset says
        d = offsets(3, seed=11)
        for m in range(3):
            pen(page, ds.tablet_px[m] + d[m])
        assert "all 3 touched" in prompt(page)
        page.click("#send")
        assert "3 pen;" in wait_saved(page)
        saved = load_dataset(ds_path)
        assert saved.n_landmarks == 3 and np.abs(saved.touch_error_px - d).max() <= 0.5
        assert saved == ds.replace(touch_error_px=saved.touch_error_px)
        assert page.errors == []
    finally:
        page.context.close()
        server.shutdown()
        server.server_close()


def test_pictures_show_every_landmark_alone_and_the_captures_are_listed(browser, tmp_path):
    paper = load_dataset(PAPER)
    first = paper.captures[0]
    second = Capture([330.0, -60.0, 370.0], 60.0, [0, 4, 8], first.image_px[[0, 4, 8]],
                        first.depth_mm[[0, 4, 8]] + 80.0)  # fmt: skip
    path = tmp_path / "rig.toml"
    save_dataset(paper.replace(captures=[first, second]), path)
    before = path.read_bytes()
    server = make_server(path, listen=Listen(port=0), quiet=True)
    threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True).start()
    page = open_page(browser, server.secret_url)
    try:
        items = page.locator("#captures li").all_inner_texts()
        assert items == [
            "hand at (320.0, -70.0, 290.0) mm, 90.0 deg: 9 of 9 landmarks",
            "hand at (330.0, -60.0, 370.0) mm, 60.0 deg: 3 of 9 landmarks",
        ]
        assert page.is_checked("#marks")  # rings and numbers on: a picture leaves them out
        page.click("#start-pictures")
        assert not page.locator("#panel").is_visible()
        assert_dots_at(page, paper.tablet_px)  # every landmark at once
        rgb = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"))
        dot_side = round(SCALE)
        assert int((rgb.min(axis=2) < 250).sum()) == paper.n_landmarks * dot_side**2
        pen(page, (60, 60))  # the picture is taken: a touch brings the panel back
        page.wait_for_selector("#panel", state="visible")
        assert page.locator("#menu").is_visible() and prompt(page) == ""  # no run started
        assert marked_pixels(page) > 10 * paper.n_landmarks * dot_side**2  # rings again
        # Pictures from higher up see smaller dots: 2 tablet px, remembered in this browser.
        page.select_option("#dot-px", "2")
        page.reload()
        page.wait_for_selector("#tablet-info:not(:empty)")
        assert page.input_value("#dot-px") == "2"
        page.click("#start-pictures")
        assert_dots_at(page, paper.tablet_px)  # centred where they were
        rgb = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"))
        assert int((rgb.min(axis=2) < 250).sum()) == paper.n_landmarks * (2 * dot_side) ** 2
        assert path.read_bytes() == before
        assert page.errors == []
    finally:
        page.context.close()
        server.shutdown()
        server.server_close()


def test_a_version_1_dataset_lists_its_one_picture_and_how_to_take_more(page):
    items = page.locator("#captures li").all_inner_texts()
    assert items[0] == "hand at (320.0, -70.0, 290.0) mm, 90.0 deg: 9 of 9 landmarks"
    assert "handeye-jax convert" in items[1]
