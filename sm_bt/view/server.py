"""The web view's server: the page, py_trees_js's assets, and the frames as Server-Sent Events.

Standard library only (``http.server``), one thread per connection, on 127.0.0.1 unless told
otherwise. :meth:`ViewServer.publish` never blocks: each browser has a bounded queue, and one
that falls too far behind starts again from the history (a ``reset`` event), while the robot
loses no tick. A browser that connects late gets the run so far first (the last ``history`` frames,
the oldest folded into a key frame), then every new frame. GET and HEAD only; anything else, or a
request that cannot be parsed, gets a one-line plain-text answer (404, 405, 400), never a
traceback; a browser that closes a connection is no news.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import queue
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from sm_bt.view.assets import ASSETS, NEEDED, missing
from sm_bt.view.frames import Frame
from sm_bt.view.recording import encode, fold

log = logging.getLogger("sm_bt.view")

STATIC = Path(__file__).with_name("static")
_PAGES = {"/": ("index.html", "text/html; charset=utf-8"), "/view.js": ("view.js", "text/javascript"),
          "/view.css": ("view.css", "text/css"), "/tree.js": ("tree.js", "text/javascript"),
          "/timeline.js": ("timeline.js", "text/javascript"), "/check.js": ("check.js", "text/javascript")}
_TYPES = {".js": "text/javascript", ".css": "text/css"}
_TEXT = "text/plain; charset=utf-8"
_CLOSED = object()
_RESYNC = object()  # the browser fell too far behind: send it the history again
#: Frames a browser may fall behind by before it loses the oldest.
CLIENT_QUEUE = 2000
#: How often the serving thread looks for a shutdown (seconds): closing waits about half of it.
_POLL = 0.02


class _History:
    """The frames a late browser gets: at most ``limit``, the first always a key frame (the
    oldest are folded into the next one as they go)."""

    def __init__(self, limit: int, frames: list[Frame]) -> None:
        self.limit = max(limit, 2)
        self.frames: collections.deque[Frame] = collections.deque(frames)

    def append(self, frame: Frame) -> None:
        self.frames.append(frame)
        while len(self.frames) > self.limit:
            oldest = self.frames.popleft()
            self.frames[0] = fold(oldest, self.frames[0])


class ViewServer:
    """Serve the view on ``host``:``port`` (0: any free port) from a background thread; with
    ``frames`` (a recording), those and no more."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *, history: int = 20_000,
                 frames: list[Frame] | None = None) -> None:
        lacking = missing()
        if lacking:
            raise RuntimeError(f"the py_trees_js assets are missing ({', '.join(lacking)}): run "
                               "`python -m sm_bt.view.assets` once (make does it)")
        self._history = _History(max(history, len(frames or ())), list(frames or ()))
        self._clients: set[queue.Queue[Any]] = set()
        self._lock = threading.Lock()
        self.live = frames is None
        #: Bytes sent by path (the page's weight, for tests and the curious).
        self.sent: collections.Counter[str] = collections.Counter()
        handler = type("Handler", (_Handler,), {"view": self})
        self._http = _Server((host, port), handler)
        self._http.daemon_threads = True
        self._thread = threading.Thread(target=self._http.serve_forever, args=(_POLL,), name="sm_bt-view",
                                        daemon=True)
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
            _offer(client, frame)

    __call__ = publish  # a FrameMaker sink

    def history(self) -> list[Frame]:
        """The frames kept for browsers that connect later (the first a key frame)."""
        with self._lock:
            return list(self._history.frames)

    def subscribe(self) -> tuple[list[Frame], queue.Queue[Any]]:
        client: queue.Queue[Any] = queue.Queue(maxsize=CLIENT_QUEUE)
        with self._lock:
            self._clients.add(client)
            return list(self._history.frames), client

    def unsubscribe(self, client: queue.Queue[Any]) -> None:
        with self._lock:
            self._clients.discard(client)

    def finish(self) -> None:
        """The run is over: browsers are told so (and those that come later), the page stays served."""
        with self._lock:
            self.live = False
            clients = list(self._clients)
        for client in clients:
            _offer(client, _CLOSED)

    def close(self) -> None:
        with self._lock:
            clients, self._clients = list(self._clients), set()
        for client in clients:
            _offer(client, _CLOSED)
        self._http.shutdown()
        self._http.server_close()
        self._thread.join(3.0)


class _Server(ThreadingHTTPServer):
    def handle_error(self, request: Any, client_address: Any) -> None:
        """A browser that leaves mid-request (a reset, a broken pipe) is normal; anything else is
        logged, not printed to the program's stderr."""
        import sys

        error = sys.exc_info()[1]
        if isinstance(error, (ConnectionError, TimeoutError)):
            return
        log.warning("view: request from %s failed", client_address[0], exc_info=error)


