"""The terminal a person and a coordinator share during a session (rich output, raw key input).

Between trials the terminal is in normal line mode (instructions, Likert items, outcome entry: type an
answer and press Enter; an invalid answer is re-asked with the reason). During timed phases (trials,
familiarisation, breaks) it is in cbreak mode: single keys act at once and a countdown is redrawn a few
times a second, while the feedback loop keeps its rate (keys are polled, never waited for).

Keys during a trial::

    participant   s  request a CT scan (counted; ignored in real-time conditions)
                  r  report a location: type it, Enter (re-asked with the reason if invalid)
                  f  finished
    coordinator   p  pause (stops the trial; it is repeated or replaced per protocol)
                  a  abort the trial: type a reason, Enter
                  i  mark the trial invalid: type a reason, Enter (the trial goes on)

Ctrl-C stops the session safely (device to its safe state, everything recorded, resumable).
"""

from __future__ import annotations

import os
import select
import sys
import termios
import time
import tty
from collections.abc import Callable, Mapping
from typing import Any

from rich.console import Console
from rich.panel import Panel
from rich.text import Text

from studyctl.engine.clock import Clock
from studyctl.engine.plan import Instrument, Item, ReportSpec, Step
from studyctl.engine.ui import Control, ManualOutcome, TimerResult
from studyctl.errors import InvalidAnswer, UsageError

REDRAW_S = 0.25
LINE_MODES = {"r": "report", "a": "abort", "i": "invalid", "n": "note"}


def fmt_clock(seconds: float) -> str:
    if seconds == float("inf"):
        return "no limit"
    seconds = max(0.0, seconds)
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


class Terminal:
    """Raw key input plus a one-line status display on a real terminal."""

    def __init__(self, console: Console | None = None, stdin=None) -> None:
        self.stdin = stdin or sys.stdin
        if not self.stdin.isatty():
            raise UsageError(
                "a session with a person needs a terminal (stdin is not one); use --input FILE for scripted "
                "answers or --virtual for a virtual participant"
            )
        self.fd = self.stdin.fileno()
        self.console = console or Console(highlight=False)
        self._saved = termios.tcgetattr(self.fd)
        self._raw = False
        self.mode: str | None = None  # None, "report", "abort", "invalid"
        self.line = ""
        self.keys: list[str] = []  # single keys not consumed yet
        self.lines: list[tuple[str, str]] = []  # finished (mode, text) entries
        self.notice = ""
        # Another place where the person may answer the current prompt (the participant view): polled while
        # a prompt waits; a string it returns is taken as the typed line, so it is checked the same way.
        self.answer_source: Callable[[], str | None] | None = None
        self._last_draw = 0.0
        self._last_poll = 0.0
        self._status = ""

    # -- modes ---------------------------------------------------------------------------------------
    def raw(self) -> None:
        if not self._raw:
            tty.setcbreak(self.fd)
            self._raw = True

    def cooked(self) -> None:
        if self._raw:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._raw = False
            self.console.print()

    def restore(self) -> None:
        try:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
        except termios.error:
            pass
        self._raw = False

    # -- input -----------------------------------------------------------------------------------------
    def pump(self, *, min_interval_s: float = 0.01) -> None:
        """Read whatever keys are waiting (never blocks) and feed the line editor."""
        now = time.monotonic()
        if now - self._last_poll < min_interval_s:
            return
        self._last_poll = now
        while select.select([self.fd], [], [], 0)[0]:
            data = os.read(self.fd, 1024).decode("utf-8", "replace")
            if not data:
                return
            for ch in data:
                self._feed(ch)

    def _feed(self, ch: str) -> None:
        if self.mode is None:
            if ch in LINE_MODES:
                self.mode = LINE_MODES[ch]
                self.line = ""
            else:
                self.keys.append(ch)
            return
        if ch in ("\r", "\n"):
            self.lines.append((self.mode, self.line.strip()))
            self.mode, self.line = None, ""
        elif ch == "\x1b":  # Esc cancels the entry
            self.mode, self.line = None, ""
        elif ch in ("\x7f", "\b"):
            self.line = self.line[:-1]
        elif ch.isprintable():
            self.line += ch

    def take_key(self, allowed: str) -> str | None:
        for i, k in enumerate(self.keys):
            if k.lower() in allowed:
                del self.keys[i]
                return k.lower()
        return None

    def take_line(self, mode: str) -> str | None:
        for i, (m, text) in enumerate(self.lines):
            if m == mode:
                del self.lines[i]
                return text
        return None

    # -- output ----------------------------------------------------------------------------------------
    def status(self, text: str, *, force: bool = False) -> None:
        """Redraw the status line (at most every REDRAW_S unless forced)."""
        now = time.monotonic()
        if not force and now - self._last_draw < REDRAW_S:
            return
        self._last_draw = now
        editing = f"  > {self.mode}: {self.line}_" if self.mode else ""
        notice = f"  ! {self.notice}" if self.notice else ""
        line = f"{text}{editing}{notice}"
        self._status = line
        # carriage return + clear line keeps one status line; plain text so codes stay verbatim
        self.console.file.write("\r\x1b[2K" + line)
        self.console.file.flush()

    def say(self, text: str, style: str | None = None) -> None:
        if self._raw:
            self.console.file.write("\r\x1b[2K")
        self.console.print(Text(text, style=style or ""))

    def ask(self, prompt: str) -> str:
        self.cooked()
        if self.answer_source is None:
            return self.console.input(prompt)
        return self._ask_either(prompt)

    def _ask_either(self, prompt: str) -> str:
        """A line typed here or an answer from :attr:`answer_source`, whichever comes first."""
        self.console.print(Text(prompt), end="")
        self.console.file.flush()
        buf = b""
        while True:
            # Line mode: the descriptor becomes readable once Enter completes a line.
            if select.select([self.fd], [], [], 0.05)[0]:
                data = os.read(self.fd, 4096)
                if not data:
                    raise EOFError("the terminal closed")
                buf += data
                if b"\n" in buf:
                    return buf.split(b"\n", 1)[0].decode("utf-8", "replace").rstrip("\r")
                continue
            source = self.answer_source
            answer = source() if source is not None else None
            if answer is not None:
                termios.tcflush(self.fd, termios.TCIFLUSH)  # drop a half-typed line: it was not sent
                self.console.print(Text(f"{answer}  (answered in the participant view)", style="cyan"))
                return answer


