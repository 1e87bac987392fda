"""A page's requests without a browser: the same HTTP the participant view's JavaScript sends."""

from __future__ import annotations

import http.client
import json
import socket
import threading
from typing import Any


def request(view, method: str, rest: str, body: Any = None, *, token: str | None = None, headers=None,
            origin: bool = True, path: str = "v") -> tuple[int, Any, dict[str, str]]:
    """``method`` ``/<path>/<token>/<rest>`` on the view's server (path ``v``: the participant's page, ``c``: the
    coordinator's); returns (status, JSON or text, headers)."""
    conn = http.client.HTTPConnection("127.0.0.1", view.server.port, timeout=10)
    hdrs = {"Host": f"127.0.0.1:{view.server.port}"}
    data = None
    if body is not None:
        data = json.dumps(body).encode()
        hdrs["Content-Type"] = "application/json"
    if origin and method == "POST":
        hdrs["Origin"] = f"http://127.0.0.1:{view.server.port}"
    hdrs.update(headers or {})
    conn.request(method, f"/{path}/{token or view.server.token}/{rest}", body=data, headers=hdrs)
    resp = conn.getresponse()
    raw = resp.read()
    conn.close()
    try:
        payload = json.loads(raw)
    except ValueError:
        payload = raw.decode("utf-8", "replace")
    return resp.status, payload, dict(resp.getheaders())


class Stream:
    """An open event stream (as EventSource keeps one), collecting events in a background thread."""

    def __init__(self, view, client: str) -> None:
        self.client = client
        self.events: list[tuple[str, Any]] = []
        self.conn = http.client.HTTPConnection("127.0.0.1", view.server.port, timeout=30)
        self.conn.request("GET", f"/v/{view.server.token}/stream?client={client}",
                          headers={"Host": f"127.0.0.1:{view.server.port}"})
        self.sock = self.conn.sock  # the response takes it over (Connection: close)
        self.resp = self.conn.getresponse()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        event = None
        try:
            for raw in self.resp:
                line = raw.decode().rstrip("\n")
                if line.startswith("event: "):
                    event = line[7:]
                elif line.startswith("data: ") and event:
                    self.events.append((event, json.loads(line[6:])))
                    event = None
        except (OSError, ValueError):
            pass

    def of(self, kind: str) -> list[Any]:
        return [data for k, data in list(self.events) if k == kind]

    def close(self) -> None:
        """Drop the connection at once, as a closing or reloading tab does."""
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
        self.conn.close()
        self.thread.join(5)
