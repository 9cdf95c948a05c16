"""flocking play in a real browser: headless Chromium driven by Playwright.

Needs Debian's ``chromium`` (``apt-get install -y chromium``) and ``pip install playwright``
(no ``playwright install``: the system Chromium is used); skipped when either is missing.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
import tomllib

import pytest

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
if not os.path.exists(CHROMIUM):
    pytest.skip("no chromium here (apt-get install -y chromium)", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")
pytest.importorskip("starlette", reason="the play extra is not installed (pip install 'flocking[play]')")

SRC = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, "src"))
ENV = {**os.environ, "PYTHONPATH": SRC}
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]


def serve(*options):
    """``flocking play`` with ``options`` in a subprocess; yields its address."""
    proc = subprocess.Popen([sys.executable, "-m", "flocking", "play", "--port", "0", "--no-browser", *options],
                            env=ENV, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        match = re.search(r"http://127\.0\.0\.1:\d+/", line)
        assert match, line + proc.stderr.read()
        yield match.group(0)
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        proc.stderr.close()


@pytest.fixture(scope="module")
def url():
    yield from serve("--n", "2000", "--noise", "0.5")


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        try:
            b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        except Exception as err:  # a chromium that cannot start here
            pytest.skip(f"chromium does not start: {str(err).splitlines()[0]}")
        yield b
        b.close()


@pytest.fixture
def page(browser, url):
    # bypass_csp: Playwright polls string predicates with eval, which the page's CSP forbids
    context = browser.new_context(viewport={"width": 1280, "height": 1000}, accept_downloads=True,
                                  bypass_csp=True)
    page = context.new_page()
    errors = []
    page.on("pageerror", lambda err: errors.append(str(err)))
    page.goto(url)
    page.wait_for_function("window.flockPlay && flockPlay.frames > 5", timeout=30_000)
    yield page
    context.close()
    assert not errors, errors


def lit_fraction(page) -> float:
    """The fraction of canvas pixels that are not the background."""
    return page.evaluate("""() => {
        const c = document.getElementById('flock');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let lit = 0;
        for (let o = 0; o < d.length; o += 4) if (d[o] !== 15 || d[o + 1] !== 20 || d[o + 2] !== 32) lit++;
        return lit / (c.width * c.height);
    }""")


def test_page_draws_the_flock(page):
    assert page.title() == "flocking play"
    assert page.evaluate("flockPlay.n") == 2000
    assert 0.01 < lit_fraction(page) < 0.9  # particles, not an empty or a blank canvas
    assert re.fullmatch(r"0\.\d{3}", page.inner_text("#phi"))
    assert re.search(r"step \d+ · N = 2000 · box 31\.6 × 31\.6", page.inner_text("#readout").replace("   ", " "))


def test_noise_slider_dissolves_the_flock(page):
    page.select_option("#init", "aligned")  # a fresh, perfectly aligned flock
    page.wait_for_function("flockPlay.model.noise === 0.5 && flockPlay.phi > 0.9")
    page.focus("#noise")
    page.keyboard.press("End")  # the slider to its maximum, as a keyboard user would
    assert page.input_value("#noise") == "6.28"  # the last 0.01 step below 2 pi
    page.wait_for_function("flockPlay.model.noise === 6.28", timeout=10_000)
    # at eta ~ 2 pi headings are random: phi ~ 1/sqrt(N) ~ 0.02; 0.2 is 9 standard deviations
    page.wait_for_function("flockPlay.phi < 0.2", timeout=30_000)
    assert page.inner_text('output[for="noise"]') == "6.28"


def test_export_config_runs_with_flocking_run(page, tmp_path):
    page.check('input[name="neighbours"][value="topological"]')
    page.wait_for_function("flockPlay.model.neighbours === 'topological'")
    assert page.is_visible("#k") and not page.is_visible("#radius")
    page.focus("#alignment")
    page.keyboard.press("Home")
    page.wait_for_function("flockPlay.model.alignment === 0")
    with page.expect_download() as download:
        page.click("#export")
    path = tmp_path / download.value.suggested_filename
    download.value.save_as(path)
    config = tomllib.loads(path.read_text())
    assert (config["neighbours"], config["alignment"], config["n"]) == ("topological", 0.0, 2000)
    out = tmp_path / "run"
    result = subprocess.run([sys.executable, "-m", "flocking", "run", "--config", str(path), "--steps", "5",
                             "--out", str(out), "--quiet"], env=ENV, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert tomllib.loads((out / "config.toml").read_text())["neighbours"] == "topological"


def test_snapshot_is_a_png(page, tmp_path):
    with page.expect_download() as download:
        page.click("#snapshot")
    path = tmp_path / "snap.png"
    download.value.save_as(path)
    assert download.value.suggested_filename.startswith("flocking-step-")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 5000


def test_pause_step_and_errors_are_shown(page):
    page.click("#play")
    page.wait_for_function("!flockPlay.running")
    assert page.inner_text("#play") == "Play"
    # the pause may land while a frame's steps are taken: that frame follows the reply
    time.sleep(0.3)
    step = page.evaluate("flockPlay.step")
    page.click("#step")
    page.wait_for_function(f"flockPlay.step === {step + 1}")
    time.sleep(0.3)
    assert page.evaluate("flockPlay.step") == step + 1  # still paused
    page.fill("#n", "300000")
    page.press("#n", "Enter")
    page.wait_for_function("flockPlay.errors.length > 0")
    assert "n: must be at most 200000" in page.inner_text("#message")
    assert page.evaluate("flockPlay.n") == 2000


def test_three_dimensions_turn_with_the_mouse(page):
    page.check('input[name="dim"][value="3"]')
    page.wait_for_function("flockPlay.dim === 3 && flockPlay.n === 2000")
    assert page.is_visible("#hint")
    page.click("#play")  # pause, so that only the view changes
    page.wait_for_function("!flockPlay.running")
    time.sleep(0.3)
    before = page.evaluate("document.getElementById('flock').toDataURL()")
    assert lit_fraction(page) > 0.005
    box = page.locator("#flock").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 120, y + 40, steps=8)
    page.mouse.up()
    page.wait_for_timeout(200)
    after = page.evaluate("document.getElementById('flock').toDataURL()")
    assert after != before and page.evaluate("flockPlay.step") == page.evaluate("flockPlay.step")


def test_ten_thousand_particles_stream_at_30_frames_per_second(page):
    page.fill("#n", "10000")
    page.press("#n", "Enter")
    page.wait_for_function("flockPlay.n === 10000", timeout=20_000)
    page.wait_for_timeout(1000)
    rates = []
    for _ in range(2):  # the best of two 3-second windows: the machine is shared
        frames, start = page.evaluate("[flockPlay.frames, performance.now()]")
        page.wait_for_timeout(3000)
        frames2, end = page.evaluate("[flockPlay.frames, performance.now()]")
        rates.append((frames2 - frames) / (end - start) * 1000)
    drawn = page.evaluate("flockPlay.fps")
    print(f"10^4 particles, 2D: {max(rates):.1f} frames/s received, {drawn:.1f} drawn")
    assert max(rates) >= 30


def pixel(page, x, y):
    """The canvas's RGB at a fraction ``(x, y)`` of its width and height from the top left."""
    return page.evaluate("""([x, y]) => {
        const c = document.getElementById('flock');
        return [...c.getContext('2d').getImageData(Math.round(x * c.width), Math.round(y * c.height), 1, 1).data]
            .slice(0, 3);
    }""", [x, y])


