"""The live page's HTTP server (c3f_slam/live/server.py): its endpoints and 404s, /shown, a port in
use, loopback only, several clients at once, clients that go away mid-request."""

from __future__ import annotations

import http.client
import json
import socket
import threading
import time

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.live.server import LiveServer
from tests.test_live_state import grey, make_state, publish


def request(port: int, method: str, path: str, body: bytes | None = None, headers: dict | None = None,
            host: str = "127.0.0.1") -> tuple[int, dict[str, str], bytes]:
    """(status, headers, body) of one request (http.client: no proxy from the environment)."""
    conn = http.client.HTTPConnection(host, port, timeout=10)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        resp = conn.getresponse()
        return resp.status, dict(resp.getheaders()), resp.read()
    finally:
        conn.close()


@pytest.fixture
def served():
    state = make_state(np.ones((120, 160), bool))
    with LiveServer(state) as server:
        yield state, server


def test_endpoints(served, capfd):
    state, server = served
    port = server.port
    assert server.url == f"http://127.0.0.1:{port}/"
    status, headers, page = request(port, "GET", "/")
    assert status == 200 and headers["Content-Type"].startswith("text/html") and b'src="/live.js"' in page
    status, headers, js = request(port, "GET", "/live.js")
    assert status == 200 and "javascript" in headers["Content-Type"] and b"state.json" in js
    status, _, three = request(port, "GET", "/three.js")
    assert status == 200 and b"OrbitControls" in three
    assert request(port, "GET", "/frame.jpg")[0] == 404  # before the first frame
    publish(state, 3, "keyframe", rgb=grey(), z=0.0)
    status, headers, body = request(port, "GET", "/state.json")
    snap = json.loads(body)
    assert status == 200 and headers["Cache-Control"] == "no-store" and snap["frame"]["index"] == 3
    status, _, body = request(port, "GET", f"/state.json?since={snap['version']}")
    assert status == 200 and json.loads(body)["timeline"]["entries"] == []
    assert request(port, "GET", "/state.json?since=abc")[0] == 400
    status, headers, jpeg = request(port, "GET", f"/frame.jpg?v={snap['frame']['version']}")
    assert status == 200 and headers["Content-Type"] == "image/jpeg" and headers["Cache-Control"] == "no-store"
    assert headers["X-Frame-Index"] == "3" and headers["X-Frame-Decision"] == "keyframe"
    assert cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR).shape == (120, 160, 3)
    for path in ("/nope", "/page.html", "/state.json/x", "/../state.py"):
        assert request(port, "GET", path)[0] == 404, path
    assert request(port, "POST", "/state.json", b"{}", {"Content-Type": "application/json"})[0] == 404
    status, _, _ = request(port, "POST", "/shown", json.dumps({"index": 3, "delay_ms": 42.5}).encode(),
                           {"Content-Type": "application/json"})
    assert status == 204
    delays = state.snapshot()["rates"]["delays"]["capture_to_display_ms"]
    assert delays == {"median": 42.5, "p95": 42.5, "samples": 1}
    for bad in (b"not json", b'{"index": 3}', b'{"index": "3", "delay_ms": 1}', b"[]"):
        assert request(port, "POST", "/shown", bad, {"Content-Type": "application/json"})[0] == 400, bad
    assert request(port, "PUT", "/shown", b"{}")[0] == 501
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # no request log


def test_other_host_names_are_refused(served):
    _, server = served
    assert request(server.port, "GET", "/state.json", headers={"Host": "evil.example:80"})[0] == 403
    assert request(server.port, "GET", "/state.json", headers={"Host": f"localhost:{server.port}"})[0] == 200


def test_port_in_use_is_an_input_error():
    state = make_state()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(InputError, match=f"port {port} on 127.0.0.1 is in use") as err:
            LiveServer(state, port=port).start()
    assert "\n" not in str(err.value)


def non_loopback_address() -> str | None:
    """An IPv4 address of this machine other than loopback, or None."""
    candidates = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("10.255.255.255", 1))  # no packet is sent: it only picks the outgoing interface
            candidates.append(s.getsockname()[0])
        except OSError:
            pass
    try:
        candidates.append(socket.gethostbyname(socket.gethostname()))
    except OSError:
        pass
    return next((a for a in candidates if a and not a.startswith("127.") and a != "0.0.0.0"), None)


def test_served_on_loopback_only(served):
    _, server = served
    address = non_loopback_address()
    if address is None:
        pytest.skip("this machine has no non-loopback IPv4 address")
    assert request(server.port, "GET", "/state.json")[0] == 200
    with pytest.raises(OSError):
        socket.create_connection((address, server.port), timeout=2).close()


def test_several_clients_at_once(served):
    state, server = served
    publish(state, 0, rgb=grey())
    failures = []

    def client(k: int) -> None:
        try:
            for i in range(15):
                path = ("/state.json?since=0", "/frame.jpg", "/live.js")[(i + k) % 3]
                assert request(server.port, "GET", path)[0] == 200
        except Exception as exc:
            failures.append(exc)

    threads = [threading.Thread(target=client, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for i in range(1, 50):  # the run goes on meanwhile
        publish(state, i, rgb=grey(i))
    for t in threads:
        t.join(timeout=30)
    assert not failures, failures[0]


def test_clients_that_go_away(served, capfd):
    state, server = served
    publish(state, 0, rgb=grey())
    for _ in range(5):
        with socket.create_connection(("127.0.0.1", server.port)) as s:  # half a request, then gone
            s.sendall(b"GET /state.json HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        s = socket.create_connection(("127.0.0.1", server.port))  # a big answer nobody reads
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")  # reset on close
        s.sendall(b"GET /three.js HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
        s.recv(10)
        s.close()
    with socket.create_connection(("127.0.0.1", server.port)) as s:  # a POST whose body never comes
        s.sendall(b"POST /shown HTTP/1.0\r\nHost: 127.0.0.1\r\nContent-Length: 100\r\n\r\n{")
    time.sleep(0.2)
    publish(state, 1, rgb=grey())
    assert request(server.port, "GET", "/state.json")[0] == 200
    assert request(server.port, "GET", "/frame.jpg")[0] == 200
    assert capfd.readouterr().err == ""


def test_stop_closes_the_port():
    state = make_state()
    server = LiveServer(state).start()
    port = server.port
    assert request(port, "GET", "/")[0] == 200
    server.stop()
    server.stop()  # twice is fine
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
