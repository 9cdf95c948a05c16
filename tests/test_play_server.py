"""flocking play: the session (messages, limits, frames), the web app and its socket, the CLI.

Attacks on the server each have a test here: malformed and absurd messages, binary and
1 MB garbage, floods, many tabs at once, a foreign Origin, models too slow or too large
for the shared budget, and a flock that turns non-finite.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import tracemalloc
import urllib.request

import numpy as np
import pytest
from click.testing import CliRunner

from flocking import Model, Simulation, State
from flocking.cli import main
from flocking.config import RunConfig
from flocking.play import session as session_module
from flocking.backends.cpu import CPUBackend
from flocking.play.budget import session_bytes
from flocking.play.codec import decode_frame, encode_frame
from flocking.play.session import MAX_ERRORS, MAX_MESSAGE, MAX_N, MAX_STEP_SECONDS, Session, parse_message

pytest.importorskip("starlette")
pytest.importorskip("httpx")  # starlette's TestClient
from starlette.testclient import TestClient  # noqa: E402
from starlette.websockets import WebSocketDisconnect  # noqa: E402

from flocking.play.server import create_app  # noqa: E402

SRC = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, "src"))
ENV = {**os.environ, "PYTHONPATH": SRC}
SMALL = Model(n=300, density=2.0, noise=0.5, seed=4)


def reply(ws, kind=None, limit=2000):
    """The next JSON reply (of ``kind``), skipping frames."""
    for _ in range(limit):
        msg = ws.receive()
        if msg.get("text") is not None:
            data = json.loads(msg["text"])
            if kind is None or data["type"] == kind:
                return data
    raise AssertionError("no reply")


def frame(ws, limit=2000):
    for _ in range(limit):
        msg = ws.receive()
        if msg.get("bytes") is not None:
            return decode_frame(msg["bytes"])
    raise AssertionError("no frame")


def wait_for(predicate, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return False


@pytest.fixture
def client():
    app = create_app(SMALL)
    with TestClient(app) as c:
        c.app_sessions = app.state.sessions
        c.budget = app.state.budget
        yield c


def paused(ws):
    """Pause a fresh tab and reset it, so that the next frame is step 0."""
    assert reply(ws)["type"] == "state"
    ws.send_text('{"type": "pause"}')
    assert reply(ws, "state")["running"] is False
    ws.send_text('{"type": "reset"}')  # frames of the steps before the pause are behind us now
    reply(ws, "state")
    assert frame(ws)["step"] == 0
    return ws


@pytest.fixture
def ws(client):
    with client.websocket_connect("/ws") as ws:
        yield paused(ws)


# -- the page ---------------------------------------------------------------------------


def test_page_and_static_files(client):
    page = client.get("/")
    assert page.status_code == 200 and "<canvas id=\"flock\"" in page.text
    assert "default-src 'self'" in page.headers["content-security-policy"]
    for name in ("app.js", "frame.js", "render.js", "plot.js", "style.css", "favicon.svg"):
        assert client.get(f"/static/{name}").status_code == 200, name
    assert client.get("/static/nothing.js").status_code == 404
    assert client.get("/static/../server.py").status_code == 404


# -- hostile, absurd and malformed messages -------------------------------------------------

BAD = [
    ("{not json", "not valid JSON"),
    ("[1, 2]", "must be a JSON object"),
    ('"set"', "must be a JSON object"),
    ("{}", "type: must be one of"),
    ('{"type": "explode"}', "type: must be one of"),
    ('{"type": 7}', "type: must be one of"),
    ('{"type": "pause", "extra": 1}', "unknown field 'extra'"),
    ('{"type": "set"}', "missing field 'params'"),
    ('{"type": "set", "params": [1]}', "set.params: must be a dict"),
    ('{"type": "set", "params": {"nosie": 1}}', "unknown parameter 'nosie'"),
    ('{"type": "set", "params": {"box": 5}}', "unknown parameter 'box'"),
    ('{"type": "set", "params": {"__class__": 5}}', "unknown parameter '__class__'"),
    ('{"type": "set", "params": {"noise": 9}}', "noise: must be in [0, 2*pi]"),
    ('{"type": "set", "params": {"noise": "loud"}}', "noise: must be a number"),
    ('{"type": "set", "params": {"noise": NaN}}', "not valid JSON"),
    ('{"type": "set", "params": {"noise": Infinity}}', "not valid JSON"),
    ('{"type": "set", "params": {"noise": 1e999}}', "noise: must be"),
    ('{"type": "set", "params": {"noise": null}}', "noise: must be a number"),
    ('{"type": "set", "params": {"radius": 1e308}}', "radius: must be"),
    ('{"type": "set", "params": {"n": 1000000000}}', f"n: must be at most {MAX_N}"),
    ('{"type": "set", "params": {"n": 1e300}}', "n: must be at most"),
    ('{"type": "set", "params": {"n": -5}}', "n: must be a whole number"),
    ('{"type": "set", "params": {"n": 2.5}}', "n: must be a whole number"),
    ('{"type": "set", "params": {"density": 0}}', "density: must be"),
    ('{"type": "set", "params": {"dim": 4}}', "dim: must be one of"),
    ('{"type": "set", "params": {"neighbours": "psychic"}}', "neighbours: must be one of"),
    ('{"type": "set", "params": {"neighbours": ["metric"]}}', "neighbours: must be one of"),
    ('{"type": "set", "params": {"k": 100000}}', "k: must be at most"),
    ('{"type": "set", "params": {"delay": 100000}}', "delay: must be at most"),
    ('{"type": "set", "params": {"seed": -1}}', "seed: must be"),
    ('{"type": "set", "params": {"seed": 18446744073709551616}}', "seed: must be"),
    ('{"type": "set", "params": {"alignment": true}}', "alignment: must be a number"),
    # priced from where the particles would be: a step of seconds is refused before it runs
    ('{"type": "set", "params": {"radius": 50, "n": 100000}}', "radius: one step would take about"),
    ('{"type": "set", "params": {"n": 20000, "radius": 40}}', "radius: one step would take about"),
    ('{"type": "set", "params": {"n": 200000, "neighbours": "topological", "k": 64}}',
     "k: one step would take about"),
    ('{"type": "steps_per_frame", "value": 0}', "steps_per_frame: must be in [1, 50]"),
    ('{"type": "steps_per_frame", "value": 1' + "0" * 4000 + "}", "steps_per_frame: must be in [1, 50]"),
    ('{"type": "steps_per_frame", "value": 1e9}', "steps_per_frame.value: must be a int"),
    ('{"type": "steps_per_frame", "value": true}', "steps_per_frame.value: must be a int"),
    ('{"type": "reset", "init": "/etc/passwd"}', "reset.init: must be one of random, aligned"),
    ('{"type": "reset", "init": "\\ud800"}', "reset.init: must be one of random, aligned"),
    ("[" * 3000 + "]" * 3000, "message too long"),
    ("[" * 2000 + "]" * 2000, "not valid JSON"),
    ('{"type": "config", "pad": "' + "x" * MAX_MESSAGE + '"}', "message too long"),
]


@pytest.mark.parametrize("raw, expected", BAD, ids=[f"bad{i}" for i in range(len(BAD))])
def test_bad_message_is_refused_and_changes_nothing(ws, raw, expected):
    ws.send_text(raw)
    error = reply(ws)
    assert error["type"] == "error" and expected in error["message"], error
    assert len(error["message"]) <= 300 and "\n" not in error["message"]
    ws.send_text('{"type": "set", "params": {"noise": 0.25}}')  # still serving, nothing changed before
    while (state := reply(ws))["model"]["noise"] != 0.25:
        assert state["type"] == "state" and state["model"] == {**SMALL.to_dict(), "density": SMALL.density}
    assert state["model"] == {**SMALL.replace(noise=0.25).to_dict(), "density": SMALL.density}
    assert state["running"] is False
    assert frame(ws)["step"] == 0  # the change, drawn
    ws.send_text('{"type": "step"}')
    assert frame(ws)["step"] == 1


# values whose products overflow: refused by the playground's own limits (vectorial noise at
# most 10, v0 dt at most half the box), or by Model itself where it checks them first
OVERFLOWS = [
    ({"noise": 1e308, "noise_type": "vectorial"}, "noise"),
    ({"noise": 5e307, "noise_type": "vectorial", "density": 8.0}, "noise"),
    ({"speed": 1e308}, "speed|dt"),
    ({"dt": 1e300}, "speed|dt"),
    ({"speed": 1e200, "dt": 1e200}, "speed|dt"),
    ({"density": 1e300}, "speed|dt|density|box"),
]


@pytest.mark.parametrize("params, names", OVERFLOWS, ids=[f"overflow{i}" for i in range(len(OVERFLOWS))])
def test_overflowing_values_are_refused_in_one_line_naming_the_parameter(ws, params, names):
    ws.send_text(json.dumps({"type": "set", "params": params}))
    error = reply(ws)
    assert error["type"] == "error" and re.match(rf"({names}): ", error["message"]), error
    assert "\n" not in error["message"]
    state = reply(ws, "state")
    assert state["model"] == {**SMALL.to_dict(), "density": SMALL.density}
    ws.send_text('{"type": "step"}')
    f = frame(ws)
    assert f["step"] == 1 and np.isfinite(f["phi"])


def test_binary_garbage_is_refused(ws):
    for junk in (b"\x00\xff" * 100, os.urandom(5000), b""):
        ws.send_bytes(junk)
        assert "binary messages are not accepted" in reply(ws, "error")["message"]
    ws.send_text('{"type": "step"}')
    assert frame(ws)["step"] == 1


def test_a_flood_of_bad_messages_is_answered_in_brief(client):
    s = Session(SMALL)
    s.take_replies()
    for i in range(500):
        s.receive('{"type": "set", "params": {"n": %d}}' % (10**9 + i))
    replies = s.take_replies()
    assert [r["type"] for r in replies] == ["error"] * (MAX_ERRORS + 1) + ["state"]
    assert replies[MAX_ERRORS]["message"] == f"... and {500 - MAX_ERRORS} more messages were refused"
    with client.websocket_connect("/ws") as ws:  # on a socket: every refusal is answered or counted
        paused(ws)
        for i in range(500):
            ws.send_text('{"type": "set", "params": {"n": %d}}' % (10**9 + i))
        ws.send_text('{"type": "set", "params": {"noise": 0.75}}')
        refused = 0
        while (r := reply(ws))["type"] != "state" or r["model"]["noise"] != 0.75:
            if r["type"] == "error":
                counted = re.fullmatch(r"\.\.\. and (\d+) more messages were refused", r["message"])
                assert counted or r["message"].startswith("n: must be at most 200000")
                refused += int(counted.group(1)) if counted else 1
        assert refused == 500


def flood(ws_send, count):
    """``count`` set messages that move noise, speed, alignment and radius; their last values."""
    rng = np.random.default_rng(1)
    last = {}
    for i in range(count):
        params = {"noise": round(float(rng.uniform(0, 6)), 3)}
        if i % 3 == 0:
            params["speed"] = round(float(rng.uniform(0.1, 2)), 3)
        if i % 5 == 0:
            params["alignment"] = round(float(rng.uniform(0, 1)), 3)
        if i % 7 == 0:
            params["radius"] = round(float(rng.uniform(0.5, 2)), 3)
        last.update(params)
        ws_send(json.dumps({"type": "set", "params": params}))
    return last


def test_a_flood_is_coalesced_into_one_change(client):
    with client.websocket_connect("/ws") as ws:
        paused(ws)
        ws.send_text('{"type": "step"}')
        assert frame(ws)["step"] == 1
        start = time.monotonic()
        last = flood(ws.send_text, 2000)
        ws.send_text('{"type": "config"}')
        ws.send_text('{"type": "step"}')
        states = 0
        while (r := reply(ws))["type"] != "config":
            states += r["type"] == "state"
        assert RunConfig.from_toml(r["toml"]).model == SMALL.replace(**last)  # the last value of each
        while (r := reply(ws, "state"))["model"]["noise"] != last["noise"]:
            states += 1
        elapsed = time.monotonic() - start
        assert r["model"] == {**SMALL.replace(**last).to_dict(), "density": SMALL.density}
        print(f"2000 messages over {elapsed:.2f} s: {states} changes applied")
        assert states <= 60 * elapsed + 2  # at most one change a frame (60 a second), not one a message
        f = frame(ws)
        assert f["step"] in (1, 2) and f["n"] == SMALL.n  # the state continued
        if f["step"] == 1:  # the last change's frame: the step sent after the flood comes next (sent
            f = frame(ws)  # after ours, it would be taken together with ours: step 3 in one frame)
        assert f["step"] == 2
        ws.send_text('{"type": "step"}')
        assert frame(ws)["step"] == 3


def cpu_seconds(pid: int) -> float:
    """User and system time of a process so far (Linux)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.fixture