def test_a_click_drops_an_obstacle_that_is_drawn_and_a_second_click_removes_it(page, tmp_path):
    page.click("#space summary")
    page.fill("#obstacle-radius", "3")  # a disc of radius 3 in a box of 31.6: 19 % of the width across
    page.click("#play")  # paused, so that no particle crosses the centre between the frames compared
    page.wait_for_function("!flockPlay.running")
    box = page.locator("#flock").bounding_box()
    page.mouse.click(box["x"] + 0.5 * box["width"], box["y"] + 0.25 * box["height"])
    page.wait_for_function("flockPlay.model.obstacles && flockPlay.model.obstacles.length === 1")
    (obstacle,) = page.evaluate("flockPlay.model.obstacles")
    side = page.evaluate("flockPlay.model.box[0]")
    assert obstacle["radius"] == 3 and obstacle["centre"] == pytest.approx([side / 2, 0.75 * side], abs=0.1)
    assert page.inner_text("#space-state") == "1 obstacle"
    page.wait_for_timeout(300)
    page.screenshot(path=tmp_path / "obstacle.png")
    print(f"screenshot: {tmp_path / 'obstacle.png'}")
    # the disc is drawn where it was dropped: its fill (rgba(92, 102, 124, 0.92) over the background)
    # at its centre and 0.8 of its radius off it, where no particle is left
    disc = [round(15 + 0.92 * 77), round(20 + 0.92 * 82), round(32 + 0.92 * 92)]
    for dx in (0.0, 0.8 * 3 / side, -0.8 * 3 / side):
        assert pixel(page, 0.5 + dx, 0.25) == pytest.approx(disc, abs=2)
    # one dropped by the left side shows across the right one too: its periodic image
    page.mouse.click(box["x"] + 0.03 * box["width"], box["y"] + 0.75 * box["height"])
    page.wait_for_function("flockPlay.model.obstacles.length === 2")
    page.wait_for_timeout(300)
    for x in (0.03, 0.97):
        assert pixel(page, x, 0.75) == pytest.approx(disc, abs=2)
    page.mouse.click(box["x"] + 0.97 * box["width"], box["y"] + 0.75 * box["height"])  # on its image: removed
    page.wait_for_function("flockPlay.model.obstacles.length === 1")
    page.mouse.click(box["x"] + 0.52 * box["width"], box["y"] + 0.27 * box["height"])  # on it: removed
    page.wait_for_function("!flockPlay.model.obstacles")
    page.wait_for_timeout(300)
    for x, y in ((0.5, 0.25), (0.03, 0.75), (0.97, 0.75)):
        assert pixel(page, x, y) == [15, 20, 32]  # the background again: the flock stayed paused
    assert page.inner_text("#space-state") == "none"