def _offer(client: queue.Queue[Any], item: Any) -> None:
    """Queue ``item`` for a browser; one that fell ``CLIENT_QUEUE`` frames behind loses them all
    and starts again from the history (a delta without the frames before it means nothing)."""
    try:
        client.put_nowait(item)
    except queue.Full:
        with contextlib.suppress(queue.Empty):  # the browser's thread may take some meanwhile
            while True:
                client.get_nowait()
        client.put_nowait(_CLOSED if item is _CLOSED else _RESYNC)


class _Handler(BaseHTTPRequestHandler):
    view: ViewServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("%s %s", self.address_string(), format % args)

    def handle(self) -> None:
        with contextlib.suppress(ConnectionError, TimeoutError):  # the browser went away
            super().handle()

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """One plain-text line instead of http.server's HTML page; an unknown method is 405."""
        status = HTTPStatus(code)
        if status is HTTPStatus.NOT_IMPLEMENTED:
            status, message = HTTPStatus.METHOD_NOT_ALLOWED, f"{getattr(self, 'command', '')} is not served"
        body = f"{status.value} {status.phrase}: {message or status.description}\n".encode("utf-8", "replace")
        self.close_connection = True
        self.request_version = "HTTP/1.0"  # a line without one reads as HTTP/0.9: no status line, no headers
        self._send(status, body, _TEXT, allow="GET, HEAD" if status is HTTPStatus.METHOD_NOT_ALLOWED else "")

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
                frames = ",".join(encode(frame) for frame in self.view.history())
                body = f'{{"live":{"true" if self.view.live else "false"},"frames":[{frames}]}}'
                self._send(HTTPStatus.OK, body.encode(), "application/json")
            elif path == "/events" and self.command == "GET":
                self._stream()
            elif path == "/events":
                self._send(HTTPStatus.OK, b"", "text/event-stream")
            else:
                self._send(HTTPStatus.NOT_FOUND, b"404 Not Found: " + path.encode("utf-8", "replace")[:200] + b"\n",
                           _TEXT)
        except ConnectionError:
            pass  # the browser went away
        except Exception:
            log.exception("view request %s failed", path)
            self._send(HTTPStatus.INTERNAL_SERVER_ERROR, b"500 Internal Server Error\n", _TEXT)

    do_HEAD = do_GET  # _send leaves the body out

    def _refuse(self) -> None:
        self.send_error(HTTPStatus.NOT_IMPLEMENTED)

    do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_TRACE = do_CONNECT = _refuse

    def _send(self, status: HTTPStatus, body: bytes, kind: str, *, cache: bool = False, allow: str = "") -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        # The page and frames change with every run; the assets only with the pinned wheel.
        self.send_header("Cache-Control", "max-age=86400, immutable" if cache else "no-store")
        if allow:
            self.send_header("Allow", allow)
        if self.close_connection:
            self.send_header("Connection", "close")
        self.end_headers()
        if getattr(self, "command", None) != "HEAD":  # unset when the request line could not be read
            self.wfile.write(body)
            self.view.sent[getattr(self, "path", "").split("?", 1)[0]] += len(body)

    def _stream(self) -> None:
        """Server-Sent Events: the run so far, then each new frame, until the browser leaves."""
        history, client = self.view.subscribe()
        try:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.send_header("Connection", "close")
            self.end_headers()
            while True:
                self._write(b"".join(_event(frame) for frame in history) + b"event: caught-up\ndata: {}\n\n")
                if not self.view.live:
                    self._write(b"event: end\ndata: {}\n\n")
                    return
                if not self._follow(client):
                    return
                self.view.unsubscribe(client)  # it fell behind: the page starts again from the history
                history, client = self.view.subscribe()
                self._write(b"event: reset\ndata: {}\n\n")
        finally:
            self.view.unsubscribe(client)
            self.close_connection = True

    def _follow(self, client: queue.Queue[Any]) -> bool:
        """Send each new frame until the run ends (False) or the browser fell behind (True)."""
        while True:
            try:
                batch = [client.get(timeout=15.0)]
            except queue.Empty:
                self._write(b": keep-alive\n\n")  # tells a dead connection apart
                continue
            while len(batch) < 200:  # a burst goes out in one write
                try:
                    batch.append(client.get_nowait())
                except queue.Empty:
                    break
            marker = next((item for item in batch if item is _CLOSED or item is _RESYNC), None)
            frames = batch[:batch.index(marker)] if marker is not None else batch  # none after a marker:
            if frames:  # after _RESYNC they follow frames this browser will never get
                self._write(b"".join(_event(frame) for frame in frames))
            if marker is _CLOSED:
                self._write(b"event: end\ndata: {}\n\n")
                return False
            if marker is _RESYNC:
                return True

    def _write(self, data: bytes) -> None:
        self.wfile.write(data)
        self.wfile.flush()
        self.view.sent["/events"] += len(data)


def _event(frame: Frame) -> bytes:
    return b"data: " + encode(frame).encode() + b"\n\n"