def server(request):
    """``flocking play --n 500`` (or the test's parameter) in a subprocess: (its address, the process)."""
    n = str(getattr(request, "param", 500))
    proc = subprocess.Popen([sys.executable, "-m", "flocking", "play", "--port", "0", "--no-browser",
                             "--n", n], env=ENV, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        match = re.search(r"http://127\.0\.0\.1:\d+/", line)
        assert match, line
        yield match.group(0), proc
    finally:
        if proc.poll() is None:
            proc.terminate()
        proc.wait(timeout=20)


@pytest.mark.parametrize("server", [20_000], indirect=True)  # a rebuild a message took 7 s of CPU here
def test_a_flood_on_a_real_socket_takes_well_under_a_second_of_server_work(server):
    websockets = pytest.importorskip("websockets.sync.client")
    if not os.path.exists("/proc/self/stat"):
        pytest.skip("needs /proc to read the server's CPU time")
    url, proc = server
    with websockets.connect(url.replace("http", "ws") + "ws", max_size=None) as ws:
        assert json.loads(ws.recv(timeout=20))["type"] == "state"
        ws.send('{"type": "pause"}')
        ws.send('{"type": "steps_per_frame", "value": 1}')  # nothing to do until the flood
        time.sleep(1.0)
        while True:  # drain what came before the pause
            try:
                ws.recv(timeout=0.2)
            except TimeoutError:
                break
        before, start = cpu_seconds(proc.pid), time.monotonic()
        last = flood(ws.send, 2000)
        ws.send('{"type": "config"}')
        while True:
            msg = ws.recv(timeout=20)
            if isinstance(msg, str) and json.loads(msg)["type"] == "config":
                break
        while True:
            msg = ws.recv(timeout=20)
            r = json.loads(msg) if isinstance(msg, str) else {}
            if r.get("type") == "state" and r["model"]["noise"] == last["noise"]:
                break
        work, wall = cpu_seconds(proc.pid) - before, time.monotonic() - start
    print(f"2000 messages: {work:.2f} s of server CPU, {wall:.2f} s wall")
    assert {k: r["model"][k] for k in last} == last
    assert work < 0.8  # checks of 2000 messages and one rebuild, on a busy 2-core machine


def test_one_megabyte_of_garbage_closes_only_that_socket(server):
    websockets = pytest.importorskip("websockets.sync.client")
    from websockets.exceptions import ConnectionClosedError

    url, proc = server
    ws_url = url.replace("http", "ws") + "ws"
    with websockets.connect(ws_url, max_size=None) as other:
        assert json.loads(other.recv(timeout=20))["type"] == "state"
        for junk in (os.urandom(2**20), "x" * 2**20):  # over the server's 64 KiB frame limit
            with websockets.connect(ws_url, max_size=None) as ws:
                ws.send(junk)
                # the server closes this socket as "message too big" (1009), not by falling silent
                with pytest.raises(ConnectionClosedError) as closed:
                    for _ in range(10_000):
                        ws.recv(timeout=10)
                assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
        other.send('{"type": "set", "params": {"noise": 2.0}}')  # the other tab goes on
        while True:
            msg = other.recv(timeout=20)
            if isinstance(msg, str) and json.loads(msg)["model"]["noise"] == 2.0:
                break
    assert proc.poll() is None


# -- controls act on the running simulation ------------------------------------------------


def test_step_and_parameter_changes_continue_the_state(ws):
    ws.send_text('{"type": "step"}')
    before = frame(ws)
    assert before["step"] == 1 and before["n"] == SMALL.n and not before["running"]
    ws.send_text('{"type": "set", "params": {"noise": 3.0, "neighbours": "topological", "k": 5}}')
    state = reply(ws, "state")
    assert state["model"]["neighbours"] == "topological" and state["model"]["k"] == 5
    after = frame(ws)
    assert after["step"] == 1
    np.testing.assert_array_equal(after["positions"], before["positions"])
    ws.send_text('{"type": "step"}')
    assert frame(ws)["step"] == 2


def test_voronoi_neighbours_are_a_choice_of_the_page(ws):
    ws.send_text('{"type": "set", "params": {"neighbours": "voronoi"}}')
    assert reply(ws, "state")["model"]["neighbours"] == "voronoi"
    assert frame(ws)["step"] == 0
    ws.send_text('{"type": "step"}')
    assert frame(ws)["step"] == 1
    assert CPUBackend.step_cost(Model(n=10_000, neighbours="voronoi"), np.zeros((10_000, 2)))[0] > 0.1  # as measured


def test_speed_change_moves_particles_at_the_new_speed(ws):
    ws.send_text('{"type": "set", "params": {"speed": 1.25, "noise": 0.0}}')
    first = frame(ws)
    ws.send_text('{"type": "step"}')
    second = frame(ws)
    box = first["box"]
    d = (second["positions"] - first["positions"] + box / 2) % box - box / 2
    step = np.linalg.norm(d, axis=1)
    quantum = box.max() / 65536  # both positions are quantised to bin centres
    assert np.all(np.abs(step - 1.25) < 2 * math.sqrt(2) * quantum)


def test_size_and_dimension_changes_start_a_new_state(ws):
    ws.send_text('{"type": "step"}')
    assert frame(ws)["step"] == 1
    ws.send_text('{"type": "set", "params": {"n": 500, "dim": 3}}')
    model = reply(ws, "state")["model"]
    assert (model["n"], model["dim"]) == (500, 3)
    assert model["density"] == pytest.approx(SMALL.density)
    f = frame(ws)
    assert (f["step"], f["n"], f["dim"]) == (0, 500, 3)
    assert np.all((f["positions"] >= 0) & (f["positions"] < f["box"]))
    ws.send_text('{"type": "set", "params": {"density": 0.5}}')
    model = reply(ws, "state")["model"]
    assert model["n"] == 500 and model["box"][0] == pytest.approx((500 / 0.5) ** (1 / 3))


def test_reset_aligned_play_and_steps_per_frame(ws):
    ws.send_text('{"type": "reset", "init": "aligned"}')
    assert reply(ws, "state")["init"] == "aligned"
    f = frame(ws)
    assert f["step"] == 0 and f["phi"] == pytest.approx(1.0)
    ws.send_text('{"type": "steps_per_frame", "value": 7}')
    assert reply(ws, "state")["steps_per_frame"] == 7
    ws.send_text('{"type": "play"}')
    assert reply(ws, "state")["running"] is True
    steps = [frame(ws)["step"] for _ in range(4)]
    assert all(b - a == 7 for a, b in zip(steps[1:], steps[2:]))
    ws.send_text('{"type": "pause"}')
    assert reply(ws, "state")["running"] is False


def test_steps_before_a_reset_are_dropped_and_waiting_steps_are_capped():
    s = Session(SMALL)
    s.take_replies()
    s.receive('{"type": "step"}')
    s.receive('{"type": "step"}')
    s.receive('{"type": "reset"}')
    s.receive('{"type": "step"}')
    s.work()
    assert s.sim.step == 1 and decode_frame(s.take_frame())["step"] == 1
    for _ in range(session_module.MAX_STEPS_PER_FRAME + 3):
        s.receive('{"type": "step"}')
    s.work()
    assert s.sim.step == 1 + session_module.MAX_STEPS_PER_FRAME
    errors = [r["message"] for r in s.take_replies() if r["type"] == "error"]
    assert errors == ["step: 50 steps are already waiting; this one is dropped"] * 3


def test_exported_config_runs_with_flocking_run(ws, tmp_path):
    ws.send_text('{"type": "set", "params": {"noise": 2.0, "noise_type": "vectorial", "delay": 3}}')
    reply(ws, "state")
    ws.send_text('{"type": "config"}')
    config = reply(ws, "config")
    cfg = RunConfig.from_toml(config["toml"])
    assert cfg.model == SMALL.replace(noise=2.0, noise_type="vectorial", delay=3)
    path = tmp_path / config["filename"]
    path.write_text(config["toml"])
    result = CliRunner().invoke(main, ["run", "--config", str(path), "--steps", "3", "--out",
                                       str(tmp_path / "out"), "--quiet"])
    assert result.exit_code == 0, result.output
    assert RunConfig.from_toml((tmp_path / "out" / "config.toml").read_text()).model == cfg.model


def test_config_answers_are_never_dropped_silently():
    s = Session(SMALL)
    s.take_replies()
    for _ in range(session_module.MAX_CONFIGS + 2):
        s.receive('{"type": "config"}')
    replies = s.take_replies()
    assert sum(r["type"] == "config" for r in replies) == session_module.MAX_CONFIGS
    assert [r["message"] for r in replies if r["type"] == "error"] == \
        ["config: 16 answers are already waiting; ask again later"] * 2


# -- resources: slow steps, memory, cores, non-finite flocks ---------------------------------


def test_a_crowded_flock_is_paused_before_a_slow_step(monkeypatch):
    model = Model(n=20_000, density=2.0, seed=1)
    s = Session(model)
    s.take_replies()
    packed = State(np.full((model.n, 2), 1.5), State.random(model).headings, np.full(model.n, 0.5))
    seconds, candidates = CPUBackend.step_cost(model, packed.positions)
    assert candidates == model.n and seconds > MAX_STEP_SECONDS  # every particle in one cell
    s.sim = Simulation(model, packed)  # as if the flock had crowded there
    monkeypatch.setattr(session_module, "PRICE_EVERY", 0.0)
    start = time.monotonic()
    s.work(advance=True)
    assert time.monotonic() - start < 0.5 and s.sim.step == 0  # priced, not stepped
    assert s.running is False
    replies = s.take_replies()
    assert "the flock has crowded so that one step would take about" in replies[0]["message"]
    assert replies[-1]["type"] == "state" and replies[-1]["running"] is False
    s.handle('{"type": "reset"}')  # a new, spread-out state runs again
    s.handle('{"type": "play"}')
    s.work(advance=True)
    assert s.sim.step == 1


def test_closing_a_tab_stops_a_slow_run_within_a_step():
    slow = Model(n=3000, density=2.0, radius=15.0, seed=2)  # two cells a side: every pair a candidate
    seconds = CPUBackend.step_cost(slow, State.random(slow).positions)[0]
    assert 0.1 < seconds < MAX_STEP_SECONDS
    app = create_app(slow)
    with TestClient(app) as c:
        with c.websocket_connect("/ws") as ws:
            assert reply(ws)["type"] == "state"
            ws.send_text('{"type": "steps_per_frame", "value": 50}')  # frames of 50 slow steps
            assert reply(ws, "state")["steps_per_frame"] == 50
            time.sleep(1.0)
        closed = time.monotonic()
        assert wait_for(lambda: not app.state.sessions) and app.state.budget.held == 0
        time.sleep(max(0.0, closed + 3 * seconds + 0.5 - time.monotonic()))  # the step in progress ends
        before = time.process_time()
        time.sleep(2.0)
        spent = time.process_time() - before
    print(f"CPU time in the 2 s after the tab closed: {spent:.2f} s")
    assert spent < 0.3  # 50 steps of ~0.2 s would still be running


def test_the_memory_budget_refuses_tabs_and_models_that_do_not_fit():
    tab = session_bytes(SMALL)
    with TestClient(app := create_app(SMALL, memory=int(2.5 * tab))) as c:
        with c.websocket_connect("/ws") as one, c.websocket_connect("/ws") as two:
            paused(one), paused(two)
            with c.websocket_connect("/ws") as three:
                refused = reply(three)
                assert refused["type"] == "refused"
                assert refused["message"].startswith("no memory left for another tab: it needs")
                assert three.receive() == {"type": "websocket.close", "code": 1013, "reason": ""}
            one.send_text('{"type": "set", "params": {"n": 600}}')  # twice the memory: no room
            error = reply(one, "error")["message"]
            assert re.fullmatch(r"n: this needs [\d.]+ MiB, but only [\d.]+ MiB of the [\d.]+ MiB that all tabs "
                                r"share are free; lower n or close another tab", error), error
            assert reply(one, "state")["model"]["n"] == SMALL.n  # still running what ran
            one.send_text('{"type": "step"}')
            assert frame(one)["n"] == SMALL.n
            # (the backend's histograms count numba's threads, which the stepping thread may have lowered)
            assert app.state.budget.held == pytest.approx(2 * tab, rel=0.05)
        with c.websocket_connect("/ws") as one:  # both closed: their memory came back
            paused(one)
            one.send_text('{"type": "set", "params": {"n": 600}}')
            assert reply(one, "state")["model"]["n"] == 600
            assert app.state.budget.held == pytest.approx(session_bytes(SMALL.replace(n=600)), rel=0.05)


@pytest.mark.parametrize("model", [Model(n=100_000, density=2.0, delay=5), Model(dim=3, n=50_000, density=1.0)],
                         ids=["2d-delay", "3d"])
def test_a_tab_holds_no_more_than_its_budget_says(model):
    s = Session(model)
    s.work(advance=True)  # compiled, and a frame made, outside the count
    s.take_frame()
    tracemalloc.start()
    try:
        s.handle('{"type": "set", "params": {"noise": 0.5, "speeds": "uniform"}}')  # a rebuild
        s.work(advance=True)
        s.take_frame()
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    budget = session_bytes(s.model)
    print(f"{model.dim}D: peak {peak / model.n:.0f} B/particle beyond what was held, budget {budget / model.n:.0f}")
    assert peak < budget


def test_each_running_tab_gets_an_equal_share_of_the_cores():
    cost = CPUBackend.step_cost(SMALL, State.random(SMALL).positions)[0]
    cores = cost / 0.4  # one tab alone: a frame every 0.4 s; two tabs: every 0.8 s
    with TestClient(create_app(SMALL, cores=cores)) as c:
        with c.websocket_connect("/ws") as one:
            reply(one)
            frame(one)
            start, frames = time.monotonic(), 0
            while time.monotonic() - start < 2.0:
                frame(one)
                frames += 1
            alone = frames / (time.monotonic() - start)
            with c.websocket_connect("/ws") as two:
                reply(two)
                frame(one), frame(two)
                start, counts = time.monotonic(), [0, 0]
                while time.monotonic() - start < 3.2:
                    frame(one)
                    counts[0] += 1
                shared = counts[0] / (time.monotonic() - start)
                assert frame(two)["step"] >= 1  # the other tab was served too
    print(f"frames/s alone {alone:.2f}, shared {shared:.2f}")
    assert alone <= 1 / 0.4 * 1.3 and shared <= 1 / 0.8 * 1.3  # the share bounds the rate from above
    assert shared < alone


def test_a_non_finite_flock_is_paused_with_one_line(monkeypatch):
    s = Session(SMALL)
    s.take_replies()
    s.handle('{"type": "steps_per_frame", "value": 5}')
    s.take_replies()
    s.work(advance=True)
    assert s.sim.step == 5
    real = s.sim.backend.advance
    calls = []

    def fails_on_the_third(steps):
        calls.append(steps)
        phi = real(steps)
        return phi * np.nan if len(calls) == 3 else phi

    monkeypatch.setattr(s.sim.backend, "advance", fails_on_the_third)
    s.take_frame()
    s.work(advance=True)
    assert s.running is False and s.broken == 8 and len(calls) == 3  # stopped at once
    assert s.take_frame() is None  # the last finite frame stays on the page
    replies = s.take_replies()
    assert [r["message"] for r in replies if r["type"] == "error"] == \
        ["the flock became non-finite at step 8 (phi = nan); paused: reset it"]
    s.handle('{"type": "play"}')
    assert s.take_replies()[0]["message"] == "play: the flock became non-finite at step 8; reset it first"
    s.handle('{"type": "reset"}')
    s.handle('{"type": "play"}')
    s.work(advance=True)
    assert s.broken is None and s.running and s.sim.step == 5


def test_a_non_finite_flock_pauses_only_its_own_tab(client, monkeypatch):
    from flocking.backends.cpu import CPUBackend

    real = CPUBackend.advance
    broken = threading.Event()

    def nan_once(self, steps):
        phi = real(self, steps)
        if self.model.noise == 1.5 and not broken.is_set():
            broken.set()
            return phi * np.nan
        return phi

    monkeypatch.setattr(CPUBackend, "advance", nan_once)
    with client.websocket_connect("/ws") as one, client.websocket_connect("/ws") as two:
        reply(one), reply(two)
        one.send_text('{"type": "set", "params": {"noise": 1.5}}')
        assert "became non-finite" in reply(one, "error")["message"]
        assert reply(one, "state")["running"] is False
        two.send_text('{"type": "set", "params": {"noise": 2.0}}')
        assert reply(two, "state")["running"] is True
        steps = [frame(two)["step"] for _ in range(3)]
        assert steps == sorted(steps) and steps[-1] > steps[0]


# -- tabs ---------------------------------------------------------------------------------


def test_tabs_have_their_own_simulation_and_closing_frees_it(client):
    with client.websocket_connect("/ws") as one, client.websocket_connect("/ws") as two:
        reply(one), reply(two)
        assert len(client.app_sessions) == 2
        one.send_text('{"type": "set", "params": {"noise": 4.0}}')
        assert reply(one, "state")["model"]["noise"] == 4.0
        two.send_text('{"type": "config"}')
        assert "noise = 0.5" in reply(two, "config")["toml"]
        (a, task_a), (b, task_b) = client.app_sessions.items()
        assert a is not b and a.sim is not b.sim
        assert not task_a.done() and not task_b.done()
    assert wait_for(lambda: not client.app_sessions)
    assert wait_for(lambda: task_a.cancelled() and task_b.cancelled())
    assert a.closed and b.closed and client.budget.held == 0


def test_foreign_origin_is_refused(client):
    with pytest.raises(WebSocketDisconnect) as err:
        with client.websocket_connect("/ws", headers={"origin": "https://evil.example"}) as ws:
            ws.receive()
    assert err.value.code == 1008
    with client.websocket_connect("/ws", headers={"origin": "http://testserver"}) as ws:
        assert reply(ws)["type"] == "state"


def test_a_tab_closed_while_another_waits_lets_that_one_in():
    """Closing a tab and reloading another reach the server in either order: a new tab
    waits up to ADMIT_SECONDS for the memory a closing tab gives back."""
    from flocking.play.server import ADMIT_SECONDS

    tab = session_bytes(SMALL)
    with TestClient(app := create_app(SMALL, memory=int(1.5 * tab))) as c:
        first = c.websocket_connect("/ws")
        paused(first.__enter__())
        with c.websocket_connect("/ws") as second:  # accepted, waiting for memory
            time.sleep(ADMIT_SECONDS / 4)
            assert len(app.state.sessions) == 1
            first.__exit__(None, None, None)
            assert reply(second)["type"] == "state"
            assert frame(second)["n"] == SMALL.n
        # with nothing given back, the refusal comes after the wait
        with c.websocket_connect("/ws") as one:
            paused(one)
            started = time.monotonic()
            with c.websocket_connect("/ws") as other:
                assert reply(other)["type"] == "refused"
            assert time.monotonic() - started >= ADMIT_SECONDS


def test_sixteen_tabs_are_served_and_a_seventeenth_is_told_why_not(client):
    import contextlib

    with contextlib.ExitStack() as stack:
        tabs = [stack.enter_context(client.websocket_connect("/ws")) for _ in range(16)]
        for tab in tabs:
            assert reply(tab)["type"] == "state"
        with client.websocket_connect("/ws") as extra:
            assert reply(extra) == {"type": "refused", "message": "too many open tabs (at most 16); close one"}
            assert extra.receive()["code"] == 1013
        for tab in tabs:
            assert frame(tab)["n"] == SMALL.n
        tabs[0].close()
        assert wait_for(lambda: len(client.app_sessions) == 15)
        with client.websocket_connect("/ws") as again:  # a closed tab makes room
            assert reply(again)["type"] == "state"


# -- frames -----------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_frames_round_trip_to_quantisation(dim):
    model = Model(dim=dim, n=1000, box=[7.0, 9.0, 5.0][:dim], seed=2)
    state = State.random(model)
    data = encode_frame(state, model, 0.125, running=False)
    assert len(data) == 36 + 1000 * (2 * dim + dim - 1)
    f = decode_frame(data)
    assert (f["dim"], f["n"], f["step"], f["phi"], f["running"]) == (dim, 1000, 0, 0.125, False)
    np.testing.assert_allclose(f["box"], model.box, rtol=1e-6)
    assert np.all(np.abs(f["positions"] - state.positions) <= np.asarray(model.box) / 131072 * 1.0001)
    cos = np.sum(f["headings"] * state.headings, axis=1)
    # half a bin of 2 pi / 256 in azimuth; in 3D z is off by at most 1 / 255 (half a bin),
    # which turns a heading by at most acos(1 - 1/255) (at the poles)
    worst = math.pi / 256 if dim == 2 else math.pi / 256 + math.acos(1 - 1 / 255)
    assert np.all(np.arccos(np.clip(cos, -1, 1)) <= worst)


def test_parse_message_refuses_binary_and_keeps_good_messages():
    assert parse_message('{"type": "reset", "init": "aligned"}') == {"type": "reset", "init": "aligned"}
    with pytest.raises(ValueError, match="binary"):
        parse_message(b'{"type": "pause"}')


def test_session_changes_speeds_with_speed():
    s = Session(Model(n=50, box=5.0, speeds="uniform", speed=1.0, seed=3))
    s.handle('{"type": "set", "params": {"speed": 2.0}}')
    speeds = s.sim.state.speeds
    assert 0 < speeds.min() and speeds.max() <= 2.0 and speeds.max() > 1.0


@pytest.mark.parametrize("dim", [2, 3])
def test_step_cost_counts_each_neighbouring_cell_once(dim):
    import itertools

    from flocking.backends.cells import cell_grid

    for box in ([2.5, 9.0, 7.0], [1.5, 2.5, 7.0], [9.0, 8.0, 7.5]):  # 1, 2 and 3+ cells a side
        model = Model(dim=dim, n=400, box=box[:dim], seed=5)
        positions = State.random(model).positions
        nc = cell_grid(model)
        cells = np.minimum((positions * nc / np.asarray(model.box)).astype(int), nc - 1)
        count = {}
        for c in map(tuple, cells):
            count[c] = count.get(c, 0) + 1
        expected = 0
        for c, k in count.items():
            offsets = itertools.product((-1, 0, 1), repeat=dim)
            around = {tuple((c[a] + o[a]) % nc[a] for a in range(dim)) for o in offsets}
            expected += k * sum(count.get(b, 0) for b in around)
        assert CPUBackend.step_cost(model, positions)[1] == expected / model.n


# -- the command ------------------------------------------------------------------------


def test_missing_extra_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "uvicorn", None)
    result = CliRunner().invoke(main, ["play", "--no-browser"])
    assert result.exit_code == 1
    assert result.output.strip() == "Error: flocking play needs its extra 'play': pip install '.[play]' in flocking's source folder"