# -- on a projector, a laptop and a phone -------------------------------------------------

SCREENS = [(1366, 768), (1920, 1080), (390, 844)]


def visible_boxes(page, selector):
    """``[(description, {x, y, width, height})]`` of the visible elements matching ``selector``
    (not those in a folded section: Chromium keeps their boxes, hidden)."""
    return page.evaluate("""(selector) => [...document.querySelectorAll(selector)]
        .filter((el) => (el.offsetParent !== null || el.tagName === 'CANVAS') && !el.closest('details:not([open])'))
        .map((el) => {
            const r = el.getBoundingClientRect();
            return [el.id || el.name || el.textContent.trim().slice(0, 20) || el.tagName,
                    { x: r.x, y: r.y, width: r.width, height: r.height }];
        })""", selector)


def font_px(page, selector):
    return page.evaluate(f"parseFloat(getComputedStyle(document.querySelector('{selector}')).fontSize)")


@pytest.mark.parametrize("width, height", SCREENS, ids=[f"{w}x{h}" for w, h in SCREENS])
def test_the_page_fits_the_screen(browser, url, tmp_path, width, height):
    context = browser.new_context(viewport={"width": width, "height": height}, bypass_csp=True)
    page = context.new_page()
    try:
        page.goto(url)
        page.wait_for_function("window.flockPlay && flockPlay.frames > 20 && flockPlay.model", timeout=30_000)
        page.wait_for_timeout(300)
        page.screenshot(path=tmp_path / f"play-{width}x{height}.png")
        print(f"screenshot: {tmp_path / f'play-{width}x{height}.png'}")
        scroll = page.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]")
        flock = page.locator("#flock").bounding_box()
        controls = visible_boxes(page, "#controls input, #controls select, #controls button, #phi, #plot")
        assert len(controls) >= 15
        assert scroll[0] <= width  # nothing sticks out sideways
        if width > height:
            # a laptop or a projector: one screen, no scrolling, the flock as tall as the screen allows
            assert scroll[1] <= height
            for name, box in controls:
                assert box["x"] >= 0 and box["y"] >= 0, name
                assert box["x"] + box["width"] <= width + 0.5 and box["y"] + box["height"] <= height + 0.5, name
            assert flock["height"] >= 0.9 * height and flock["width"] == pytest.approx(flock["height"], abs=1)
            assert flock["width"] * flock["height"] >= 0.45 * width * height
        else:
            # a phone: the flock as wide as the screen, the rest below it
            assert flock["width"] >= 0.9 * width and flock["x"] >= 0 and flock["x"] + flock["width"] <= width
            for name, box in controls:
                assert box["x"] >= 0 and box["x"] + box["width"] <= width + 0.5, name
        # the backing store matches the size on screen: drawn sharp, not stretched
        assert page.evaluate("document.getElementById('flock').width") == round(flock["width"])
        # phi is the largest number on the page; the plot's ticks are readable at a distance
        sizes = page.evaluate("""() => [...document.querySelectorAll('body *')]
            .filter((el) => el.offsetParent !== null
                            && [...el.childNodes].some((n) => n.nodeType === 3 && n.textContent.trim()))
            .map((el) => [el.id || el.className || el.tagName, parseFloat(getComputedStyle(el).fontSize)])""")
        phi = font_px(page, "#phi")
        assert all(size < phi for name, size in sizes if name != "phi"), sizes
        assert phi >= 2.5 * font_px(page, "body")
        assert page.evaluate("flockPlay.plot.tickPx") >= 14
        assert_label_clear_of_ticks(page)
    finally:
        context.close()


