"""The live page's HTTP server (:class:`LiveServer`): the standard library's threading HTTP server on
the loopback address, serving the page and a :class:`~c3f_slam.live.state.LiveState`.

Endpoints: ``GET /`` (page.html), ``GET /live.js``, ``GET /three.js`` (the vendored three.js of the
3D view), ``GET /state.json?since=V`` (:meth:`LiveState.snapshot`), ``GET /frame.jpg`` (the current
frame; 404 before the first; headers ``X-Frame-Version``, ``X-Frame-Index``, ``X-Captured-At``,
``X-Frame-Decision``),
``POST /shown`` (JSON ``{"index": int, "delay_ms": float}``: a page displayed a frame; 204); anything
else 404. Nothing is logged per request. A client that goes away mid-answer costs its thread only.

Served on a loopback address, requests must name a loopback host (``Host:`` 127.0.0.1, localhost or
[::1]): a web page elsewhere cannot reach the run's frames by pointing a host name at 127.0.0.1.
"""

from __future__ import annotations

import errno
import json
import logging
import socket
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from c3f_core.errors import InputError
from c3f_slam.live.state import LiveState

HERE = Path(__file__).parent
THREE_JS = HERE.parent / "view" / "vendor" / "three.view.min.js"
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
MAX_BODY = 4096  #: bytes a POST body may have
CLIENT_TIMEOUT_S = 10.0  #: a connection that sends nothing for this long is closed
DISCONNECTS = (BrokenPipeError, ConnectionResetError, ConnectionAbortedError, TimeoutError)

log = logging.getLogger(__name__)


def _host_name(header: str | None) -> str:
    """The host name of a ``Host:`` header (no port, no IPv6 brackets), lower case."""
    host = (header or "").strip().lower()
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host[1:]
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False  # stop() does not wait for slow clients

    def __init__(self, address: tuple[str, int], state: LiveState, assets: dict[str, tuple[bytes, str]],
                 loopback: bool) -> None:
        self.state, self.assets, self.loopback = state, assets, loopback
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        super().__init__(address, _Handler)

    def handle_error(self, request, client_address) -> None:
        """A failed request is logged (debug), never printed: the run goes on."""
        log.debug("live page request from %s failed", client_address, exc_info=True)


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    timeout = CLIENT_TIMEOUT_S
    server_version = "C3FusionLive"

    def log_message(self, format: str, *args) -> None:
        """No request log."""

    def handle(self) -> None:
        try:
            super().handle()
        except DISCONNECTS:
            self.close_connection = True

    def _send(self, status: int, body: bytes = b"", content_type: str | None = None,
              headers: dict[str, str] | None = None) -> None:
        self.send_response(status)
        if content_type:
            self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        for key, value in (headers or {}).items():
            self.send_header(key, value)
        self.end_headers()
        if body and self.command != "HEAD":
            self.wfile.write(body)

    def _not_found(self) -> None:
        self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")

    def _allowed(self) -> bool:
        if self.server.loopback and _host_name(self.headers.get("Host")) not in LOOPBACK_NAMES:
            self._send(HTTPStatus.FORBIDDEN, b"the live page answers on the loopback address only\n",
                       "text/plain; charset=utf-8")
            return False
        return True

    def do_GET(self) -> None:
        if not self._allowed():
            return
        url = urlsplit(self.path)
        if url.path in self.server.assets:
            body, content_type = self.server.assets[url.path]
            self._send(HTTPStatus.OK, body, content_type)
        elif url.path == "/state.json":
            try:
                since = int(parse_qs(url.query).get("since", ["0"])[0])
            except ValueError:
                self._send(HTTPStatus.BAD_REQUEST, b"since must be an integer\n", "text/plain; charset=utf-8")
                return
            body = json.dumps(self.server.state.snapshot(since), separators=(",", ":"), allow_nan=False)
            self._send(HTTPStatus.OK, body.encode(), "application/json")
        elif url.path == "/frame.jpg":
            jpeg = self.server.state.current_jpeg()
            if jpeg is None:
                self._not_found()
                return
            self._send(HTTPStatus.OK, jpeg.data, "image/jpeg",
                       {"X-Frame-Version": str(jpeg.version), "X-Frame-Index": str(jpeg.index),
                        "X-Captured-At": repr(jpeg.captured_at), "X-Frame-Decision": jpeg.decision})
        else:
            self._not_found()

    def do_HEAD(self) -> None:
        self.do_GET()

    def do_POST(self) -> None:
        if not self._allowed():
            return
        if urlsplit(self.path).path != "/shown":
            self._not_found()
            return
        try:
            length = int(self.headers.get("Content-Length", "0"))
        except ValueError:
            length = -1
        if not 0 < length <= MAX_BODY:
            self.close_connection = True
            self._send(HTTPStatus.BAD_REQUEST, b"a JSON body of at most 4096 bytes\n", "text/plain; charset=utf-8")
            return
        try:
            body = json.loads(self.rfile.read(length))
            index, delay_ms = body["index"], body["delay_ms"]
            if not isinstance(index, int) or isinstance(delay_ms, bool) or not isinstance(delay_ms, int | float):
                raise ValueError
        except (ValueError, KeyError, TypeError):
            self._send(HTTPStatus.BAD_REQUEST, b'expected {"index": int, "delay_ms": number}\n',
                       "text/plain; charset=utf-8")
            return
        self.server.state.report_shown(index, delay_ms)
        self._send(HTTPStatus.NO_CONTENT)


class LiveServer:
    """Serves ``state`` and the page on ``host``:``port`` (0: a free port) from a daemon thread:
    ``start()``, ``url``, ``stop()``, or ``with LiveServer(state) as server:``."""

    def __init__(self, state: LiveState, host: str = "127.0.0.1", port: int = 0) -> None:
        self.state, self.host, self._port = state, host, int(port)
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None

    def _assets(self) -> dict[str, tuple[bytes, str]]:
        page = (HERE / "page.html").read_bytes()
        return {"/": (page, "text/html; charset=utf-8"),
                "/live.js": ((HERE / "live.js").read_bytes(), "text/javascript; charset=utf-8"),
                "/three.js": (THREE_JS.read_bytes(), "text/javascript; charset=utf-8")}

    def start(self) -> LiveServer:
        """Binds and serves on a daemon thread; InputError (one line) when the port cannot be bound."""
        if self._server is not None:
            return self
        loopback = self.host in LOOPBACK_NAMES or self.host.startswith("127.")
        try:
            self._server = _Server((self.host, self._port), self.state, self._assets(), loopback)
        except OSError as exc:
            why = "is in use" if exc.errno == errno.EADDRINUSE else f"cannot be bound ({exc.strerror or exc})"
            raise InputError(f"live page: port {self._port} on {self.host} {why}") from None
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="c3f-live-server", daemon=True)
        self._thread.start()
        return self

    @property
    def port(self) -> int:
        """The port served (the free one picked for port 0 once started)."""
        return self._server.server_address[1] if self._server is not None else self._port

    @property
    def url(self) -> str:
        """The page's address, e.g. ``http://127.0.0.1:8765/``."""
        host = "127.0.0.1" if self.host in ("", "0.0.0.0") else self.host
        if ":" in host:
            host = f"[{host}]"
        return f"http://{host}:{self.port}/"

    def stop(self) -> None:
        """Stops serving and closes the socket (requests in flight finish on their own threads)."""
        if self._server is None:
            return
        self._server.shutdown()
        self._server.server_close()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._server = self._thread = None

    def __enter__(self) -> LiveServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
