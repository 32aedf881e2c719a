"""The review page's web server, run by the human-feedback node (`./run_nodes.sh --page PORT`).

Standard library only (http.server): the page (web/review.html, plain JavaScript, no build step),
a snapshot of what is under review (GET /api/state), live updates as server-sent events (GET
/api/events: plan, label_request, report, status, reviewer, progress; a page that connects, or
reconnects after a node restart, gets what is shown now first, "no label request" included), the
review history from the ledger (GET
/api/history, /api/history?review=ID; the node asks the planner, which owns the ledger), and the person's
answers (POST /api/feedback, /api/labels, /api/manual, /api/answer: a plan's question about the
manual answered with a choice number), which the node signs and publishes, the
next episode or this one again (POST /api/episode), and who is reviewing (GET and POST
/api/reviewer: the node signs as that person from then on; every open page hears it). It
binds to localhost unless told otherwise. A POST must be JSON and, when the browser names an
origin, come from this page: a web page on another origin cannot answer a plan through the
reviewer's browser.
"""

from __future__ import annotations

import json
import queue
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from lwm_models.errors import LwmError
from lwm_models.messages import plain_reason

PAGE = Path(__file__).with_name("web") / "review.html"
HEARTBEAT_S = 10.0  # a comment line on idle event streams, so a closed tab is noticed
RETRY_MS = 1000  # how soon a page whose stream broke (a node restart) connects again
MAX_BODY = 1 << 20


class Refused(ValueError):
    """The receiving node refused what the person sent; the message is its reason."""


class NoAnswer(ValueError):
    """Nothing answered what the person sent in time (it may still be taken)."""


def reply(ack: dict | None, who: str, waited: float) -> str:
    """The words a page shows for the receiving node's answer to what the person sent: its reason
    when taken; Refused with its reason, or NoAnswer when nothing came in `waited` seconds."""
    if ack is None:
        raise NoAnswer(f"sent, but {who} has not answered in {waited:.0f} s (is it running?)")
    if not ack["ok"]:
        raise Refused(ack["reason"])
    return ack["reason"]


class ReviewPage:
    """What the page shows and where its answers go. on_feedback, on_labels and on_manual take the
    body of a POST and return the receiving node's words (shown beside the control), or raise to
    refuse it (the page shows the reason); history(review_id or None) answers GET /api/history."""

    KINDS = ("plan", "label_request", "report", "status", "reviewer", "progress", "notice")
    # Sent to a (re)connecting page even when there is none: the page may still show a request that
    # ended while it was away (the node restarted, the planner moved on), and would keep asking the
    # person for labels nobody takes. A plan or report the node has not (yet) had is left as shown.
    ALWAYS_SENT = ("label_request",)

    def __init__(
        self,
        host: str,
        port: int,
        on_feedback: Callable[[dict], str],
        on_manual: Callable[[dict], str],
        on_labels: Callable[[dict], str],
        history: Callable[[str | None], dict],
        on_episode: Callable[[dict], str] | None = None,
        on_reviewer: Callable[[dict], str] | None = None,
        on_answer: Callable[[dict], str] | None = None,
        reviewer: str = "",
        html: Path = PAGE,
        kinds: tuple[str, ...] | None = None,
    ) -> None:
        """html: the page served at /; kinds: what it shows (default KINDS; the fleet page its own)."""
        self.html = html
        self.kinds = kinds or self.KINDS
        self._state: dict[str, dict | None] = dict.fromkeys(self.kinds)
        self._streams: list[queue.SimpleQueue] = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self.on_feedback, self.on_manual, self.on_labels, self.history = on_feedback, on_manual, on_labels, history
        self.on_episode = on_episode or _no_episodes
        self.on_reviewer = on_reviewer or _fixed_reviewer
        self.on_answer = on_answer or _no_questions
        self.reviewer = reviewer  # whose key signs the answers (shown on the page); "": nobody yet
        self._state["reviewer"] = {"reviewer": reviewer}
        self.server = ThreadingHTTPServer((host, port), _handler(self))
        self.server.daemon_threads = True
        threading.Thread(target=self.server.serve_forever, name="review-page", daemon=True).start()

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}/"

    @property
    def closed(self) -> bool:
        return self._closed.is_set()

    def push(self, kind: str, payload: dict | None) -> None:
        """A new plan, label request, report or status: kept for new pages, sent to open ones.
        None withdraws what was shown (an answered label request)."""
        with self._lock:
            self._state[kind] = payload
            for stream in self._streams:
                stream.put((kind, payload))

    def set_reviewer(self, reviewer: str) -> None:
        self.reviewer = reviewer
        self.push("reviewer", {"reviewer": reviewer})

    def become(self, body: dict, signer) -> str:
        """The person said who they are (POST /api/reviewer): `signer` (lwm_nodes.trust.Signer)
        signs as them from now on and every open page hears it. Returns their reviewer id."""
        name = body.get("reviewer")
        if not isinstance(name, str) or not name.strip():
            raise ValueError("type your name: 1-64 letters, digits, '_', '.' or '-'")
        who = signer.become(name.strip())
        self.set_reviewer(who)
        return who

    def snapshot(self) -> dict[str, dict | None]:
        with self._lock:
            return dict(self._state)

    def subscribe(self) -> queue.SimpleQueue:
        """A queue of (kind, payload) for one open page, starting with what is shown now; None in
        it means the server is closing. Give it back with unsubscribe."""
        stream: queue.SimpleQueue = queue.SimpleQueue()
        with self._lock:
            for kind, payload in self._state.items():
                if payload is not None or (kind in self.ALWAYS_SENT and kind in self.kinds):
                    stream.put((kind, payload))
            self._streams.append(stream)
        return stream

    def unsubscribe(self, stream: queue.SimpleQueue) -> None:
        with self._lock:
            self._streams.remove(stream)

    def close(self) -> None:
        self._closed.set()
        with self._lock:
            for stream in self._streams:
                stream.put(None)
        self.server.shutdown()
        self.server.server_close()


