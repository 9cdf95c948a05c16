"""flocking play: the session (messages, limits, frames), the web app and its socket, the CLI."""

from __future__ import annotations

import json
import math
import os
import re
import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest
from click.testing import CliRunner

from flocking import Model, State
from flocking.cli import main
from flocking.config import RunConfig
from flocking.play.session import MAX_MESSAGE, MAX_N, Session, decode_frame, encode_frame, parse_message

pytest.importorskip("starlette")
pytest.importorskip("httpx")  # starlette's TestClient
from starlette.testclient import TestClient  # noqa: E402
from starlette.websockets import WebSocketDisconnect  # noqa: E402

from flocking.play.server import create_app  # noqa: E402

SRC = os.path.join(os.path.dirname(__file__), os.pardir, "src")
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


@pytest.fixture
def client():
    app = create_app(SMALL)
    with TestClient(app) as c:
        c.app_sessions = app.state.sessions
        yield c


@pytest.fixture
def ws(client):
    with client.websocket_connect("/ws") as ws:
        assert reply(ws)["type"] == "state"
        ws.send_text('{"type": "pause"}')
        assert reply(ws, "state")["running"] is False
        ws.send_text('{"type": "reset"}')  # frames of the steps before the pause are behind us now
        reply(ws, "state")
        assert frame(ws)["step"] == 0
        yield ws


# -- the page ---------------------------------------------------------------------------


def test_page_and_static_files(client):
    page = client.get("/")
    assert page.status_code == 200 and "<canvas id=\"flock\"" in page.text
    assert "default-src 'self'" in page.headers["content-security-policy"]
    for name in ("app.js", "frame.js", "render.js", "plot.js", "style.css", "favicon.svg"):
        assert client.get(f"/static/{name}").status_code == 200, name
    assert client.get("/static/nothing.js").status_code == 404
    assert client.get("/static/../server.py").status_code == 404


# -- hostile and malformed messages -------------------------------------------------------

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
    ('{"type": "set", "params": {"noise": 9}}', "noise: must be in [0, 2*pi]"),
    ('{"type": "set", "params": {"noise": "loud"}}', "noise: must be a number"),
    ('{"type": "set", "params": {"noise": NaN}}', "not valid JSON"),
    ('{"type": "set", "params": {"noise": Infinity}}', "not valid JSON"),
    ('{"type": "set", "params": {"noise": 1e999}}', "noise: must be"),
    ('{"type": "set", "params": {"noise": null}}', "noise: must be a number"),
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
    ('{"type": "set", "params": {"radius": 50, "n": 100000}}', "radius: 50 gives too many neighbours"),
    ('{"type": "set", "params": {"seed": -1}}', "seed: must be"),
    ('{"type": "set", "params": {"alignment": true}}', "alignment: must be a number"),
    ('{"type": "steps_per_frame", "value": 0}', "steps_per_frame: must be in [1, 50]"),
    ('{"type": "steps_per_frame", "value": 1e9}', "steps_per_frame.value: must be a int"),
    ('{"type": "steps_per_frame", "value": true}', "steps_per_frame.value: must be a int"),
    ('{"type": "reset", "init": "/etc/passwd"}', "reset.init: must be one of random, aligned"),
    ("[" * 3000 + "]" * 3000, "message too long"),
    ("[" * 2000 + "]" * 2000, "not valid JSON"),
    ('{"type": "config", "pad": "' + "x" * MAX_MESSAGE + '"}', "message too long"),
]


@pytest.mark.parametrize("raw, expected", BAD, ids=[f"bad{i}" for i in range(len(BAD))])
def test_bad_message_is_refused_and_changes_nothing(ws, raw, expected):
    ws.send_text(raw)
    error = reply(ws)
    assert error["type"] == "error" and expected in error["message"], error
    ws.send_text('{"type": "set", "params": {"noise": 0.25}}')  # still serving, nothing changed before
    state = reply(ws)
    assert state["type"] == "state" and state["model"]["noise"] == 0.25
    assert state["model"]["n"] == SMALL.n and state["model"]["k"] == SMALL.k


