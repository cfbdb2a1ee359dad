"""The web view's server: the page, py_trees_js's assets, and the frames as Server-Sent Events.

Standard library only (``http.server``), one thread per connection, on 127.0.0.1 unless told
otherwise. :meth:`ViewServer.publish` never blocks: each browser has a bounded queue, and a slow
one loses its oldest frames, not the robot its ticks. A browser that connects late gets the run
so far first (the last ``history`` frames), then every new frame. Unknown paths answer 404,
other methods 405, never a traceback.
"""

from __future__ import annotations

import collections
import contextlib
import json
import logging
import queue
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from sm_bt.view.assets import ASSETS, NEEDED, missing
from sm_bt.view.frames import Frame

log = logging.getLogger("sm_bt.view")

STATIC = Path(__file__).with_name("static")
_PAGES = {"/": ("index.html", "text/html; charset=utf-8"), "/view.js": ("view.js", "text/javascript"),
          "/view.css": ("view.css", "text/css")}
_TYPES = {".js": "text/javascript", ".css": "text/css"}
_CLOSED = object()
#: Frames a browser may fall behind by before it loses the oldest.
CLIENT_QUEUE = 500


class ViewServer:
    """Serve the view on ``host``:``port`` (0: any free port) from a background thread."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *, history: int = 5000,
                 frames: list[Frame] | None = None) -> None:
        lacking = missing()
        if lacking:
            raise RuntimeError(f"the py_trees_js assets are missing ({', '.join(lacking)}): run "
                               "`python -m sm_bt.view.assets` once (make does it)")
        self._history: collections.deque[Frame] = collections.deque(frames or (), maxlen=history)
        self._clients: set[queue.Queue[Any]] = set()
        self._lock = threading.Lock()
        self.live = frames is None
        server = self
        handler = type("Handler", (_Handler,), {"view": server})
        self._http = ThreadingHTTPServer((host, port), handler)
        self._http.daemon_threads = True
        self._thread = threading.Thread(target=self._http.serve_forever, name="sm_bt-view", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        host, port = self._http.server_address[:2]
        shown = host.decode() if isinstance(host, bytes) else str(host)
        return f"http://{shown}:{port}/"

    def publish(self, frame: Frame) -> None:
        """Hand ``frame`` to every browser (and keep it for the ones that come later)."""
        with self._lock:
            self._history.append(frame)
            clients = list(self._clients)
        for client in clients:
            _put_dropping_oldest(client, frame)

    __call__ = publish  # a FrameMaker sink

    def history(self) -> list[Frame]:
        """The frames kept for browsers that connect later (the latest ``history``)."""
        with self._lock:
            return list(self._history)

    def subscribe(self) -> tuple[list[Frame], queue.Queue[Any]]:
        client: queue.Queue[Any] = queue.Queue(maxsize=CLIENT_QUEUE)
        with self._lock:
            self._clients.add(client)
            return list(self._history), client

    def unsubscribe(self, client: queue.Queue[Any]) -> None:
        with self._lock:
            self._clients.discard(client)

    def close(self) -> None:
        with self._lock:
            clients, self._clients = list(self._clients), set()
        for client in clients:
            _put_dropping_oldest(client, _CLOSED)
        self._http.shutdown()
        self._http.server_close()
        self._thread.join(3.0)


def _put_dropping_oldest(client: queue.Queue[Any], item: Any) -> None:
    while True:
        try:
            client.put_nowait(item)
            return
        except queue.Full:
            with contextlib.suppress(queue.Empty):  # another thread took it meanwhile
                client.get_nowait()


class _Handler(BaseHTTPRequestHandler):
    view: ViewServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("%s %s", self.address_string(), format % args)

    def do_GET(self) -> None:
        path = self.path.split("?", 1)[0]
        try:
            if path in _PAGES:
                name, kind = _PAGES[path]
                self._send(HTTPStatus.OK, (STATIC / name).read_bytes(), kind)
            elif path.startswith("/assets/") and path[len("/assets/"):] in NEEDED:
                name = path[len("/assets/"):]
                self._send(HTTPStatus.OK, (ASSETS / name).read_bytes(), _TYPES[Path(name).suffix], cache=True)
            elif path == "/frames.json":
                history, client = self.view.subscribe()
                self.view.unsubscribe(client)
                self._send(HTTPStatus.OK, json.dumps({"live": self.view.live, "frames": history}).encode(),
                           "application/json")
            elif path == "/events":
                self._stream()
            else:
                self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")
        except (BrokenPipeError, ConnectionResetError):
            pass  # the browser went away
        except Exception:
            log.exception("view request %s failed", path)
            self._send(HTTPStatus.INTERNAL_SERVER_ERROR, b"internal error\n", "text/plain; charset=utf-8")

    def _refuse(self) -> None:
        self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"only GET\n", "text/plain; charset=utf-8", allow="GET")

    do_POST = do_PUT = do_DELETE = do_PATCH = _refuse

    def do_HEAD(self) -> None:
        self._refuse()

    def _send(self, status: HTTPStatus, body: bytes, kind: str, *, cache: bool = False, allow: str = "") -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "max-age=3600" if cache else "no-store")
        if allow:
            self.send_header("Allow", allow)
        self.end_headers()
        self.wfile.write(body)

    def _stream(self) -> None:
        """Server-Sent Events: the run so far, then each new frame, until the browser leaves."""
        history, client = self.view.subscribe()
        try:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.send_header("Connection", "close")
            self.end_headers()
            for frame in history:
                self._event(frame)
            self.wfile.write(b"event: caught-up\ndata: {}\n\n")  # the page draws the run so far now
            self.wfile.flush()
            if not self.view.live:
                self.wfile.write(b"event: end\ndata: {}\n\n")
                self.wfile.flush()
                return
            while True:
                try:
                    item = client.get(timeout=15.0)
                except queue.Empty:
                    self.wfile.write(b": keep-alive\n\n")  # tells a dead connection apart
                    self.wfile.flush()
                    continue
                if item is _CLOSED:
                    self.wfile.write(b"event: end\ndata: {}\n\n")
                    self.wfile.flush()
                    return
                self._event(item)
                self.wfile.flush()
        finally:
            self.view.unsubscribe(client)
            self.close_connection = True

    def _event(self, frame: Frame) -> None:
        self.wfile.write(b"data: " + json.dumps(frame, separators=(",", ":")).encode() + b"\n\n")
