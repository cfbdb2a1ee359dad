"""The view's server, as a browser (or anything else) talks to it: what it does not serve gets a
one-line plain-text answer (404, 405, 400), a connection that is dropped or reset is no news on
stderr, a browser that stops reading never holds up the ticks, and one that fell behind starts
again from a key frame. Needs the page's assets (the ``browser`` marker), not Chromium."""

from __future__ import annotations

import io
import json
import queue
import socket
import struct
import threading
import time
import urllib.error
import urllib.request
from typing import Any

import pytest

from sm_bt.view.frames import Frame
from sm_bt.view.recording import fold
from sm_bt.view.server import CLIENT_QUEUE, ViewServer

pytestmark = pytest.mark.browser


def _address(server: ViewServer) -> tuple[str, int]:
    host, port = server.url.split("//")[1].rstrip("/").split(":")
    return host, int(port)


def _raw(server: ViewServer, request: bytes) -> bytes:
    """The whole answer to ``request`` sent as is (the server closes the connection after it)."""
    with socket.create_connection(_address(server), timeout=5.0) as connection:
        connection.sendall(request)
        answer = b""
        try:
            while chunk := connection.recv(65536):
                answer += chunk
        except ConnectionResetError:  # closed with our request unread (too long): the answer came first
            assert answer
    return answer


def _read_until(connection: socket.socket, marker: bytes) -> bytes:
    data = b""
    while marker not in data:
        chunk = connection.recv(65536)
        assert chunk, data[-300:]
        data += chunk
    return data


def _frames(count: int, padding: int = 0) -> list[Frame]:
    """A key frame, then deltas changing behaviour "b"'s feedback (made up, as a FrameMaker makes them)."""
    key: Frame = {"tick": 1, "time": 0.0, "status": "RUNNING", "key": True, "visited": ["a"], "blackboard": {},
                  "modes": [], "behaviours": {"a": {"id": "a", "name": "A", "status": "RUNNING", "children": ["b"],
                                                    "data": {}},
                                              "b": {"id": "b", "name": "B", "status": "RUNNING",
                                                    "data": {"Feedback": ""}}}}
    return [key] + [{"tick": tick, "time": tick / 10, "status": "RUNNING",
                     "changes": {"b": {"feedback": f"step {tick} " + "x" * padding}}} for tick in range(2, count + 1)]


def test_what_is_not_served_gets_a_short_plain_text_answer() -> None:
    server = ViewServer(port=0, frames=[])
    try:
        for path, method, code in (("nope", "GET", 404), ("assets/../view.js", "GET", 404),
                                   ("assets/secret.js", "GET", 404), ("", "POST", 405), ("events", "DELETE", 405),
                                   ("", "OPTIONS", 405), ("", "TRACE", 405), ("", "PUT", 405), ("", "PATCH", 405),
                                   ("", "BREW", 405)):
            request = urllib.request.Request(server.url + path, method=method, data=b"x" if method == "POST" else None)
            with pytest.raises(urllib.error.HTTPError) as answered:
                urllib.request.urlopen(request, timeout=5.0)
            body = answered.value.read()
            assert answered.value.code == code, (path, method)
            assert answered.value.headers["Content-Type"].startswith("text/plain"), (path, method)
            assert body.startswith(str(code).encode()) and body.count(b"\n") == 1 and b"<" not in body, body
            if code == 405:
                assert answered.value.headers["Allow"] == "GET, HEAD"
        with urllib.request.urlopen(server.url + "frames.json", timeout=5.0) as answer:
            assert answer.status == 200 and json.loads(answer.read()) == {"live": False, "frames": []}
        with urllib.request.urlopen(urllib.request.Request(server.url, method="HEAD"), timeout=5.0) as answer:
            assert answer.status == 200 and int(answer.headers["Content-Length"]) > 1000 and answer.read() == b""
    finally:
        server.close()


@pytest.mark.parametrize("request_line", [
    b"GARBAGE\r\n\r\n", b"GET\r\n\r\n", b"GET / HTTP/1.1 extra\r\n\r\n", b"GET / HTTP/x.y\r\n\r\n",
    b"GET / HTTP/1.1\r\nX: " + b"a" * 70_000 + b"\r\n\r\n",  # a header too long
    b"GET /" + b"a" * 70_000 + b" HTTP/1.1\r\n\r\n",  # a path too long
])
def test_a_malformed_request_gets_400_in_one_plain_line(request_line: bytes, capfd: pytest.CaptureFixture[str]) -> None:
    server = ViewServer(port=0, frames=[])
    try:
        answer = _raw(server, request_line)
    finally:
        server.close()
    head, _, body = answer.partition(b"\r\n\r\n")
    assert head.split(b" ")[1] in (b"400", b"414", b"431"), answer[:200]  # 414, 431: too long
    assert b"Content-Type: text/plain" in head and b"Connection: close" in head
    assert body.count(b"\n") == 1 and b"<" not in body, body
    assert "Traceback" not in capfd.readouterr().err


def _reset(connection: socket.socket) -> None:
    """Close with a TCP reset, as a browser dropping a connection may."""
    connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    connection.close()