def test_bad_options_and_busy_port():
    result = CliRunner().invoke(main, ["play", "--no-browser", "--n", "300000"])
    assert result.exit_code == 2 and "--n: must be at most 200000 in flocking play" in result.output
    result = CliRunner().invoke(main, ["play", "--no-browser", "--n", "20000", "--radius", "40"])
    assert result.exit_code == 2 and "--radius: one step would take about" in result.output
    result = CliRunner().invoke(main, ["play", "--no-browser", "--max-memory", "0"])
    assert result.exit_code == 2 and "--max-memory" in result.output
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        result = CliRunner().invoke(main, ["play", "--no-browser", "--port", str(port)])
    assert result.exit_code == 2 and result.output.startswith(f"Error: --port: cannot listen on 127.0.0.1:{port}")


def test_flocking_play_serves_on_loopback_and_ctrl_c_says_goodbye(server):
    websockets = pytest.importorskip("websockets.sync.client")
    url, proc = server
    with urllib.request.urlopen(url, timeout=20) as page:
        assert b"flocking play" in page.read()
    with websockets.connect(url.replace("http", "ws") + "ws", max_size=None) as ws:
        assert json.loads(ws.recv(timeout=20))["model"]["n"] == 500
        assert decode_frame(ws.recv(timeout=20))["n"] == 500
        proc.send_signal(signal.SIGINT)  # with a tab open and stepping
        assert proc.wait(timeout=20) == 0
    rest = proc.stderr.read()
    assert rest == "flocking play: stopped; goodbye\n"