def assert_label_clear_of_ticks(page):
    """The plot's phi label and its tick labels are apart: the columns of the plot's left
    margin that hold ink form separate runs, the first (the label) at least 0.4 font
    sizes from the next (the ticks' labels)."""
    runs = page.evaluate("""() => {
        const c = document.getElementById('plot'), ctx = c.getContext('2d');
        const dpr = window.devicePixelRatio || 1, x0 = Math.round(flockPlay.plot.x0 * dpr);
        const d = ctx.getImageData(0, 0, x0, c.height).data;
        const inked = [];
        for (let x = 0; x < x0; x++) {
            let any = false;
            for (let y = 0; y < c.height && !any; y++) any = d[4 * (y * x0 + x) + 3] > 40;
            inked.push(any);
        }
        const runs = [];
        inked.forEach((on, x) => {
            if (on && (!runs.length || runs[runs.length - 1][1] !== x - 1)) runs.push([x, x]);
            else if (on) runs[runs.length - 1][1] = x;
        });
        return runs.map(([a, b]) => [a / dpr, b / dpr]);
    }""")
    assert len(runs) >= 2, runs
    assert runs[1][0] - runs[0][1] >= 0.4 * page.evaluate("flockPlay.plot.tickPx"), runs


REACHABLE = [(1366, 768), (1920, 1080), (1024, 700)]