class TerminalUI:
    """Prompts for a person and a coordinator at one terminal (see the module docstring for keys)."""

    interactive = True

    def __init__(self, term: Terminal) -> None:
        self.term = term
        self.scans = 0
        self.reports = 0
        self._limit = float("inf")
        self._paused = False

    def message(self, text: str) -> None:
        self.term.say(text, "bold")

    def instructions(self, step: Step, text: str) -> None:
        c = self.term.console
        self.term.cooked()
        title = "Instructions" if step.kind != "end" else "Done"
        c.print(Panel(Text(text or ""), title=title, expand=False))
        if step.kind != "end":
            self.term.ask("Press Enter when ready ")

    def timer(self, title, duration_s, clock: Clock, *, can_end_early, purpose) -> TimerResult:
        t = self.term
        t.console.print(Text(f"{title}: {fmt_clock(duration_s)}"
                             + (" (press Enter to end early)" if can_end_early else "")
                             + "  [p pause]", style="bold"))
        t.raw()
        start = clock.now()
        paused_s = 0.0
        pause_start: float | None = None
        ended_early = False
        try:
            while True:
                t.pump(min_interval_s=0.0)
                key = t.take_key("p\r\n")
                now = clock.now()
                if key == "p":
                    if pause_start is None:
                        pause_start = now
                    else:
                        paused_s += now - pause_start
                        pause_start = None
                elif key in ("\r", "\n") and can_end_early and pause_start is None:
                    ended_early = True
                    break
                active = now - start - paused_s - ((now - pause_start) if pause_start is not None else 0.0)
                if active >= duration_s:
                    break
                state = "PAUSED " if pause_start is not None else ""
                t.status(f"{state}{title}: {fmt_clock(duration_s - active)} left")
                clock.sleep_until(now + 0.05)
        finally:
            t.status(f"{title}: done", force=True)
            t.cooked()
        return TimerResult(clock.now() - start - paused_s, ended_early, paused_s)

    def ask_item(self, instrument: Instrument, item: Item, number: int, context: Mapping[str, Any]):
        c = self.term.console
        self.term.cooked()
        c.print(Text(f"{instrument.title} — {number}/{len(instrument.items)}", style="bold"))
        c.print(Text(item.text))
        anchors = "   ".join(f"{p.code} = {p.label}" if p.label else str(p.code) for p in item.scale)
        c.print(Text(anchors, style="dim"))
        t0 = time.monotonic()
        while True:
            raw = self.term.ask(f"Answer ({item.scale[0].code}–{item.scale[-1].code}): ")
            try:
                return item.parse(raw), time.monotonic() - t0
            except InvalidAnswer as exc:
                c.print(Text(f"Not accepted: {exc}. Please answer again.", style="red"))

    def manual_outcome(self, step: Step, report: ReportSpec, clock: Clock) -> ManualOutcome:
        c = self.term.console
        self.term.cooked()
        c.print(Text(f"Manual trial ({step.condition}): no controller runs; the coordinator records the outcome.",
                     style="bold"))
        self.term.ask("Press Enter when the participant starts ")
        start = clock.now()
        self.term.ask("Press Enter when the participant has finished ")
        duration = clock.now() - start
        reports: list[dict[str, Any]] = []
        if report.kind != "none":
            c.print(Text(f"Enter each reported location as {report.describe()}; an empty line ends the list."))
            while True:
                raw = self.term.ask(f"Location {len(reports) + 1}: ")
                if not raw.strip():
                    break
                try:
                    reports.append(report.parse(raw))
                except InvalidAnswer as exc:
                    c.print(Text(f"Not accepted: {exc}. Please enter it again.", style="red"))
        note = self.term.ask("Note (optional, Enter to skip): ")
        return ManualOutcome(duration, tuple(reports), note.strip())

    def trial_begin(self, step: Step, time_limit_s: float) -> None:
        self._limit = time_limit_s
        self.scans = self.reports = 0
        c = self.term.console
        self.term.cooked()
        if step.kind == "familiarisation":
            c.print(Text(f"Practice — condition {step.condition}, up to {fmt_clock(time_limit_s)}; the feedback "
                         "is on and the example tumour sites are marked", style="bold"))
            c.print(Text("f ends the practice    coordinator: a stop the practice    Ctrl-C stop", style="dim"))
            self.term.ask("Press Enter to start the practice ")
            self.term.raw()
            return
        c.print(Text(f"Trial {step.trial_index} — condition {step.condition}, time limit {fmt_clock(time_limit_s)}",
                     style="bold"))
        c.print(Text("participant: s scan · r report · f finished    coordinator: p pause · a abort · "
                     "i mark invalid · n note    Ctrl-C stop", style="dim"))
        self.term.ask("Press Enter to start the trial ")
        self.term.raw()

    def trial_tick(self, t: float) -> None:
        self.term.pump()
        left = self._limit - t
        self.term.status(f"time left {fmt_clock(left)} · scans {self.scans} · reports {self.reports}")

    def trial_end(self, step: Step, summary: Mapping[str, Any]) -> None:
        self.term.status("trial over", force=True)
        self.term.cooked()
        status = summary.get("status")
        how = {"finish": "finished", "time_limit": "time limit reached"}.get(summary.get("ended_by"), status)
        if step.kind == "familiarisation":
            self.term.say(f"Practice: {how} after {summary.get('duration_s', 0):.1f} s")
            return
        self.term.say(f"Trial {step.trial_index}: {how} after {summary.get('duration_s', 0):.1f} s "
                      f"({summary.get('scans', 0)} scans, {summary.get('reports', 0)} reports)")
        if summary.get("reason"):
            self.term.say(f"  {summary['reason']}", "yellow")

    def poll_control(self) -> Control | None:
        t = self.term
        if t.take_key("p"):
            return Control("pause", "coordinator pressed p")
        for mode in ("abort", "invalid", "note"):
            text = t.take_line(mode)
            if text is not None:
                if not text:
                    what = "a note needs text" if mode == "note" else f"{mode}: a reason is required"
                    t.notice = f"{what} (press {mode[0]} again)"
                    return None
                t.notice = {"invalid": "marked invalid", "note": "note saved"}.get(mode, "")
                return Control(mode, text)
        return None

    def wait_unpause(self) -> None:
        self.term.ask("Session paused. Press Enter to continue ")

    def close(self) -> None:
        self.term.restore()