# -- the extensions: walls, obstacles, a second species, vision, chirality ----------------

EXT = Model(n=400, density=2.0, noise=0.5, seed=2)  # a box of 14.14


def ext_session(model=EXT):
    s = Session(model)
    s.take_replies()
    return s


def answers(s, message):
    """Send ``message`` (a dict), apply it, and return the error lines and the state."""
    s.handle(json.dumps(message))
    replies = s.take_replies()
    errors = [r["message"] for r in replies if r["type"] == "error"]
    states = [r for r in replies if r["type"] == "state"]
    return errors, states[-1] if states else None


def inside(model, positions):
    from flocking.space import Space

    return Space.of(model).in_obstacle(positions)


@pytest.mark.parametrize("params, check", [
    ({"boundary": "wall"}, lambda m: m.walls == (True, True)),
    ({"boundary": "wall,periodic"}, lambda m: m.walls == (True, False)),
    ({"boundary": "periodic,wall"}, lambda m: m.walls == (False, True)),
    ({"vision": math.pi / 4}, lambda m: m.vision == math.pi / 4),
    ({"chirality": -0.3}, lambda m: m.chirality == -0.3),
    ({"obstacles": [{"centre": [5.0, 5.0], "radius": 2.0}]}, lambda m: m.obstacles[0].radius == 2.0),
])
def test_each_extension_control_is_accepted_and_continues_the_state(params, check):
    s = ext_session()
    s.handle('{"type": "step"}')
    before = s.sim.state
    errors, state = answers(s, {"type": "set", "params": params})
    assert errors == [] and check(s.model) and s.model.extended
    assert state["model"] == {**s.model.to_dict(), "density": s.model.density}
    after = s.sim.state
    assert after.step == before.step == 1
    moved = inside(s.model, before.positions)  # only what a new obstacle covers moves
    np.testing.assert_array_equal(after.positions[~moved], before.positions[~moved])
    np.testing.assert_array_equal(after.headings[~moved], before.headings[~moved])
    s.handle('{"type": "step"}')
    assert s.sim.state.step == 2 and np.isfinite(s.sim.state.positions).all()