def _no_episodes(body: dict) -> str:
    raise ValueError("this page cannot start episodes")


def _no_questions(body: dict) -> str:
    raise LwmError("this page takes no answers to questions")


def _fixed_reviewer(body: dict) -> str:
    raise ValueError("this page's reviewer is fixed")


def _handler(page: ReviewPage) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, fmt: str, *args) -> None:  # the node logs what matters
            pass

        def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
            url = urlsplit(self.path)
            if url.path == "/":
                self._send(HTTPStatus.OK, page.html.read_bytes(), "text/html; charset=utf-8")
            elif url.path == "/api/state":
                self._send(HTTPStatus.OK, json.dumps(page.snapshot()).encode(), "application/json")
            elif url.path == "/api/reviewer":
                self._send(HTTPStatus.OK, json.dumps({"reviewer": page.reviewer}).encode(), "application/json")
            elif url.path == "/api/events":
                self._events()
            elif url.path == "/api/history":
                review = parse_qs(url.query).get("review", [None])[0]
                try:
                    body = page.history(review)
                except Exception as exc:  # a ledger being written or damaged: say so, keep serving
                    return self._answer(HTTPStatus.INTERNAL_SERVER_ERROR, f"{type(exc).__name__}: {exc}")
                self._send(HTTPStatus.OK, json.dumps(body).encode(), "application/json")
            else:
                self._answer(HTTPStatus.NOT_FOUND, "not found")

        def do_POST(self) -> None:  # noqa: N802
            routes = {
                "/api/feedback": page.on_feedback,
                "/api/labels": page.on_labels,
                "/api/manual": page.on_manual,
                "/api/episode": page.on_episode,
                "/api/reviewer": page.on_reviewer,
                "/api/answer": page.on_answer,
            }
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
                said = handle(body)
            except Exception as exc:  # the person sees why, in words; the node keeps serving
                pending = isinstance(exc, NoAnswer)  # sent, but nobody answered yet
                status = HTTPStatus.ACCEPTED if pending else HTTPStatus.BAD_REQUEST
                return self._answer(status, plain_reason(exc))
            self._answer(HTTPStatus.OK, said or "taken")

        def _answer(self, status: HTTPStatus, words: str = "") -> None:
            if status == HTTPStatus.OK:
                body = {"ok": True, "answer": words}
            elif status == HTTPStatus.ACCEPTED:
                body = {"ok": True, "pending": True, "answer": words}
            else:
                body = {"ok": False, "error": words}
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
            stream = page.subscribe()
            try:
                # A restarted node is back in seconds: the browser's default wait (3 s in Chromium)
                # between attempts would add most of that again.
                self.wfile.write(f"retry: {RETRY_MS}\n\n".encode())
                self.wfile.flush()
                while not page.closed:
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
                page.unsubscribe(stream)
                self.close_connection = True

    return Handler


__all__ = ["NoAnswer", "Refused", "ReviewPage", "reply"]
