"""The participant view's HTTP server: loopback only, one secret token per session, Server-Sent Events.

Routes (under ``/v/<token>/``, and the coordinator's under ``/c/<coordinator token>/``; anything else is
refused and logged)::

    GET  /v/<token>/              the page (index.html, view.js, view.css ship inside the package)
    GET  /c/<ctoken>/             the coordinator's read-only page (coordinator.html/.js/.css); any other
    GET  /c/<ctoken>/state        method there answers 405; state: the board's snapshot as JSON
    GET  /v/<token>/stream?client=ID   Server-Sent Events: hello, screen, frame, key, surface, tick, role
    POST /v/<token>/input         a participant's input {client, kind, ...} (JSON)
    POST /v/<token>/ack           frames and screens drawn {client, frames: [[seq, t]], screens: [[v, t]]}
    POST /v/<token>/sync          clock sync: returns the server's perf_counter

Every request must name this server by a loopback ``Host`` (defeats DNS rebinding), carry the token, and,
when the browser says where it comes from (``Origin``, ``Sec-Fetch-Site``), come from the page itself.
POSTs must be JSON from the page's own origin. Refusals answer 403 and are logged.

Each stream is served by its own thread that polls the hub every :data:`POLL_S` and sends the newest frame
at most :data:`~studyctl.view.hub.FRAME_HZ` times a second: the trial loop never waits for a browser, and a
slow browser only ever gets the newest frame, never a backlog.
"""

from __future__ import annotations

import hmac
import json
import math
import secrets
import select
import socket
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from studyctl.errors import UsageError, ValueTypeError
from studyctl.inputs import loads_json
from studyctl.view.board import CoordinatorBoard
from studyctl.view.hub import FRAME_HZ, ViewHub

POLL_S = 0.004
TICK_INTERVAL_S = 0.1
KEEPALIVE_S = 2.0
MAX_BODY = 64 * 1024
STATIC = {
    "": ("index.html", "text/html; charset=utf-8"),
    "view.js": ("view.js", "text/javascript; charset=utf-8"),
    "view.css": ("view.css", "text/css; charset=utf-8"),
}
COORD_STATIC = {
    "": ("coordinator.html", "text/html; charset=utf-8"),
    "coordinator.js": ("coordinator.js", "text/javascript; charset=utf-8"),
    "coordinator.css": ("coordinator.css", "text/css; charset=utf-8"),
}
SECURITY_HEADERS = {
    "Cache-Control": "no-store",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",  # the token is in the URL: never send it elsewhere
    "X-Frame-Options": "DENY",
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
    "img-src 'self' data:; frame-ancestors 'none'; base-uri 'none'; form-action 'none'",
}
LOOPBACK = ("127.0.0.1", "localhost", "[::1]")


def _static(name: str) -> bytes:
    return resources.files("studyctl.view").joinpath("static", name).read_bytes()


def _json_bytes(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False, default=_default).encode("utf-8")


def _default(value: Any) -> Any:
    if hasattr(value, "item"):
        return value.item()
    if isinstance(value, (tuple, set)):
        return list(value)
    raise ValueTypeError(f"not JSON serialisable: {type(value).__name__}")