def test_binary_garbage_is_refused(ws):
    for junk in (b"\x00\xff" * 100, os.urandom(5000), b""):
        ws.send_bytes(junk)
        assert "binary messages are not accepted" in reply(ws, "error")["message"]
    ws.send_text('{"type": "step"}')
    assert frame(ws)["step"] == 1


def test_a_flood_of_bad_messages_does_not_stop_the_server(client):
    with client.websocket_connect("/ws") as ws:
        for i in range(200):
            ws.send_text('{"type": "set", "params": {"n": %d}}' % (10**9 + i))
        errors = 0
        while errors < 64:  # replies beyond the queue's 64 are dropped, not stored
            if reply(ws)["type"] == "error":
                errors += 1
        ws.send_text('{"type": "set", "params": {"noise": 0.75}}')
        while (r := reply(ws))["type"] != "state":
            pass
        assert r["model"]["noise"] == 0.75


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


# -- sessions ---------------------------------------------------------------------------


def wait_for(predicate, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return False


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


def test_foreign_origin_is_refused(client):
    with pytest.raises(WebSocketDisconnect) as err:
        with client.websocket_connect("/ws", headers={"origin": "https://evil.example"}) as ws:
            ws.receive()
    assert err.value.code == 1008
    with client.websocket_connect("/ws", headers={"origin": "http://testserver"}) as ws:
        assert reply(ws)["type"] == "state"


def test_too_many_tabs_get_an_error():
    with TestClient(create_app(SMALL, max_sessions=1)) as c:
        with c.websocket_connect("/ws") as first:
            reply(first)
            with c.websocket_connect("/ws") as second:
                assert "too many open tabs" in reply(second)["message"]
                closing = second.receive()
                assert closing["type"] == "websocket.close" and closing["code"] == 1013


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


# -- the command ------------------------------------------------------------------------


def test_missing_extra_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "uvicorn", None)
    result = CliRunner().invoke(main, ["play", "--no-browser"])
    assert result.exit_code == 1
    assert result.output.strip() == "Error: flocking play needs its web extra: pip install 'flocking[play]'"


def test_bad_options_and_busy_port():
    result = CliRunner().invoke(main, ["play", "--no-browser", "--n", "300000"])
    assert result.exit_code == 2 and "--n: must be at most 200000 in flocking play" in result.output
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        result = CliRunner().invoke(main, ["play", "--no-browser", "--port", str(port)])
    assert result.exit_code == 2 and result.output.startswith(f"Error: --port: cannot listen on 127.0.0.1:{port}")


def test_flocking_play_serves_on_loopback():
    websockets = pytest.importorskip("websockets.sync.client")
    env = {**os.environ, "PYTHONPATH": os.path.abspath(SRC)}
    proc = subprocess.Popen([sys.executable, "-m", "flocking", "play", "--port", "0", "--no-browser",
                             "--n", "500"], env=env, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        url = re.search(r"http://127\.0\.0\.1:\d+/", line).group(0)
        with urllib.request.urlopen(url, timeout=20) as page:
            assert b"flocking play" in page.read()
        ws_url = url.replace("http", "ws") + "ws"
        with websockets.connect(ws_url, max_size=None) as ws:
            ws.send("x" * 100_000)  # over the server's 64 KiB frame limit: that socket is closed
            with pytest.raises(Exception):
                for _ in range(1000):
                    ws.recv(timeout=10)
        with websockets.connect(ws_url, max_size=None) as ws:  # the server goes on serving
            assert json.loads(ws.recv(timeout=20))["model"]["n"] == 500
            assert decode_frame(ws.recv(timeout=20))["n"] == 500
    finally:
        proc.terminate()
        proc.wait(timeout=20)
