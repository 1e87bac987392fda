// The coordinator's read-only page: polls the session's state twice a second and shows it. Never sends
// anything but GET; text from the study (notes, labels) is set as text, never parsed as HTML.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const set = (id, text) => { const el = $(id); if (el) el.textContent = text == null ? "–" : String(text); };
  const mmss = (s) => {
    if (s == null || !isFinite(s)) return "–";
    const v = Math.max(0, Math.round(s)), m = Math.floor(v / 60), r = v % 60;
    return m + ":" + String(r).padStart(2, "0");
  };
  const PHASES = {
    waiting: "waiting", instructions: "instructions", timer: "timer", item: "questionnaire",
    trial_ready: "trial about to start", trial: "trial running", practice: "practice running",
    trial_over: "trial over", manual: "hands-on trial (coordinator times it)", paused: "PAUSED", done: "session done",
  };
  let last = null;

  function list(id, items, render) {
    const ul = $(id);
    ul.replaceChildren(...items.map((it) => { const li = document.createElement("li"); render(li, it); return li; }));
  }

  function span(cls, text) { const s = document.createElement("span"); s.className = cls; s.textContent = text; return s; }

  function draw(s) {
    last = s;
    const p = s.progress || {};
    set("who", p.session_id ? "Session " + p.session_id + " · " + p.participant +
        (p.virtual ? " (virtual)" : "") + (p.rehearsal ? " (rehearsal)" : "") +
        (p.resumes ? " · resumed " + p.resumes + "×" : "") : "Session not started");
    set("phase", PHASES[s.phase.kind] || s.phase.kind);
    document.body.dataset.phase = s.phase.kind;
    // protocol progress
    const total = p.steps_total || 0, done = p.steps_done || 0;
    $("bar-fill").style.width = total ? (100 * done / total).toFixed(1) + "%" : "0";
    set("progress-text", total ? "step " + done + " of " + total + " done" : "");
    list("steps", p.steps || [], (li, st) => {
      li.className = st.state; li.textContent = st.position + " " + st.kind + (st.condition ? " " + st.condition : "");
      li.title = st.label;
    });
    // now
    set("step-label", p.step ? p.step.label : "–");
    const c = p.condition;
    set("cond-code", c ? c.code : "–");
    set("cond-label", c ? c.label : "");
    set("cond-detail", c ? [c.manual ? "manual" : "controller " + (c.controller || "–"), "visual " + c.visual,
      c.view_label ? "participant sees \u201c" + c.view_label + "\u201d" : "participant sees no condition name"].join(" · ") : "");
    const loop = s.loop || {};
    if (s.timer) {
      set("timer-name", (s.timer.purpose === "break" ? "Break" : "Practice") + " left");
      set("timer-value", mmss(s.timer.left_s));
    } else if (loop.running && loop.t != null) {
      const limit = loop.time_limit_s;
      set("timer-name", limit ? "Trial time left" : "Trial time (no limit)");
      set("timer-value", limit ? mmss(limit - loop.t) : mmss(loop.t));
    } else {
      set("timer-name", "Session"); set("timer-value", mmss(s.session_elapsed_s));
    }
    set("phase-for", "in this phase for " + mmss(s.phase.for_s) + " · session page open " + mmss(s.session_elapsed_s));
    // trials
    const t = p.trials || {};
    set("t-done", t.planned != null ? t.done + " of " + t.planned : "–");
    set("t-left", t.left); set("t-aborted", t.aborted); set("t-invalid", t.invalid);
    set("t-requests", loop.running ? (loop.scans ?? 0) + " / " + (loop.reports ?? 0) : "–");
    // loop and device
    const d = s.device || {};
    const st = $("dev-state");
    if (d.fault_active) { st.className = "pill bad"; st.textContent = "FAULT: " + d.fault_active.rule; }
    else if (loop.running && loop.stalled) { st.className = "pill warn"; st.textContent = "loop stalled"; }
    else if (loop.running) { st.className = "pill ok"; st.textContent = "running, no fault"; }
    else { st.className = "pill"; st.textContent = "idle"; }
    set("dev-name", (d.plugin || "no device") + " (" + (d.kind || "–") + ")");
    set("loop-rate", loop.rate_hz != null ? loop.rate_hz.toFixed(0) + " Hz" + (loop.target_hz ? " of " + loop.target_hz + " Hz" : "")
      : (loop.running ? "measuring…" : "–"));
    set("loop-tick", loop.last_tick_ago_s != null ? (loop.last_tick_ago_s * 1000).toFixed(0) + " ms ago" : "–");
    const tr = d.trial || {}, se = d.session || {};
    set("dev-trial-label", "faults / recoveries (" + (loop.running ? "this" : "last") + " trial)");
    set("dev-trial", (tr.device_fault || 0) + " / " + (tr.device_recovered || 0));
    set("dev-safety", se.safety || 0);
    set("loop-late", (tr.late_ticks || 0) + " / " + (se.late_ticks || 0));
    set("loop-samples", loop.samples == null ? "–" : loop.samples + (loop.samples_behind == null ? ""
      : " · " + loop.samples_behind + " behind the rate"));
    list("dev-events", (d.events || []).slice().reverse(), (li, e) => {
      li.append(span("dim", "t=" + e.t.toFixed(2) + " s"), e.kind + " " + e.rule + (e.channel ? " " + e.channel : "") +
        (e.state ? " (" + e.state + ")" : ""));
    });
    // participant's screen
    const ps = s.participant_screen || {};
    set("ps-screen", (ps.screen || "–") + (ps.prompt ? " · waiting for " + ps.prompt : ""));
    const control = (ps.screens || []).filter((x) => x.control).length;
    set("ps-clients", (ps.screens || []).length + (control ? " (1 in control)" : ""));
    set("ps-latency", ps.frame_latency_ms_p50 != null ? ps.frame_latency_ms_p50 + " ms" : "–");
    set("ps-refused", ps.refused_requests);
    // lease and notes
    const l = s.lease;
    set("lease", l ? "held by pid " + l.pid + " on " + l.host + " since " + l.since + " · heartbeat " + l.heartbeat_age_s + " s ago"
      : (p.session_id ? "no lease held" : "–"));
    set("store-read", s.store && s.store.error ? "could not read the study database: " + s.store.error
      : (s.store && s.store.read_at ? "read from the study database at " + s.store.read_at : ""));
    drawStudy(s.study, p.participant);
    if (p.session_id) set("note-how", "studyctl note \"…\" --session " + p.session_id);
    const notes = s.notes || [];
    list("notes", notes.length ? notes : [null], (li, n) => {
      if (!n) { li.className = "dim"; li.textContent = "no notes on this session yet"; return; }
      li.append(span("dim", n.at.slice(11, 19) + " " + n.actor + (n.trial_id ? " · trial " + n.trial_id : "")), n.text);
    });
  }

  function cell(tag, text, cls) {
    const c = document.createElement(tag); c.textContent = text; if (cls) c.className = cls; return c;
  }

  function drawStudy(st, me) {
    const table = $("study-table");
    if (!st || st.error) {
      table.replaceChildren();
      set("study-name", st && st.error ? "could not read: " + st.error : "");
      set("study-totals", ""); set("study-balance", ""); set("study-data", ""); $("study-gaps").replaceChildren();
      return;
    }
    set("study-name", st.name + " · " + st.participants + " participant" + (st.participants === 1 ? "" : "s"));
    const head = document.createElement("tr");
    head.append(cell("th", "participant"), cell("th", "group"), cell("th", "status"),
      ...st.conditions.map((c) => cell("th", c)), cell("th", "left"));
    const rows = st.people.map((person) => {
      const tr = document.createElement("tr");
      tr.className = (person.code === me ? "me " : "") + (person.status === "withdrawn" ? "withdrawn" : "");
      tr.append(cell("td", person.code), cell("td", person.stratum || "–"), cell("td", person.status),
        ...st.conditions.map((c) => {
          const v = person.cells[c];
          return v ? cell("td", v[0] + "/" + v[1], v[1] && v[0] >= v[1] ? "full" : "") : cell("td", "–");
        }), cell("td", person.left));
      return tr;
    });
    table.replaceChildren(head, ...rows);
    const t = st.totals;
    set("study-totals", "trials: " + t.done + " done, " + t.running + " running, " + t.left + " left, " +
      t.aborted + " aborted, " + t.invalid + " invalid");
    const balance = Object.entries(st.first_condition).map(([k, v]) =>
      "[" + k + "] " + Object.entries(v).map(([c, n]) => c + " " + n).join(", ")).join("  ");
    set("study-balance", "balance, first condition: " + (balance || "–"));
    const g = st.data;
    if (g && g.error) { set("study-data", "data: could not read: " + g.error); $("study-gaps").replaceChildren(); }
    else if (g) {
      const n = g.totals;
      set("study-data", "data: " + n.samples_stored + " of " + n.ticks + " loop samples stored in " + n.trials_checked +
        " ended trials (" + n.dropped_samples + " dropped) · missing: " + n.trials_missing + " trials, " +
        n.answers_missing + " questionnaire answers");
      $("study-data").className = n.dropped_samples || n.trials_missing || n.answers_missing ? "warn" : "dim";
      const rows = g.gaps.map((x) => x.participant + " " + (x.trial_id != null ? "trial " + x.trial_id
        : x.session_id != null ? "session " + x.session_id : "no session") + (x.condition ? " " + x.condition : "") +
        ": " + x.detail);
      if (g.more) rows.push("… " + g.more + " more (studyctl status lists them all)");
      list("study-gaps", rows, (li, text) => { li.textContent = text; });
    }
  }

  async function poll() {
    try {
      const r = await fetch("state", { cache: "no-store", credentials: "same-origin" });
      if (r.status === 410) {
        document.body.dataset.conn = "lost";
        set("conn", "the session's view has closed · last data shown");
        clearInterval(timer);
        return;
      }
      if (!r.ok) throw new Error("HTTP " + r.status);
      draw(await r.json());
      document.body.dataset.conn = "ok";
      set("conn", "live · " + new Date().toLocaleTimeString());
    } catch (e) {
      document.body.dataset.conn = "lost";
      set("conn", "connection lost (session ended?) · last data shown");
    }
  }
  window.studyctlCoordinator = { state: () => last };
  const timer = setInterval(poll, 500);
  poll();
})();