@pytest.mark.parametrize("message, expected", [
    ({"type": "set", "params": {"vision": 4.0}}, "vision: must be a half-angle in (0, pi] (got 4.0)"),
    ({"type": "set", "params": {"vision": 0}}, "vision: must be a half-angle in (0, pi] (got 0.0)"),
    ({"type": "set", "params": {"boundary": "walls"}}, "boundary: must be 'periodic', 'wall' or 2 of them"),
    ({"type": "set", "params": {"chirality": 4.0}}, "chirality: must be at most pi / dt"),
    ({"type": "set", "params": {"dim": 3, "chirality": 0.2}}, "chirality: must be 0 in 3D"),
    ({"type": "set", "params": {"species": [{"fraction": 0.5}, {"fraction": 0.6}]}},
     "species: the fractions must add up to 1 (got 1.1)"),
    ({"type": "set", "params": {"species": [{"fraction": 0.5}, {"fraction": 0.5, "noise": 7.0}]}},
     "species: must be in [0, 2*pi] for angular noise (species 'B')"),
    ({"type": "set", "params": {"species": [{"fraction": 0.5}, {"fraction": 0.5}], "coupling": [[1, -1]]}},
     "coupling: must be a 2 x 2 matrix"),
    ({"type": "obstacle", "at": [7.0, 7.0], "radius": 0.4}, "obstacles: must be radii above one step"),
    ({"type": "obstacle", "at": [7.0, 7.0], "radius": 7.5},
     "obstacles: obstacle 0 must keep at least one step (0.5) from its own periodic image along axis 0"),
    ({"type": "obstacle", "at": [7.0, 7.0], "radius": -1}, "obstacles: must be radii that are finite numbers > 0"),
    ({"type": "obstacle", "at": [7.0, 20.0], "radius": 1.0}, "obstacles: must be centres inside the box"),
    ({"type": "obstacle", "at": [7.0], "radius": 1.0}, "obstacle.at: must be 2 numbers, a point in the box"),
    ({"type": "obstacle", "at": [7.0, "x"], "radius": 1.0}, "obstacle.at: must be 2 numbers"),
    ({"type": "obstacle", "at": [7.0, 7.0]}, "obstacle: missing field 'radius'"),
    ({"type": "obstacle", "at": [7.0, 7.0], "radius": True}, "obstacle.radius: must be a float"),
])
def test_extension_errors_are_one_line_and_change_nothing(message, expected):
    s = ext_session()
    before = s.sim.state
    errors, _ = answers(s, message)
    assert len(errors) == 1 and errors[0].startswith(expected), errors
    assert "\n" not in errors[0]
    assert s.model == EXT and s.sim.state.step == 0
    np.testing.assert_array_equal(s.sim.state.positions, before.positions)