@pytest.mark.parametrize("opened", [True, False], ids=["sections-open", "sections-closed"])
@pytest.mark.parametrize("width, height", REACHABLE, ids=[f"{w}x{h}" for w, h in REACHABLE])
def test_every_control_is_within_the_width_and_reachable_by_scrolling_down(browser, url, tmp_path, width, height,
                                                                         opened):
    context = browser.new_context(viewport={"width": width, "height": height}, bypass_csp=True)
    page = context.new_page()
    try:
        page.goto(url)
        page.wait_for_function("window.flockPlay && flockPlay.frames > 5 && flockPlay.model", timeout=30_000)
        if opened:
            for section in ("#space", "#second", "#sight"):
                page.click(f"{section} summary")
            assert page.evaluate("[...document.querySelectorAll('details')].every((d) => d.open)")
        page.wait_for_timeout(300)
        shot = tmp_path / f"play-{width}x{height}-{'open' if opened else 'closed'}.png"
        page.screenshot(path=shot)
        print(f"screenshot: {shot}")
        assert page.evaluate("document.documentElement.scrollWidth") <= width  # the page never scrolls sideways
        # the status line under the plot shows its whole height
        line = page.evaluate("(() => { const r = document.getElementById('readout'); "
                             "return [r.clientHeight, r.scrollHeight, parseFloat(getComputedStyle(r).fontSize)]; })()")
        assert line[0] >= line[1] and line[0] >= 1.2 * line[2], line
        controls = page.evaluate("""() => [...document.querySelectorAll(
                '#controls input, #controls select, #controls button, #controls summary')]
            .filter((el) => el.offsetParent !== null && !el.closest('details:not([open]) > :not(summary)'))
            .map((el) => el.id || el.name + ':' + el.value || el.textContent.trim().slice(0, 20))""")
        assert len(controls) >= (30 if opened else 20), controls
        for k, name in enumerate(controls):
            box = page.evaluate("""(k) => {
                const el = [...document.querySelectorAll(
                    '#controls input, #controls select, #controls button, #controls summary')]
                    .filter((el) => el.offsetParent !== null && !el.closest('details:not([open]) > :not(summary)'))[k];
                el.scrollIntoView({ block: 'nearest' });
                const r = el.getBoundingClientRect();
                const hit = document.elementFromPoint(r.x + r.width / 2, r.y + r.height / 2);
                return { x: r.x, y: r.y, right: r.right, bottom: r.bottom,
                         top: hit === el || el.contains(hit) || (el.labels && [...el.labels].some((l) => l.contains(hit))) };
            }""", k)
            assert box["x"] >= 0 and box["right"] <= width + 0.5, name          # nothing off the right edge
            assert box["y"] >= 0 and box["bottom"] <= height + 0.5, name        # scrolled into view: reachable
            assert box["top"], name                                             # and not covered by anything
        assert page.evaluate("window.scrollY") == 0  # the panel scrolled, not the page: the flock stays in view
    finally:
        context.close()


def test_labels_say_what_a_class_needs(page):
    assert page.inner_text("#wheel-caption") == "colour = heading"
    assert page.inner_text("#noise-scale").split() == ["0:", "none", "π", "2π:", "random"]
    assert page.inner_text("#radius-hint") == "how far a particle sees: the box is 32 R wide"
    assert page.inner_text("#speed-hint") == "distance moved per step: crossing the box takes 63 steps"
    hints = page.locator("#controls .hint:visible")
    assert hints.count() >= 7  # each slider says what it changes
    page.focus("#radius")
    page.keyboard.press("End")  # R = 4
    page.wait_for_function("flockPlay.model.radius === 4")
    assert page.inner_text("#radius-hint") == "how far a particle sees: the box is 7.9 R wide"
    page.check('input[name="noise_type"][value="vectorial"]')
    page.wait_for_function("flockPlay.model.noise_type === 'vectorial'")
    assert page.inner_text("#noise-scale").split() == ["0:", "none", "1", "2"]
    page.check('input[name="dim"][value="3"]')
    page.wait_for_function("flockPlay.dim === 3")
    assert page.inner_text("#wheel-caption") == "colour = heading, seen from above"


@pytest.fixture(scope="module")
def small_server():
    """A server whose memory holds one tab of 3000 particles, not two."""
    yield from serve("--n", "3000", "--max-memory", "1")


