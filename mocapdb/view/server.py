"""The viewer's web server: the standard library's threading HTTP server on 127.0.0.1, in a thread.

Routes (``data_specs/viewer.md``): ``/`` the page; ``/static/...`` its script; ``/vendor/three/...`` three.js;
``/api/take`` the take's description; ``/api/frames?from=P&count=N`` the frames at timeline
positions P..P+N; ``/video/N.jpg`` video frame N; ``/files/NAME`` a file the run wrote (only those
the description lists); ``/api/live`` the live stream as server-sent events. Requests naming
another host than the loopback (a page elsewhere rebinding its name to 127.0.0.1) are refused.
"""
from __future__ import annotations

import json
import logging
import sys
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

from mocapdb.view.live import LiveFeed
from mocapdb.view.take import TakeView

LOG = logging.getLogger(__name__)
STATIC = Path(__file__).resolve().parent / "static"  # the page and its script
VENDOR = Path(__file__).resolve().parent / "vendor"  # third-party code served as is: three.js
HOST = "127.0.0.1"
TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css",
         ".json": "application/json", ".jsonl": "application/jsonl", ".png": "image/png", ".jpg": "image/jpeg"}
TEXT = "text/plain; charset=utf-8"   # BVH, TRC, CSV, TOML, LICENSE
KEEPALIVE_S = 1.0     # an idle event stream sends a comment this often (a closed page is noticed)
SEND_TIMEOUT_S = 10.0  # a page that takes nothing for this long is dropped


class ViewServer:
    """The page of a recorded ``take`` or of a live ``feed``, served on 127.0.0.1:``port`` (0: a free
    port) from a daemon thread until :meth:`close`; ``folder`` holds the files the page links to."""

    def __init__(self, port: int, take: TakeView | None = None, feed: LiveFeed | None = None,
                 folder: Path | None = None) -> None:
        self.take, self.feed, self.folder = take, feed, folder
        handler = type("Handler", (_Handler,), {"view": self})
        self.httpd = _Server((HOST, port), handler)
        self.port = int(self.httpd.server_address[1])
        self.closing = threading.Event()
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="mocapdb-view", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}/"

    def meta(self) -> dict:
        if self.take is not None:
            return self.take.meta
        assert self.feed is not None, "a server shows a take or a feed"
        return self.feed.meta()

    def close(self) -> None:
        """Stop serving: event streams end, the port is released."""
        self.closing.set()
        self.httpd.shutdown()
        self.httpd.server_close()
        self._thread.join()


class _Server(ThreadingHTTPServer):
    daemon_threads = True

    def handle_error(self, request, client_address) -> None:
        """A page that went away mid-answer (a frame no longer wanted) is no error worth a traceback."""
        if isinstance(sys.exc_info()[1], (ConnectionError, TimeoutError)):
            LOG.debug("view: %s went away", client_address)
        else:
            LOG.exception("view: a request from %s failed", client_address)


class _Handler(BaseHTTPRequestHandler):
    view: ViewServer
    protocol_version = "HTTP/1.1"
    server_version = "mocapdb-view"

    def log_message(self, format: str, *args) -> None:   # noqa: A002 (the base class's name)
        LOG.debug("view: " + format, *args)

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        host = (self.headers.get("Host") or "").rsplit(":", 1)[0]
        if host not in (HOST, "localhost"):
            return self._error(HTTPStatus.FORBIDDEN, "only the loopback address is served")
        url = urlsplit(self.path)
        path = unquote(url.path)
        take = self.view.take
        if path == "/":
            return self._file(STATIC / "index.html")
        if path.startswith("/static/"):
            return self._file(STATIC / path.removeprefix("/static/"), STATIC)
        if path.startswith("/vendor/"):
            return self._file(VENDOR / path.removeprefix("/vendor/"), VENDOR)
        if path == "/api/take":
            return self._send(json.dumps(self.view.meta()).encode(), TYPES[".json"])
        if path == "/api/frames" and take is not None:
            query = parse_qs(url.query)
            try:
                start, count = int(query["from"][0]), int(query["count"][0])
            except (KeyError, ValueError):
                return self._error(HTTPStatus.BAD_REQUEST, "expected /api/frames?from=P&count=N")
            return self._send(json.dumps(take.frames_json(start, count)).encode(), TYPES[".json"])
        if path.startswith("/video/") and path.endswith(".jpg") and take is not None:
            index = path.removeprefix("/video/").removesuffix(".jpg")
            data = take.video_jpeg(int(index)) if index.isdigit() else None
            return self._send(data, TYPES[".jpg"]) if data else self._error(HTTPStatus.NOT_FOUND, "no such frame")
        if path.startswith("/files/") and self.view.folder is not None:
            name = path.removeprefix("/files/")
            if name in self.view.meta().get("files", []):
                return self._file(self.view.folder / name, self.view.folder)
        if path == "/api/live" and self.view.feed is not None:
            return self._events(self.view.feed)
        return self._error(HTTPStatus.NOT_FOUND, "not found")

    def _send(self, data: bytes, content_type: str, status: HTTPStatus = HTTPStatus.OK) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-cache")
        self.end_headers()
        self.wfile.write(data)

    def _error(self, status: HTTPStatus, text: str) -> None:
        self._send(text.encode(), TEXT, status)

    def _file(self, path: Path, root: Path | None = None) -> None:
        """A file, when it lies inside ``root`` (no ``..`` out of it)."""
        path = path.resolve()
        if (root is not None and root.resolve() not in path.parents) or not path.is_file():
            return self._error(HTTPStatus.NOT_FOUND, "not found")
        self._send(path.read_bytes(), TYPES.get(path.suffix.lower(), TEXT))

    def _events(self, feed: LiveFeed) -> None:
        """The live stream as server-sent events until it ends, the page goes or the server closes."""
        page = feed.subscribe()
        if page is None:
            return self._error(HTTPStatus.SERVICE_UNAVAILABLE, "too many pages watch this stream")
        self.close_connection = True
        self.connection.settimeout(SEND_TIMEOUT_S)
        try:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-cache")
            self.send_header("Connection", "close")
            self.end_headers()
            while not self.view.closing.is_set():
                item = page.take(KEEPALIVE_S)
                if isinstance(item, str):   # live.END: the stream ended
                    self.wfile.write(b"event: end\ndata: {}\n\n")
                    break
                text = ": idle\n\n" if item is None else f"data: {feed.event(item, page)}\n\n"
                self.wfile.write(text.encode())
                self.wfile.flush()
        except OSError:   # the page went (broken pipe, reset, timed out)
            pass
        finally:
            feed.unsubscribe(page)