def test_a_connection_reset_by_the_browser_is_no_news(capfd: pytest.CaptureFixture[str]) -> None:
    server = ViewServer(port=0)
    try:
        server.publish(_frames(1)[0])
        half = socket.create_connection(_address(server), timeout=5.0)  # reset while the server reads
        half.sendall(b"GET / HT")
        time.sleep(0.2)
        _reset(half)
        for _ in range(3):  # reset while the server writes the events stream
            stream = socket.create_connection(_address(server), timeout=5.0)
            stream.sendall(b"GET /events HTTP/1.1\r\nHost: x\r\n\r\n")
            _read_until(stream, b"caught-up")
            _reset(stream)
        for frame in _frames(400, padding=2000)[1:]:
            server.publish(frame)
        time.sleep(0.5)
        with urllib.request.urlopen(server.url + "view.js", timeout=5.0) as answer:
            assert answer.status == 200  # still serving
    finally:
        server.close()
    err = capfd.readouterr().err
    assert "Traceback" not in err and "ConnectionResetError" not in err and "BrokenPipe" not in err, err


def test_a_browser_that_stops_reading_never_holds_up_publishing() -> None:
    server = ViewServer(port=0)
    stalled = socket.create_connection(_address(server), timeout=5.0)
    try:
        stalled.sendall(b"GET /events HTTP/1.1\r\nHost: x\r\n\r\n")  # and never reads
        done = threading.Event()

        def publish() -> None:
            for frame in _frames(3000, padding=20_000):  # ~60 MB: far more than the socket buffers hold
                server.publish(frame)
            done.set()

        threading.Thread(target=publish, daemon=True).start()
        assert done.wait(60.0), "publish blocked on a browser that does not read"
    finally:
        stalled.close()
        server.close()


def _events(data: bytes) -> list[tuple[str, Any]]:
    """Server-Sent Events as (event name, data), frames parsed."""
    found = []
    for block in data.split(b"\n\n"):
        lines = dict(line.split(b": ", 1) for line in block.split(b"\n") if b": " in line)
        if b"data" in lines:
            name = lines.get(b"event", b"message").decode()
            found.append((name, json.loads(lines[b"data"]) if name == "message" else None))
    return found


def test_a_browser_that_fell_behind_starts_again_from_a_key_frame() -> None:
    frames = _frames(CLIENT_QUEUE * 3, padding=2000)
    server = ViewServer(port=0, history=CLIENT_QUEUE)
    slow = socket.create_connection(_address(server), timeout=10.0)
    slow.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 65536)
    try:
        server.publish(frames[0])
        slow.sendall(b"GET /events HTTP/1.1\r\nHost: x\r\n\r\n")
        time.sleep(0.3)
        for frame in frames[1:]:  # far more than the socket holds: the browser's queue overflows
            server.publish(frame)
        history = server.history()
        assert len(history) == CLIENT_QUEUE and history[0]["key"], "the oldest folded into a key frame"
        whole = frames[0]
        for frame in frames[1:]:
            whole = fold(whole, frame)
        again = history[0]
        for frame in history[1:]:
            again = fold(again, frame)
        assert again["behaviours"] == whole["behaviours"]
        chunks: list[bytes] = []
        slow.settimeout(2.0)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:  # everything was published: read until nothing more comes
            try:
                chunks.append(slow.recv(1 << 20))
            except TimeoutError:
                break
        data = b"".join(chunks)
    finally:
        slow.close()
        server.close()
    received = _events(data.split(b"\r\n\r\n", 1)[1].rsplit(b"\n\n", 1)[0])  # whole events only
    names = [name for name, _ in received]
    assert "reset" in names, "the queue overflowed: the browser is told to start again"
    # What the page relies on: after each reset a key frame, then every frame in order (no gap).
    segments: list[list[Frame]] = []
    for name, frame in received[names.index("reset"):]:
        if name == "reset":
            segments.append([])
        elif name == "message":
            segments[-1].append(frame)
    for segment in segments:
        assert segment[0]["key"], "a reset is followed by the history, from its key frame"
        ticks = [frame["tick"] for frame in segment]
        assert ticks == list(range(ticks[0], ticks[0] + len(ticks))), "no frame lost after a reset"
    assert segments[-1][-1]["tick"] == frames[-1]["tick"], "then the frames that came since, to the last"


def test_after_falling_behind_no_frame_is_sent_before_the_history() -> None:
    """The frames queued behind the marker are newer than what the browser has: sent before the
    history they would be applied to the wrong state (the race of the test above, made certain)."""
    from sm_bt.view import server as module

    first, second = _frames(3)[1:]
    queued: queue.Queue[Any] = queue.Queue()
    for item in (first, module._RESYNC, second):
        queued.put(item)
    handler = module._Handler.__new__(module._Handler)
    handler.wfile = io.BytesIO()
    handler.view = ViewServer(port=0, frames=[])
    try:
        assert handler._follow(queued) is True  # start again from the history
    finally:
        handler.view.close()
    sent = [frame["tick"] for name, frame in _events(handler.wfile.getvalue()) if name == "message"]
    assert sent == [first["tick"]]
