"""The participant view: what the participant sees during a session, in a browser on a second screen.

Example (the CLI's ``studyctl run CODE --view`` does this)::

    from studyctl.engine import run_session
    from studyctl.view import ParticipantView

    with ParticipantView() as view:
        print("open on the participant's screen:", view.url)
        run_session(store, "NDL-4KX7Q", virtual=False, frontend=view.attach)

The coordinator's terminal stays in control (pause, abort, mark invalid, manual outcomes); the view shows
instructions, countdowns, the condition's visual feedback and the participant's prompts, and takes the
participant's answers and trial requests through the engine's own paths (see :mod:`studyctl.view.frontend`).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from studyctl.view.board import CoordinatorBoard
from studyctl.view.frontend import ViewParticipant, ViewUI
from studyctl.view.hub import FrameState, ViewHub
from studyctl.view.server import ViewServer

# GIL switch interval while a view serves (see ParticipantView.start).
SWITCH_INTERVAL_S = 0.0005

__all__ = ["CoordinatorBoard", "FrameState", "ParticipantView", "ViewHub", "ViewParticipant", "ViewServer", "ViewUI",
           "open_view"]


class ParticipantView:
    """One session's participant view: a loopback server with a secret URL, and the session hooks.

    Parameters
    ----------
    host, port, token
        Where to listen (loopback only; port 0 picks a free one) and the URL's secret (default: random).
    """

    def __init__(self, *, host: str = "127.0.0.1", port: int = 0, token: str | None = None) -> None:
        self.hub = ViewHub()
        self.board = CoordinatorBoard(self.hub, clock=self.hub.clock)
        self.server = ViewServer(self.hub, host=host, port=port, token=token, board=self.board)
        self.ui: ViewUI | None = None
        self.participant: ViewParticipant | None = None
        self._switch: float | None = None

    @property
    def url(self) -> str:
        """The address to open on the participant's screen (contains the session's token)."""
        return self.server.url

    @property
    def coordinator_url(self) -> str:
        """The coordinator's read-only page (a token of its own; never shown to the participant's screen)."""
        return str(self.server.coordinator_url)

    def start(self) -> ParticipantView:
        # The 1 kHz loop spin-waits its last half-millisecond for precise pacing and holds the GIL while it
        # does; the server threads then get the GIL only when they ask for a switch. At the default 5 ms
        # interval every GIL hand-over of a frame on its way to the browser would wait up to 5 ms.
        self._switch = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch, SWITCH_INTERVAL_S))
        self.server.start()
        return self

    def attach(self, participant: Any, ui: Any, recorder: Any = None) -> tuple[ViewParticipant, ViewUI]:
        """The engine's ``frontend`` hook: wrap the session's participant and UI (see :func:`run_session`)."""
        self.participant = ViewParticipant(participant, self.hub)
        self.ui = ViewUI(ui, self.hub, recorder, self.board)
        return self.participant, self.ui

    def close(self) -> None:
        """Show "session ended", stop the server and write what is still queued in the view's log."""
        self.hub.show("ended")
        self.hub.closed = True
        self.server.stop()
        if self._switch is not None:
            sys.setswitchinterval(self._switch)
            self._switch = None
        if self.ui is not None:
            try:
                self.ui.flush()
            except Exception:  # the session's store may already be closed; the session itself is recorded
                pass

    def __enter__(self) -> ParticipantView:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextmanager
def open_view(
    enabled: bool, *, announce: Callable[[str], None], port: int = 0
) -> Iterator[ParticipantView | None]:
    """The CLI's ``--view``: a started :class:`ParticipantView` whose URL is passed to ``announce``, or None
    when off."""
    if not enabled:
        yield None
        return
    with ParticipantView(port=port) as view:
        announce(f"Participant view: {view.url}")
        announce("  open it on the participant's screen, full screen (e.g. `chromium --kiosk URL`); "
                 "only this machine can reach it")
        announce(f"Coordinator page: {view.coordinator_url}")
        announce("  read-only, for the coordinator's screen: progress, condition, timers, loop and device status, "
                 "lease, notes")
        yield view