def test_obstacles_that_clash_with_walls_or_each_other_are_refused_in_one_line():
    s = ext_session()
    assert answers(s, {"type": "obstacle", "at": [7.0, 7.0], "radius": 3.0})[0] == []
    errors, _ = answers(s, {"type": "obstacle", "at": [12.0, 7.0], "radius": 1.8})  # a gap of 0.2 < v0 dt
    assert errors == ["obstacles: obstacles 0 and 1 overlap or are closer than one step (0.5) apart (gap 0.2)"]
    errors, _ = answers(s, {"type": "obstacle", "at": [1.0, 1.0], "radius": 1.0})  # fine while periodic
    assert errors == [] and len(s.model.obstacles) == 2
    errors, _ = answers(s, {"type": "set", "params": {"boundary": "wall"}})  # now 0 from the walls
    assert errors == [f"obstacles: obstacle 1 must keep at least one step (0.5) from the walls of axis 0 "
                      f"(centre 1, radius 1, box {EXT.box[0]:g})"]
    assert s.model.walls == (False, False)
    errors, _ = answers(s, {"type": "set", "params": {"speed": 3.5}})  # a step longer than a radius
    assert errors and errors[0].startswith("obstacles: must be radii above one step, speed * dt = 3.5")


def test_the_page_gets_each_obstacle_with_its_images_and_a_click_inside_removes_it():
    """The state names every disc the page draws, the rows of Space.obstacle_images: an
    obstacle at (1, 7) of radius 1.5 in a periodic box of 14.14 also shows past the
    opposite side, at x = 15.14. A click strictly inside an obstacle (here on its image)
    removes it; one on the rim does not (it tries to drop a second there, which overlaps).
    With walls across x, an image shows only across y."""
    s = ext_session()
    side = EXT.box[0]
    errors, state = answers(s, {"type": "obstacle", "at": [1.0, 7.0], "radius": 1.5})
    assert errors == []
    np.testing.assert_allclose(state["obstacle_images"], [[1.0, 7.0, 1.5], [1.0 + side, 7.0, 1.5]])
    errors, state = answers(s, {"type": "obstacle", "at": [7.0, 7.0], "radius": 2.0})
    assert errors == [] and len(state["obstacle_images"]) == 3
    errors, state = answers(s, {"type": "obstacle", "at": [14.0, 7.0], "radius": 0.6})  # inside the image
    assert errors == [] and [o.centre for o in s.model.obstacles] == [(7.0, 7.0)]
    assert state["obstacle_images"] == [[7.0, 7.0, 2.0]]
    errors, _ = answers(s, {"type": "obstacle", "at": [9.0, 7.0], "radius": 0.6})  # on the rim
    assert errors and errors[0].startswith("obstacles: obstacles 0 and 1 overlap") and len(s.model.obstacles) == 1
    assert answers(s, {"type": "set", "params": {"boundary": "wall,periodic"}})[0] == []
    errors, state = answers(s, {"type": "obstacle", "at": [12.0, 1.0], "radius": 1.2})
    assert errors == []
    np.testing.assert_allclose(state["obstacle_images"], [[7.0, 7.0, 2.0], [12.0, 1.0, 1.2], [12.0, 1.0 + side, 1.2]])