def _clean(obj: Any) -> Any:
    """NaN and infinities become null (JSON has neither)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj


def sse(event: str, data: Any) -> bytes:
    return b"event: " + event.encode() + b"\ndata: " + _json_bytes(_clean(data)) + b"\n\n"


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    view: ViewServer


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"
    server_version = "studyctl-view"
    sys_version = ""
    area = "v"

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base class's name
        return None  # requests are not logged one by one; refusals are (see ViewHub.refuse)

    # -- checks ----------------------------------------------------------------------------------------
    def _route(self) -> str | None:
        """The path after ``/v/<token>/`` when the request passes every check, else None (refused)."""
        view = self.server.view
        parts = urlsplit(self.path)
        host = self.headers.get("Host", "")
        peer = self.client_address[0] if self.client_address else ""
        detail = {"method": self.command, "path": view.redact(parts.path), "host": host[:100], "peer": peer,
                  "origin": (self.headers.get("Origin") or "")[:100]}
        if host not in view.allowed_hosts:
            return self._refuse("host", detail)
        if parts.path == "/favicon.ico" and self.command == "GET":  # asked by browsers on their own
            self._send(HTTPStatus.NOT_FOUND, b"", "text/plain; charset=utf-8")
            return None
        # /v/<token>/ is the participant's page, /c/<coordinator token>/ the coordinator's (read-only)
        area = parts.path[1:2]
        if parts.path[2:3] != "/" or area not in ("v", "c") or (area == "c" and view.board is None):
            return self._refuse("no_token", detail)
        token, _, rest = parts.path[3:].partition("/")
        secret = view.token if area == "v" else view.coord_token
        if not hmac.compare_digest(token.encode(), secret.encode()):
            return self._refuse("wrong_token", detail)
        self.area = area
        origin = self.headers.get("Origin")
        if origin is not None and origin not in view.allowed_origins:
            return self._refuse("origin", detail)
        site = self.headers.get("Sec-Fetch-Site")
        if site is not None and site not in ("same-origin", "none"):
            return self._refuse("cross_site", detail)
        if area == "c" and self.command not in ("GET", "HEAD"):
            self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"the coordinator page is read-only\n",
                       "text/plain; charset=utf-8")
            return None
        if self.command == "POST":
            if origin is None:
                return self._refuse("origin_missing", detail)
            if not (self.headers.get("Content-Type") or "").startswith("application/json"):
                return self._refuse("content_type", detail)
        return rest

    def _refuse(self, reason: str, detail: dict[str, Any]) -> None:
        self.server.view.hub.refuse(reason, detail)
        self._send(HTTPStatus.FORBIDDEN, b"refused\n", "text/plain; charset=utf-8")
        return None

    def _send(self, status: int, body: bytes, ctype: str) -> None:
        self.send_response(status)
        if self.close_connection:
            self.send_header("Connection", "close")
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        for k, v in SECURITY_HEADERS.items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    # -- methods ------------------------------------------------------------------------------------------
    def do_GET(self) -> None:  # noqa: N802 - the base class's name
        rest = self._route()
        if rest is None:
            return
        if self.area == "c":
            self._coordinator(rest)
        elif rest in STATIC:
            name, ctype = STATIC[rest]
            self._send(HTTPStatus.OK, _static(name), ctype)
        elif rest == "stream":
            self._stream()
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")

    def _coordinator(self, rest: str) -> None:
        # one request per connection: a kept-alive poll would outlive the server's stop and never see the end
        self.close_connection = True
        if self.server.view.stopping:
            self._send(HTTPStatus.GONE, b"the session's view has closed\n", "text/plain; charset=utf-8")
        elif rest in COORD_STATIC:
            name, ctype = COORD_STATIC[rest]
            self._send(HTTPStatus.OK, _static(name), ctype)
        elif rest == "state":
            board = self.server.view.board
            self._send(HTTPStatus.OK, _json_bytes(_clean(board.snapshot())), "application/json")
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")

    def do_POST(self) -> None:  # noqa: N802
        rest = self._route()
        if rest is None:
            return
        try:
            length = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            length = -1
        if not 0 <= length <= MAX_BODY:
            self._send(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, b"too large\n", "text/plain; charset=utf-8")
            return
        try:
            body = loads_json(self.rfile.read(length) or b"{}")
            if not isinstance(body, dict):
                raise ValueError("not an object")
        except ValueError:  # also too deep (inputs.loads_json) and not UTF-8
            self._send(HTTPStatus.BAD_REQUEST, _json_bytes({"ok": False, "error": "bad JSON"}), "application/json")
            return
        hub = self.server.view.hub
        client = str(body.get("client", ""))[:64]
        if rest == "sync":
            status, reply = 200, {"ok": True, "s": hub.clock()}
        elif rest == "input":
            status, reply = hub.submit(client, body)
        elif rest == "ack":
            frames = body.get("frames") if isinstance(body.get("frames"), list) else []
            screens = body.get("screens") if isinstance(body.get("screens"), list) else []
            rtt = body.get("rtt_ms")
            if isinstance(rtt, (int, float)) and math.isfinite(rtt) and rtt >= 0:
                hub.sync_rtt_ms[client] = float(rtt)
            status, reply = 200, {"ok": True, "n": hub.acknowledge(client, frames, screens)}
        else:
            status, reply = 404, {"ok": False, "error": "not found"}
        self._send(status, _json_bytes(reply), "application/json")

    def do_HEAD(self) -> None:  # noqa: N802
        self.do_GET()

    def _other(self) -> None:
        if self._route() is not None:
            self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"method not allowed\n", "text/plain; charset=utf-8")

    do_PUT = do_DELETE = do_OPTIONS = do_PATCH = _other  # noqa: N815 - CORS preflights are refused too

    # -- the event stream -----------------------------------------------------------------------------
    def _stream(self) -> None:
        view = self.server.view
        hub = view.hub
        query = parse_qs(urlsplit(self.path).query)
        client = (query.get("client") or [""])[0][:64] or secrets.token_hex(8)
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Connection", "close")
        for k, v in SECURITY_HEADERS.items():
            self.send_header(k, v)
        self.end_headers()
        self.close_connection = True
        role = hub.connect(client, self.headers.get("User-Agent", ""))
        try:
            self._pump(hub, client, role)
        except (BrokenPipeError, ConnectionResetError, ConnectionAbortedError, TimeoutError, OSError):
            pass
        finally:
            hub.disconnect(client)

    def _peer_closed(self) -> bool:
        return _peer_closed(self.connection)

    def _pump(self, hub: ViewHub, client: str, role: str) -> None:
        write = self.wfile.write
        write(b"retry: 500\n\n" + sse("hello", {"client": client, "role": role, "server_time": hub.clock(),
                                                 "frame_hz": FRAME_HZ}))
        sent_screen = 0
        sent_seq = -1
        sent_key = 0
        sent_surface = 0
        sent_tick: tuple[float, float] | None = None
        last_frame = last_tick = last_role_check = 0.0
        last_write = time.monotonic()
        min_gap = 1.0 / FRAME_HZ - POLL_S / 2
        while not hub.closed and not self.server.view.stopping:
            now = hub.clock()
            out: list[bytes] = []
            sent_now = False
            if now - last_role_check > 0.25:
                last_role_check = now
                if self._peer_closed():
                    return
                hub.maintain()
                new_role = hub.role(client)
                if new_role != role:
                    role = new_role
                    out.append(sse("role", {"role": role}))
            if hub.screen_version != sent_screen:
                with hub.lock:
                    sent_screen, screen = hub.screen_version, dict(hub.screen)
                out.append(sse("screen", {"version": sent_screen, **screen}))
            state = hub.latest
            if state is not None and state.seq != sent_seq and now - last_frame >= min_gap:
                msg, _ = hub.encoded(state)
                key_id = msg.get("key")
                if key_id is not None and key_id != sent_key:
                    key = hub.codec.key_message
                    if key is not None and key["key"] == key_id:
                        out.append(sse("key", key))
                        sent_key = key_id
                surface_id = msg.get("surface")
                if surface_id is not None and surface_id != sent_surface and hub.surface_msg is not None:
                    out.append(sse("surface", hub.surface_msg))
                    sent_surface = surface_id
                out.append(sse("frame", msg))
                sent_seq, last_frame = state.seq, now
                sent_now = True
            tick = hub.tick
            if tick is not None and tick is not sent_tick and now - last_tick >= TICK_INTERVAL_S:
                out.append(sse("tick", {"t": tick[0], "ts": tick[1]}))
                sent_tick, last_tick = tick, now
            mono = time.monotonic()
            if out:
                write(b"".join(out))
                last_write = mono
            elif mono - last_write > KEEPALIVE_S:
                write(b": keep-alive\n\n")  # lets a dead connection fail and frees its thread
                last_write = mono
            # After a frame nothing new may go out for a display period: sleep through it (fewer wake-ups,
            # fewer GIL hand-overs from the loop); otherwise look again soon, so a scan goes out at once.
            time.sleep(max(POLL_S, min_gap - POLL_S / 2) if sent_now else POLL_S)
        write(sse("screen", {"version": hub.screen_version + 1, "screen": "ended"}))


def _peer_closed(sock: socket.socket) -> bool:
    """True when the browser has closed the stream (it never sends anything on it, so readable = gone)."""
    try:
        if not select.select([sock], [], [], 0)[0]:
            return False
        return sock.recv(1, socket.MSG_PEEK) == b""
    except (OSError, ValueError):
        return True


class ViewServer:
    """The HTTP server of one participant view, in a background thread.

    Parameters
    ----------
    hub
        The view's shared state.
    host
        Interface to bind; loopback only (``127.0.0.1`` by default, ``::1`` and ``localhost`` allowed).
    port
        0 picks a free port.
    token
        The session's secret (default: 128 random bits, URL-safe).
    """

    def __init__(self, hub: ViewHub, *, host: str = "127.0.0.1", port: int = 0, token: str | None = None,
                 board: CoordinatorBoard | None = None) -> None:
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise UsageError(f"participant view host {host!r}: the view is served on this machine only; "
                             "use 127.0.0.1 (the default), localhost or ::1")
        if token is not None and (len(token) < 16 or not token.replace("-", "").replace("_", "").isalnum()):
            raise UsageError("participant view token: use at least 16 URL-safe characters (letters, digits, - _)")
        self.hub = hub
        self.host = host
        self.token = token or secrets.token_urlsafe(16)
        # the coordinator's page has a secret of its own: the participant's screen never learns its address
        self.board = board
        self.coord_token = secrets.token_urlsafe(16)
        self.stopping = False
        bind = "127.0.0.1" if host == "localhost" else host
        try:
            if bind == "::1":

                class _V6(_Server):
                    address_family = socket.AF_INET6

                self._httpd: _Server = _V6((bind, port), _Handler)
            else:
                self._httpd = _Server((bind, port), _Handler)
        except OSError as exc:
            raise UsageError(f"participant view: cannot listen on {host}:{port} ({exc.strerror or exc}); "
                             "choose another port or 0 for a free one") from None
        self._httpd.view = self
        self.port = int(self._httpd.server_address[1])
        self.allowed_hosts = {f"{h}:{self.port}" for h in LOOPBACK}
        self.allowed_origins = {f"http://{h}" for h in self.allowed_hosts}
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="studyctl-view", daemon=True)

    @property
    def url(self) -> str:
        host = "[::1]" if self.host == "::1" else self.host
        return f"http://{host}:{self.port}/v/{self.token}/"

    @property
    def coordinator_url(self) -> str | None:
        """The coordinator page's address (None without a board)."""
        if self.board is None:
            return None
        return f"{self.url.rsplit('/v/', 1)[0]}/c/{self.coord_token}/"

    def redact(self, path: str) -> str:
        """A path for the log with any token cut to its first 4 characters (never log a secret)."""
        if path.startswith(("/v/", "/c/")):
            token, _, rest = path[3:].partition("/")
            return f"{path[:3]}{token[:4]}…/{rest}"
        return path[:200]

    def start(self) -> ViewServer:
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """Tell streams to end (browsers show "ended"), stop serving and close the socket."""
        if self.stopping:
            return
        self.stopping = True
        if self._thread.is_alive():
            time.sleep(min(0.05, timeout_s))  # let stream threads send their last message
            self._httpd.shutdown()
            self._thread.join(timeout_s)
        self._httpd.server_close()