def test_a_refused_tab_says_why_and_its_controls_look_disabled(browser, small_server, tmp_path):
    context = browser.new_context(viewport={"width": 1366, "height": 768}, bypass_csp=True)
    try:
        first = context.new_page()
        first.goto(small_server)
        first.wait_for_function("window.flockPlay && flockPlay.frames > 2", timeout=30_000)
        second = context.new_page()
        second.goto(small_server)
        second.wait_for_function("window.flockPlay && flockPlay.refused", timeout=30_000)
        second.wait_for_function("document.body.classList.contains('offline')")
        second.screenshot(path=tmp_path / "refused-1366x768.png")
        print(f"screenshot: {tmp_path / 'refused-1366x768.png'}")
        message = second.inner_text("#message")
        assert message.startswith("The server refused this tab: no memory left for another tab: it needs")
        assert "The server is still running" in message and "Start `flocking play` again" not in message
        assert second.inner_text("#readout") == "refused by the server"
        for control in ("#play", "#noise", "#n", "#export"):
            assert second.is_disabled(control), control
        assert float(second.evaluate("getComputedStyle(document.querySelector('.panel')).opacity")) < 0.6
        first.close()  # its memory comes back: the refused tab gets in on a reload
        second.reload()
        second.wait_for_function("window.flockPlay && flockPlay.frames > 2 && !flockPlay.refused", timeout=30_000)
        assert not second.is_disabled("#play")
    finally:
        context.close()


@pytest.fixture
def slow_obstacle_url(monkeypatch):
    """An in-process server whose tab takes 2.5 s to apply its first obstacle, as numba
    compiling the extended kernels for the first time does."""
    import threading

    import uvicorn

    from flocking import Model
    from flocking.cli.play import listen
    from flocking.play import server
    from flocking.play.session import Session

    receive, work = Session.receive, Session.work
    asked = threading.Event()

    def note(self, raw):
        if b'"obstacle"' in (raw if isinstance(raw, bytes) else raw.encode()):
            asked.set()
        receive(self, raw)

    def slow(self, advance=False):
        if asked.is_set():
            asked.clear()
            time.sleep(2.5)
        work(self, advance)

    monkeypatch.setattr(Session, "receive", note)
    monkeypatch.setattr(Session, "work", slow)
    app = server.create_app(Model(n=2000, noise=0.5))
    sock = listen("127.0.0.1", 0)
    from uvicorn.config import WS_PROTOCOLS

    ws = "websockets-sansio" if "websockets-sansio" in WS_PROTOCOLS else "websockets"  # as flocking play
    config = uvicorn.Config(app, ws=ws, log_level="warning", lifespan="off")
    runner = uvicorn.Server(config)
    thread = threading.Thread(target=runner.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{sock.getsockname()[1]}/"
    runner.should_exit = True
    thread.join(timeout=20)


def test_a_slow_change_is_announced_until_its_frame_comes(browser, slow_obstacle_url):
    context = browser.new_context(viewport={"width": 1366, "height": 768}, bypass_csp=True)
    page = context.new_page()
    try:
        page.goto(slow_obstacle_url)
        page.wait_for_function("window.flockPlay && flockPlay.frames > 5", timeout=30_000)
        assert page.inner_text("#message") == ""
        box = page.locator("#flock").bounding_box()
        page.mouse.click(box["x"] + 0.5 * box["width"], box["y"] + 0.5 * box["height"])
        started = time.monotonic()
        page.wait_for_function("flockPlay.busy", timeout=5_000)
        said = time.monotonic() - started
        assert "compiles the simulation's code once on this machine" in page.inner_text("#message")
        assert said < 2.4  # announced while the change was still being prepared (it takes 2.5 s)
        page.wait_for_function("!flockPlay.busy && flockPlay.model.obstacles && flockPlay.model.obstacles.length === 1",
                               timeout=10_000)
        assert page.inner_text("#message") == ""  # the next frame took the notice away
    finally:
        context.close()