def test_more_than_the_obstacle_limit_is_refused():
    s = ext_session(Model(n=400, box=[200.0, 8.0], noise=0.5))
    for i in range(session_module.MAX_OBSTACLES):
        assert answers(s, {"type": "obstacle", "at": [3.0 + 6 * i, 4.0], "radius": 1.0})[0] == []
    errors, _ = answers(s, {"type": "obstacle", "at": [197.0, 4.0], "radius": 1.0})
    assert errors == ["obstacles: at most 32 in flocking play (got 33); click one to remove it"]
    assert len(s.model.obstacles) == session_module.MAX_OBSTACLES


def test_a_click_drops_an_obstacle_and_a_click_on_it_removes_it():
    s = ext_session()
    before = s.sim.state
    covered = inside(EXT.replace(obstacles=[{"centre": [7.0, 6.0], "radius": 3.0}]), before.positions)
    assert covered.sum() > 20  # about pi 9 * 2 = 57 particles
    errors, state = answers(s, {"type": "obstacle", "at": [7.0, 6.0], "radius": 3.0})
    assert errors == [] and state["model"]["obstacles"] == [{"centre": [7.0, 6.0], "radius": 3.0}]
    after = s.sim.state
    assert not inside(s.model, after.positions).any()
    # the covered particles sit just beyond the rim, on the ray from the centre through them
    r_old, r_new = before.positions[covered] - (7.0, 6.0), after.positions[covered] - (7.0, 6.0)
    np.testing.assert_allclose(np.linalg.norm(r_new, axis=1), 3.0 + 1e-6 * 0.5, rtol=1e-12)
    np.testing.assert_allclose(r_new / 3.0, r_old / np.linalg.norm(r_old, axis=1)[:, None], atol=1e-6)
    radial = np.einsum("ij,ij->i", after.headings[covered], r_new)
    assert (radial >= -1e-12).all()  # none heads back in
    np.testing.assert_array_equal(after.positions[~covered], before.positions[~covered])
    frame = decode_frame(s.take_frame())
    assert np.linalg.norm(frame["positions"] - (7.0, 6.0), axis=1).min() > 3.0 - 1e-3
    for _ in range(20):
        s.handle('{"type": "step"}')
    assert not inside(s.model, s.sim.state.positions).any()  # the engine bounces them off
    # a click inside the obstacle (not at its centre) removes it; the particles stay where they are
    held = s.sim.state.positions
    errors, state = answers(s, {"type": "obstacle", "at": [8.5, 7.0], "radius": 1.0})
    assert errors == [] and state["model"].get("obstacles") is None and s.model.obstacles == ()
    np.testing.assert_array_equal(s.sim.state.positions, held)


