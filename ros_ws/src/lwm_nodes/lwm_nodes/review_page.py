"""The review page's web server, run by the human-feedback node (`./run_nodes.sh --page PORT`).

Standard library only (http.server): the page (web/review.html, plain JavaScript, no build step),
a snapshot of what is under review (GET /api/state), live updates as server-sent events (GET
/api/events: plan, report, status), and the person's answers (POST /api/feedback, /api/manual),
which the node signs and publishes. It binds to localhost unless told otherwise. A POST must be
JSON and, when the browser names an origin, come from this page: a web page on another origin
cannot answer a plan through the reviewer's browser.
"""

from __future__ import annotations

import json
import queue
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

PAGE = Path(__file__).with_name("web") / "review.html"
HEARTBEAT_S = 10.0  # a comment line on idle event streams, so a closed tab is noticed
MAX_BODY = 1 << 20


class ReviewPage:
    def __init__(
        self,
        host: str,
        port: int,
        on_feedback: Callable[[dict], None],
        on_manual: Callable[[list[str]], None],
    ) -> None:
        self.state: dict[str, dict | None] = {"plan": None, "report": None, "status": None}
        self._streams: list[queue.SimpleQueue] = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self.on_feedback, self.on_manual = on_feedback, on_manual
        self.server = ThreadingHTTPServer((host, port), _handler(self))
        self.server.daemon_threads = True
        threading.Thread(target=self.server.serve_forever, name="review-page", daemon=True).start()

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}/"

    def push(self, kind: str, payload: dict) -> None:
        """A new plan, report or status: kept for new pages, sent to open ones."""
        with self._lock:
            self.state[kind] = payload
            for stream in self._streams:
                stream.put((kind, payload))

    def close(self) -> None:
        self._closed.set()
        with self._lock:
            for stream in self._streams:
                stream.put(None)
        self.server.shutdown()
        self.server.server_close()

    def _stream(self) -> queue.SimpleQueue:
        stream: queue.SimpleQueue = queue.SimpleQueue()
        with self._lock:
            for kind, payload in self.state.items():  # what is under review now, first
                if payload is not None:
                    stream.put((kind, payload))
            self._streams.append(stream)
        return stream

    def _unstream(self, stream: queue.SimpleQueue) -> None:
        with self._lock:
            self._streams.remove(stream)


def _handler(page: ReviewPage) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, fmt: str, *args) -> None:  # the node logs what matters
            pass

        def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
            if self.path == "/":
                self._send(HTTPStatus.OK, PAGE.read_bytes(), "text/html; charset=utf-8")
            elif self.path == "/api/state":
                with page._lock:
                    body = json.dumps(page.state)
                self._send(HTTPStatus.OK, body.encode(), "application/json")
            elif self.path == "/api/events":
                self._events()
            else:
                self._send(HTTPStatus.NOT_FOUND, b'{"ok": false, "error": "not found"}', "application/json")

        def do_POST(self) -> None:  # noqa: N802
            routes = {"/api/feedback": page.on_feedback, "/api/manual": lambda b: page.on_manual(b["descriptions"])}
            handle = routes.get(self.path)
            origin = self.headers.get("Origin")
            host = self.headers.get("Host", "")
            if handle is None:
                return self._answer(HTTPStatus.NOT_FOUND, "not found")
            if origin is not None and origin.split("://", 1)[-1] != host:
                return self._answer(HTTPStatus.FORBIDDEN, f"origin {origin} is not this page")
            if not self.headers.get("Content-Type", "").startswith("application/json"):
                return self._answer(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "send JSON")
            length = int(self.headers.get("Content-Length") or 0)
            if length > MAX_BODY:
                return self._answer(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "too large")
            try:
                body = json.loads(self.rfile.read(length) or b"null")
                if not isinstance(body, dict):
                    raise ValueError("send a JSON object")
                handle(body)
            except Exception as exc:  # the person sees why; the node keeps serving
                return self._answer(HTTPStatus.BAD_REQUEST, f"{type(exc).__name__}: {exc}")
            self._answer(HTTPStatus.OK)

        def _answer(self, status: HTTPStatus, error: str = "") -> None:
            body = {"ok": True} if status == HTTPStatus.OK else {"ok": False, "error": error}
            self._send(status, json.dumps(body).encode(), "application/json")

        def _send(self, status: HTTPStatus, body: bytes, kind: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def _events(self) -> None:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            stream = page._stream()
            try:
                while not page._closed.is_set():
                    try:
                        item = stream.get(timeout=HEARTBEAT_S)
                    except queue.Empty:
                        self.wfile.write(b": still here\n\n")
                        self.wfile.flush()
                        continue
                    if item is None:
                        break
                    kind, payload = item
                    self.wfile.write(f"event: {kind}\ndata: {json.dumps(payload)}\n\n".encode())
                    self.wfile.flush()
            except OSError:  # the tab was closed
                pass
            finally:
                page._unstream(stream)
                self.close_connection = True

    return Handler


__all__ = ["ReviewPage"]