def test_an_obstacle_across_a_periodic_edge_is_cleared_and_removed_through_the_edge():
    s = ext_session()
    L = EXT.box[0]
    assert answers(s, {"type": "obstacle", "at": [0.5, 7.0], "radius": 2.0})[0] == []
    assert not inside(s.model, s.sim.state.positions).any()
    assert (s.sim.state.positions < L).all() and (s.sim.state.positions >= 0).all()
    assert answers(s, {"type": "obstacle", "at": [L - 1.0, 7.5], "radius": 1.0})[0] == []  # its image
    assert s.model.obstacles == ()


def test_clear_obstacles_moves_a_particle_at_the_centre_against_its_heading_within_walls():
    model = Model(n=3, box=10.0, boundary="wall", speed=0.5,
                  obstacles=[{"centre": [2.0, 5.0], "radius": 1.4}, {"centre": [6.0, 5.0], "radius": 2.0}])
    x = np.array([[2.0, 5.0], [6.0, 6.9], [9.0, 9.0]])
    u = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 1.0]])
    assert session_module.clear_obstacles(model, x, u) == 2
    np.testing.assert_allclose(x, [[2.0 - 1.4 - 5e-7, 5.0], [6.0, 7.0 + 5e-7], [9.0, 9.0]], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(u, [[-1.0, 0.0], [0.0, 1.0], [0.0, 1.0]])  # outward headings are kept
    assert not inside(model, x).any() and (x > 0).all() and (x < 10).all()


def test_species_sliders_make_the_model_and_each_species_moves_at_its_speed():
    s = ext_session(EXT.replace(noise=0.0))
    two = [{"name": "A", "fraction": 0.75}, {"name": "B", "fraction": 0.25, "speed": 1.5, "noise": 2.0}]
    errors, state = answers(s, {"type": "set", "params": {"species": two, "coupling": [[1, -1], [-1, 1]]}})
    m = s.model
    assert errors == [] and m.species_counts == (300, 100) and state["species_counts"] == [300, 100]
    assert m.species_values("speed") == (0.5, 1.5) and m.species_values("noise") == (0.0, 2.0)
    assert m.coupling == ((1.0, -1.0), (-1.0, 1.0)) and m.species_names == ("A", "B")
    assert state["model"]["species"] == two and state["model"]["coupling"] == [[1.0, -1.0], [-1.0, 1.0]]
    before = s.sim.state
    s.handle('{"type": "step"}')
    step = np.linalg.norm((s.sim.state.positions - before.positions + 7.07) % EXT.box[0] - 7.07, axis=1)
    np.testing.assert_allclose(step[:300], 0.5, rtol=1e-9)  # particles 0..299 are species A
    np.testing.assert_allclose(step[300:], 1.5, rtol=1e-9)
    # the global sliders still move species A only where B has its own value
    assert answers(s, {"type": "set", "params": {"speed": 0.8}})[0] == []
    assert s.model.species_values("speed") == (0.8, 1.5)
    # one species again: the 2 x 2 coupling cannot carry over, and goes
    errors, state = answers(s, {"type": "set", "params": {"species": []}})
    assert errors == [] and s.model.species == () and s.model.coupling is None and not s.model.extended
    assert state["species_counts"] == [400]


def test_a_new_dimension_keeps_the_walls_of_x_and_y_and_drops_obstacles_and_chirality():
    s = ext_session()
    for message in ({"type": "set", "params": {"boundary": "periodic,wall", "chirality": 0.2}},
                    {"type": "obstacle", "at": [7.0, 7.0], "radius": 2.0}):
        assert answers(s, message)[0] == []
    errors, state = answers(s, {"type": "set", "params": {"dim": 3}})
    assert errors == [] and s.model.dim == 3
    assert s.model.boundary == ("periodic", "wall", "periodic")
    assert s.model.obstacles == () and s.model.chirality == 0.0
    errors, _ = answers(s, {"type": "set", "params": {"boundary": "wall"}})
    assert errors == [] and s.model.walls == (True, True, True)
    errors, _ = answers(s, {"type": "set", "params": {"dim": 2}})
    assert errors == [] and s.model.walls == (True, True)


def test_the_extended_step_is_priced_higher_and_a_slow_one_is_refused_naming_its_switch():
    positions = State.random(EXT).positions
    plain = CPUBackend.step_cost(EXT, positions)[0]
    walls = CPUBackend.step_cost(EXT.replace(boundary="wall"), positions)[0]
    extended = CPUBackend.step_cost(EXT.replace(vision=2.0), positions)[0]
    small = Model(n=EXT.n, box=2.5, noise=0.5, vision=2.0)  # every particle a candidate of every other
    small_box = CPUBackend.step_cost(small, State.random(small).positions)[0]
    # measured: walls as the plain step; a cone about 1.2 times per particle and 3 per
    # candidate; the scalar step of a box under 3R 7 and 20 times (flocking/play/budget.py)
    assert plain <= walls < 1.3 * plain and 1.2 * plain < extended < 2 * plain and small_box > 10 * extended
    with_obstacles = CPUBackend.step_cost(EXT.replace(vision=2.0, obstacles=[{"centre": [7.0, 7.0], "radius": 1.0}] * 1),
                               positions)[0]
    assert with_obstacles == pytest.approx(extended + 25e-9 * EXT.n)
    s = ext_session(Model(n=200_000, density=60.0, noise=0.5))  # plain: 0.28 s a step, with the cone 0.74 s
    errors, _ = answers(s, {"type": "set", "params": {"vision": 2.0}})
    assert len(errors) == 1 and re.fullmatch(r"vision: one step would take about 0\.\d+ s here .*, or turn "
                                             r"extensions off", errors[0]), errors
    assert not s.model.extended


def test_extensions_reach_the_page_and_the_exported_config(ws, tmp_path):
    ws.send_text(json.dumps({"type": "set", "params": {
        "boundary": "wall", "vision": 2.0, "species": [{"name": "A", "fraction": 0.5},
                                                       {"name": "B", "fraction": 0.5, "noise": 1.5}],
        "coupling": [[1, -1], [-1, 1]]}}))
    state = reply(ws, "state")
    assert state["model"]["boundary"] == "wall" and state["species_counts"] == [150, 150]
    ws.send_text('{"type": "obstacle", "at": [6.0, 6.0], "radius": 1.5}')
    state = reply(ws, "state")
    assert state["model"]["obstacles"] == [{"centre": [6.0, 6.0], "radius": 1.5}]
    assert state["limits"]["obstacles"] == session_module.MAX_OBSTACLES
    ws.send_text('{"type": "config"}')
    config = reply(ws, "config")["toml"]
    model = RunConfig.from_toml(config).model  # what flocking run --config would run
    assert model.walls == (True, True) and model.vision == 2.0 and model.species_counts == (150, 150)
    assert model.coupling == ((1.0, -1.0), (-1.0, 1.0)) and model.species_values("noise") == (0.5, 1.5)
    assert [o.to_dict() for o in model.obstacles] == [{"centre": [6.0, 6.0], "radius": 1.5}]
