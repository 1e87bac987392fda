// studyctl participant view: draws what the server streams (Server-Sent Events) and posts the
// participant's inputs. State lives on the server; a reload or reconnect gets it all again.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const KEY = "studyctl-view-client";
  const clientId = sessionStorage.getItem(KEY) || (() => {
    const a = new Uint8Array(8);
    crypto.getRandomValues(a);
    const id = Array.from(a, (b) => b.toString(16).padStart(2, "0")).join("");
    sessionStorage.setItem(KEY, id);
    return id;
  })();

  let role = "connecting"; // until the server's hello says control or read_only: nothing can be pressed
  let screen = { screen: "waiting", version: 0 };
  let ended = false;
  // Clock: server perf_counter seconds = page seconds + offset (best of recent round trips).
  let offset = null;
  let syncs = [];
  const keys = new Map();
  let base = null; // {key, w, h, rgba} the key image expanded to RGBA
  let surface = null;
  let surfaceBitmap = null;
  let pending = null;
  let lastFrame = null;
  let drawQueued = false;
  let lastT = null; // latest trial time (tick or frame)
  let promptShownAt = 0;
  let shownTrial = null;
  let reportMark = null;
  const acks = { frames: [], screens: [] };

  const pageNow = () => performance.now() / 1000;
  const serverNow = () => (offset === null ? null : pageNow() + offset);

  function post(path, body) {
    return fetch(path, {
      method: "POST", cache: "no-store", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ client: clientId, ...body }),
    }).then((r) => r.json().then((j) => ({ status: r.status, ...j }))).catch(() => null);
  }

  async function sync(n) {
    for (let i = 0; i < n; i++) {
      const c0 = pageNow();
      const r = await post("sync", {});
      const c1 = pageNow();
      if (!r || !r.ok) return;
      syncs.push({ rtt: c1 - c0, off: r.s - (c0 + c1) / 2 });
      if (syncs.length > 12) syncs.shift();
      const best = syncs.reduce((a, b) => (b.rtt < a.rtt ? b : a));
      offset = best.off;
    }
  }

  function flushAcks() {
    if (!acks.frames.length && !acks.screens.length) return;
    const body = { frames: acks.frames.splice(0), screens: acks.screens.splice(0) };
    if (syncs.length) body.rtt_ms = 1000 * Math.min(...syncs.map((x) => x.rtt));
    post("ack", body);
  }

  // ------------------------------------------------------------------ stream
  let es = null;
  function connect() {
    es = new EventSource("stream?client=" + encodeURIComponent(clientId));
    es.addEventListener("hello", (e) => {
      const m = JSON.parse(e.data);
      setRole(m.role);
      setConn("connected");
      sync(5);
    });
    es.addEventListener("role", (e) => setRole(JSON.parse(e.data).role));
    es.addEventListener("screen", (e) => {
      const m = JSON.parse(e.data);
      if (m.version === screen.version && m.screen === screen.screen) return;
      if (m.screen === "ended") {
        ended = true; es.close(); setConn("session ended");
        if (screen.screen === "done") return; // keep the closing words on screen
      }
      screen = m;
      renderScreen();
    });
    es.addEventListener("key", (e) => {
      const m = JSON.parse(e.data);
      keys.clear();
      keys.set(m.key, { w: m.w, h: m.h, data: bytes(m.data) });
      base = null;
    });
    es.addEventListener("surface", (e) => { surface = JSON.parse(e.data); surfaceBitmap = null; });
    es.addEventListener("frame", (e) => {
      pending = JSON.parse(e.data);
      if (!drawQueued) { drawQueued = true; requestAnimationFrame(drawPending); }
    });
    es.addEventListener("tick", (e) => { lastT = JSON.parse(e.data).t; });
    es.onerror = () => { if (!ended) setConn("reconnecting…"); };
    es.onopen = () => setConn("connected");
  }

  function setConn(text) { $("conn").textContent = text; }
  function setRole(r) {
    role = r;
    document.body.dataset.role = r;
    for (const b of document.querySelectorAll("button:not(#btn-full)")) b.disabled = r !== "control" || b.dataset.used === "1";
  }

  function bytes(b64) {
    const s = atob(b64);
    const out = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
    return out;
  }

  // ------------------------------------------------------------------ screens
  function fmt(sec) {
    if (sec === null || sec === undefined || !isFinite(sec)) return "";
    sec = Math.max(0, sec);
    return Math.floor(sec / 60) + ":" + String(Math.floor(sec % 60)).padStart(2, "0");
  }

  function notice(text, ok) {
    const n = $("notice");
    n.textContent = text || "";
    n.className = ok ? "ok" : "";
  }

  function renderScreen() {
    const s = screen;
    document.body.dataset.screen = s.screen;
    const answerable = !s.prompt || s.prompt.answerable;
    document.body.dataset.answerable = answerable ? "yes" : "no";
    promptShownAt = pageNow();
    if (s.screen !== "trial") notice("");
    const trialKey = (s.practice ? "p" : "t") + s.trial + (s.label || "");
    if (s.screen === "trial_ready" || (s.screen === "trial" && trialKey !== shownTrial)) {
      // a new trial: nothing of the previous one stays on screen
      shownTrial = trialKey; lastFrame = null; lastT = null; reportMark = null;
    }
    // The server sends a neutral label ("Trial 3", or the protocol's view_label): never a condition code.
    const label = s.label || (s.practice ? "Practice" : s.trial ? "Trial " + s.trial : "");
    $("heading").textContent = label || "studyctl";
    if (s.screen === "instructions") {
      $("ins-title").textContent = s.title || "Instructions";
      $("ins-text").textContent = s.text || "";
    } else if (s.screen === "trial_ready") {
      $("ready-title").textContent = label;
      $("btn-start").textContent = s.practice ? "Start the practice" : "Start the trial";
      $("ready-limit").textContent = s.time_limit_s ? "Time limit " + fmt(s.time_limit_s) : "No time limit";
    } else if (s.screen === "timer") {
      $("timer-title").textContent = s.title || "";
    } else if (s.screen === "trial") {
      renderTrial(s);
    } else if (s.screen === "trial_over") {
      const how = { finish: "finished", time_limit: "time limit reached" }[s.ended_by] || (s.status || "");
      $("over-text").textContent = label + ": " + how +
        (s.duration_s != null ? " after " + Number(s.duration_s).toFixed(1) + " s" : "");
    } else if (s.screen === "item") {
      renderItem(s);
    } else if (s.screen === "done") {
      $("done-text").textContent = s.text || "";
    }
    for (const b of document.querySelectorAll("button")) { delete b.dataset.used; b.classList.remove("chosen"); }
    setRole(role);
    // Tell the server when this screen was on the display (logged as what the participant saw).
    requestAnimationFrame(() => {
      const t = serverNow();
      if (t !== null && s.version) { acks.screens.push([s.version, t]); flushAcks(); }
    });
  }

  function renderItem(s) {
    $("item-title").textContent = s.title || "";
    $("item-progress").textContent = s.number && s.total ? s.number + " / " + s.total : "";
    $("item-intro").textContent = s.intro || "";
    $("item-text").textContent = s.text || "";
    const scale = $("scale");
    scale.replaceChildren();
    for (const p of s.scale || []) {
      const b = document.createElement("button");
      b.type = "button";
      b.className = "scale-point";
      b.dataset.code = String(p.code);
      b.setAttribute("role", "radio");
      const c = document.createElement("span"); c.className = "code"; c.textContent = String(p.code);
      const l = document.createElement("span"); l.className = "label"; l.textContent = p.label || "";
      b.append(c, l);
      b.addEventListener("click", () => answerLikert(s, p.code, b));
      scale.append(b);
    }
  }

  async function answerLikert(s, code, button) {
    if (role !== "control" || !s.prompt) return;
    for (const b of $("scale").querySelectorAll("button")) { b.disabled = true; b.dataset.used = "1"; }
    button.classList.add("chosen");
    const r = await post("input", { kind: "likert", prompt: s.prompt.id, code, rt_s: pageNow() - promptShownAt });
    if (!r || !r.ok) {
      notice((r && r.error) || "not sent: check the connection and answer again");
      for (const b of $("scale").querySelectorAll("button")) { b.disabled = false; delete b.dataset.used; }
      button.classList.remove("chosen");
    } else {
      notice("Answer " + code + " recorded", true);
    }
  }

  async function answerPrompt(kind, button) {
    if (role !== "control" || !screen.prompt) return;
    button.disabled = true; button.dataset.used = "1";
    const r = await post("input", { kind, prompt: screen.prompt.id });
    if (!r || !r.ok) {
      notice((r && r.error) || "not sent: check the connection and try again");
      button.disabled = false; delete button.dataset.used;
    }
  }

  function renderTrial(s) {
    const requests = s.requests || ["report", "finish"];
    const visual = s.visual || "none";
    $("btn-scan").style.display = requests.includes("scan") && visual === "on_request" ? "" : "none";
    $("btn-finish").style.display = requests.includes("finish") ? "" : "none";
    const rep = s.report || { kind: "none" };
    const showReport = requests.includes("report") && rep.kind !== "none";
    $("report").style.display = showReport ? "" : "none";
    if (showReport) renderReport(rep);
    if (!lastFrame || visual === "none") setVisual(visual === "none" ? "none" : visual === "on_request" ? "hint" : "");
    if (visual === "none") $("caption").textContent = "";
  }

  function renderReport(rep) {
    const grid = $("report-grid");
    grid.replaceChildren();
    $("report-label").textContent = rep.kind === "grid" ? "or type" : "Location (x y, mm)";
    $("report-text").placeholder = rep.kind === "grid" ? "e.g. " + rep.columns[0] + " " + rep.rows[0] : "x y";
    if (rep.kind !== "grid") return;
    grid.style.gridTemplateColumns = "repeat(" + rep.columns.length + ", auto)";
    for (const row of rep.rows) {
      for (const col of rep.columns) {
        const b = document.createElement("button");
        b.type = "button";
        b.textContent = col + " " + row;
        b.addEventListener("click", () => sendReport(col + " " + row));
        grid.append(b);
      }
    }
    setRole(role);
  }

  async function sendReport(text) {
    if (role !== "control") return;
    const r = await post("input", { kind: "report", text });
    if (r && r.ok) notice("Reported " + text, true);
    else notice((r && r.error) || "not sent: check the connection and report again");
    return r && r.ok;
  }

  async function request(kind) {
    if (role !== "control") return;
    const r = await post("input", { kind });
    if (!r || !r.ok) notice((r && r.error) || "not sent: check the connection and try again");
    else if (kind === "scan") notice("Scan requested", true);
  }

  // ------------------------------------------------------------------ frames
  function setVisual(kind) { $("visual").dataset.kind = kind; }

  function drawPending() {
    drawQueued = false;
    const f = pending;
    pending = null;
    if (!f) return;
    let ok = false;
    if (f.kind === "ct") ok = drawCT(f);
    else if (f.kind === "tissue") ok = drawTissue(f);
    else ok = drawValues(f);
    if (!ok) return;
    lastFrame = f;
    lastT = Math.max(lastT || 0, f.t);
    const t = serverNow();
    if (t !== null) {
      acks.frames.push([f.seq, t]);
      if (f.source === "scan") flushAcks();
    }
    $("caption").textContent = f.source === "scan" ? "Scan " + f.scan + " · taken at " + f.t.toFixed(1) + " s" : "live";
  }

  function drawCT(f) {
    const key = keys.get(f.key);
    if (!key) return false;
    const { w, h } = key;
    const cv = $("cv-ct");
    const ctx = cv.getContext("2d");
    if (!base || base.key !== f.key) {
      // a new key image: expand it to RGBA once; frames then only touch the pixels that change
      const rgba = new Uint8ClampedArray(w * h * 4);
      for (let i = 0, j = 0; i < w * h; i++, j += 4) {
        const v = key.data[i];
        rgba[j] = v; rgba[j + 1] = v; rgba[j + 2] = v; rgba[j + 3] = 255;
      }
      base = { key: f.key, w, h, rgba, img: new ImageData(new Uint8ClampedArray(rgba), w, h), prev: new Uint32Array(0) };
      if (cv.width !== w || cv.height !== h) { cv.width = w; cv.height = h; }
      ctx.putImageData(base.img, 0, 0);
      placeLabels(f.panels || [], w);
    }
    const d = base.img.data, k = base.rgba;
    let lo = Infinity, hi = -1;
    for (const i of base.prev) { // undo the previous frame's changes
      const j = i * 4;
      d[j] = k[j]; d[j + 1] = k[j + 1]; d[j + 2] = k[j + 2];
      if (i < lo) lo = i;
      if (i > hi) hi = i;
    }
    const idx = new Uint32Array(bytes(f.didx).buffer);
    const val = bytes(f.dval);
    for (let n = 0; n < idx.length; n++) {
      const i = idx[n], j = i * 4, v = val[n];
      d[j] = v; d[j + 1] = v; d[j + 2] = v;
      if (i < lo) lo = i;
      if (i > hi) hi = i;
    }
    base.prev = idx;
    if (hi >= 0) { // repaint only the rows that changed
      const r0 = Math.floor(lo / w), r1 = Math.floor(hi / w);
      ctx.putImageData(base.img, 0, 0, 0, r0, w, r1 - r0 + 1);
    }
    setVisual("ct");
    return true;
  }

  function placeLabels(panels, w) {
    const box = $("ct-labels");
    box.replaceChildren();
    for (const p of panels) {
      const el = document.createElement("span");
      el.textContent = p.name + " (" + p.h_axis + "–" + p.v_axis + ")";
      el.style.left = (100 * p.col0 / w) + "%";
      box.append(el);
    }
    // Scale bars: 10 mm at each slice's own resolution, bottom-left of each slice (the first is #ct-scale).
    const first = $("ct-scale");
    for (const old of box.parentNode.querySelectorAll(".ct-scale-more")) old.remove();
    panels.forEach((p, i) => {
      const bar = i === 0 ? first : first.cloneNode(true);
      const mpp = Number(p.mm_per_px);
      if (i > 0) { bar.removeAttribute("id"); bar.className = "ct-scale-more"; first.parentNode.append(bar); }
      if (isFinite(mpp) && mpp > 0) {
        bar.style.display = "";
        bar.style.left = (100 * (p.col0 + 8) / w) + "%";
        bar.style.width = (100 * (10 / mpp) / w) + "%";
      } else {
        bar.style.display = "none";
      }
    });
    if (!panels.length) first.style.display = "none";
  }

  function heightsColour(v, lo, hi) {
    const u = hi > lo ? (v - lo) / (hi - lo) : 0.5;
    return [150 + 80 * u, 90 + 60 * u, 100 + 50 * u];
  }

  function drawTissue(f) {
    const cv = $("cv-tissue");
    const ctx = cv.getContext("2d");
    const W = cv.width, H = cv.height;
    ctx.fillStyle = "#000"; ctx.fillRect(0, 0, W, H);
    if (!surface) return false;
    const xs = surface.xs_mm, ys = surface.ys_mm, hs = surface.heights_mm;
    let lo = Infinity, hi = -Infinity;
    for (const row of hs) for (const v of row) if (v !== null) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    const x0 = xs[0], x1 = xs[xs.length - 1], y0 = ys[0], y1 = ys[ys.length - 1];
    // Margins hold the mm rulers; the cursor circle (radius r) stays inside them at every corner.
    const ox = 64, oy = 40, half = W / 2 - ox - 34;
    const s = Math.min(half / (x1 - x0), (H - oy - 54) / (y1 - y0));
    const px = (x) => ox + (x - x0) * s, py = (y) => oy + (y1 - y) * s;
    if (!surfaceBitmap) {
      const off = document.createElement("canvas");
      off.width = xs.length; off.height = ys.length;
      const c = off.getContext("2d");
      const im = c.createImageData(xs.length, ys.length);
      for (let i = 0; i < xs.length; i++) {
        for (let j = 0; j < ys.length; j++) {
          const v = hs[i][j];
          const k = ((ys.length - 1 - j) * xs.length + i) * 4;
          if (v === null) { im.data[k + 3] = 0; continue; }
          const [r, g, b] = heightsColour(v, lo, hi);
          im.data[k] = r; im.data[k + 1] = g; im.data[k + 2] = b; im.data[k + 3] = 255;
        }
      }
      c.putImageData(im, 0, 0);
      surfaceBitmap = off;
    }
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(surfaceBitmap, px(x0), py(y1), (x1 - x0) * s, (y1 - y0) * s);
    drawRulers(ctx, px, py, x0, x1, y0, y1);
    ctx.fillStyle = "#9fb3c8"; ctx.font = "16px sans-serif"; ctx.textAlign = "left"; ctx.textBaseline = "alphabetic";
    ctx.fillText("top view (x y in mm: type these to report)", 8, 18);
    ctx.fillText("side view (section through the cursor)", W / 2 + 10, 18);
    const c = f.cursor_mm;
    const def = f.deformation;
    const r = f.indenter_radius_mm || 5;
    const profile = (def && def.profile) || [];
    const dz = (rho) => {
      if (!profile.length || rho > profile[profile.length - 1][0]) return 0;
      for (let k = 1; k < profile.length; k++) {
        if (rho <= profile[k][0]) {
          const [a, da] = profile[k - 1], [b, db] = profile[k];
          return da + (db - da) * (b > a ? (rho - a) / (b - a) : 0);
        }
      }
      return profile[0][1];
    };
    if (reportMark) {
      ctx.strokeStyle = "#4cc38a"; ctx.lineWidth = 3;
      ctx.beginPath(); ctx.arc(px(reportMark[0]), py(reportMark[1]), 8, 0, 2 * Math.PI); ctx.stroke();
    }
    if (c) {
      if (profile.length) {
        const maxd = Math.max(...profile.map((p) => -p[1]), 1e-6);
        for (let k = profile.length - 1; k >= 0; k--) {
          ctx.fillStyle = "rgba(40,0,20," + (0.75 * -profile[k][1] / maxd).toFixed(3) + ")";
          ctx.beginPath(); ctx.arc(px(c[0]), py(c[1]), Math.max(1, profile[k][0] * s), 0, 2 * Math.PI); ctx.fill();
        }
      }
      ctx.strokeStyle = f.depth_mm > 0 ? "#ffb347" : "#4aa3ff"; ctx.lineWidth = 3;
      ctx.beginPath(); ctx.arc(px(c[0]), py(c[1]), r * s, 0, 2 * Math.PI); ctx.stroke();
      // side view: heights along x at the cursor's y, pressed in by the deformation
      const j = Math.max(0, Math.min(ys.length - 1, Math.round((c[1] - y0) / (ys[1] - ys[0]))));
      // one scale for both axes, so the indenter stays round and the dent keeps its true depth
      const s2 = Math.min(half / (x1 - x0), (H - 80) / (hi - lo + 40));
      const zlo = lo - 10;
      const qx = (x) => W / 2 + 10 + (x - x0) * s2, qz = (z) => H - 40 - (z - zlo) * s2;
      ctx.fillStyle = "rgb(190,120,130)";
      ctx.beginPath();
      let started = false;
      for (let i = 0; i < xs.length; i++) {
        const v = hs[i][j];
        if (v === null) continue;
        const z = v + dz(Math.hypot(xs[i] - c[0], 0));
        if (!started) { ctx.moveTo(qx(xs[i]), qz(zlo)); started = true; }
        ctx.lineTo(qx(xs[i]), qz(z));
      }
      if (started) { ctx.lineTo(qx(x1), qz(zlo)); ctx.closePath(); ctx.fill(); }
      ctx.strokeStyle = f.depth_mm > 0 ? "#ffb347" : "#4aa3ff";
      ctx.beginPath(); ctx.arc(qx(c[0]), qz(c[2] + r), r * s2, 0, 2 * Math.PI); ctx.stroke();
      // below the title, clear of the profile and the indenter
      ctx.fillStyle = "#e8ecf0"; ctx.font = "18px sans-serif";
      ctx.fillText("depth " + f.depth_mm.toFixed(1) + " mm", W / 2 + 10, 44);
      ctx.fillStyle = "#9fb3c8"; ctx.font = "15px sans-serif";
      ctx.fillText("cursor " + c[0].toFixed(1) + " " + c[1].toFixed(1) + " mm", W / 2 + 170, 44);
    }
    setVisual("tissue");
    tissueGeom = { px, py, s, x0, y1, ox, oy, W };
    return true;
  }
  let tissueGeom = null;

  // mm grid over the top view and ruler ticks (every 5 mm, labelled every 10/20 mm) on its left and bottom edges.
  function drawRulers(ctx, px, py, x0, x1, y0, y1) {
    const span = Math.max(x1 - x0, y1 - y0);
    const major = span > 150 ? 20 : 10, minor = major / 2;
    ctx.save();
    ctx.lineWidth = 1; ctx.font = "13px sans-serif"; ctx.fillStyle = "#c8d3de";
    for (let v = Math.ceil(x0 / minor) * minor; v <= x1 + 1e-9; v += minor) {
      const isMajor = Math.abs(v / major - Math.round(v / major)) < 1e-9, X = px(v);
      ctx.strokeStyle = isMajor ? "rgba(255,255,255,0.28)" : "rgba(255,255,255,0.12)";
      ctx.beginPath(); ctx.moveTo(X, py(y1)); ctx.lineTo(X, py(y0)); ctx.stroke();
      ctx.strokeStyle = "#c8d3de";
      ctx.beginPath(); ctx.moveTo(X, py(y0)); ctx.lineTo(X, py(y0) + (isMajor ? 9 : 5)); ctx.stroke();
      if (isMajor) { ctx.textAlign = "center"; ctx.textBaseline = "top"; ctx.fillText(String(Math.round(v)), X, py(y0) + 11); }
    }
    for (let v = Math.ceil(y0 / minor) * minor; v <= y1 + 1e-9; v += minor) {
      const isMajor = Math.abs(v / major - Math.round(v / major)) < 1e-9, Y = py(v);
      ctx.strokeStyle = isMajor ? "rgba(255,255,255,0.28)" : "rgba(255,255,255,0.12)";
      ctx.beginPath(); ctx.moveTo(px(x0), Y); ctx.lineTo(px(x1), Y); ctx.stroke();
      ctx.strokeStyle = "#c8d3de";
      ctx.beginPath(); ctx.moveTo(px(x0), Y); ctx.lineTo(px(x0) - (isMajor ? 9 : 5), Y); ctx.stroke();
      if (isMajor) { ctx.textAlign = "right"; ctx.textBaseline = "middle"; ctx.fillText(String(Math.round(v)), px(x0) - 12, Y); }
    }
    ctx.textAlign = "left"; ctx.textBaseline = "alphabetic";
    ctx.fillText("x mm", px(x1) - 30, py(y0) + 40);
    ctx.restore();
  }

  function drawValues(f) {
    const tb = $("tb-values");
    tb.replaceChildren();
    for (const [k, v] of Object.entries(f.values || {})) {
      const tr = document.createElement("tr");
      const a = document.createElement("td"); a.textContent = k;
      const b = document.createElement("td"); b.textContent = Number(v).toFixed(2);
      tr.append(a, b); tb.append(tr);
    }
    setVisual("values");
    return true;
  }

  // ------------------------------------------------------------------ countdown
  function updateCountdown() {
    const s = screen;
    const el = $("countdown");
    let text = "";
    if (s.screen === "trial") {
      const t = lastT || 0;
      text = s.time_limit_s ? fmt(s.time_limit_s - t) : ""; // no limit: no clock to race against
      el.classList.toggle("low", !!s.time_limit_s && s.time_limit_s - t < 10);
    } else if (s.screen === "timer" && s.duration_s != null) {
      const now = serverNow();
      const left = now === null ? s.duration_s : s.duration_s - (now - s.started);
      $("timer-clock").textContent = fmt(left);
      el.classList.remove("low");
    } else {
      el.classList.remove("low");
    }
    el.textContent = text;
  }

  // ------------------------------------------------------------------ wiring
  $("btn-ready").addEventListener("click", (e) => answerPrompt("ready", e.currentTarget));
  $("btn-start").addEventListener("click", (e) => answerPrompt("start", e.currentTarget));
  $("btn-scan").addEventListener("click", () => request("scan"));
  $("btn-finish").addEventListener("click", () => request("finish"));
  $("report-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    const text = $("report-text").value.trim();
    if (text && (await sendReport(text))) { $("report-text").value = ""; reportMark = null; }
  });
  $("cv-tissue").addEventListener("click", (e) => {
    if (!tissueGeom || role !== "control") return;
    const cv = e.currentTarget, rect = cv.getBoundingClientRect();
    const x = (e.clientX - rect.left) * (cv.width / rect.width), y = (e.clientY - rect.top) * (cv.height / rect.height);
    if (x > tissueGeom.W / 2) return;
    const xm = tissueGeom.x0 + (x - tissueGeom.ox) / tissueGeom.s, ym = tissueGeom.y1 - (y - tissueGeom.oy) / tissueGeom.s;
    reportMark = [xm, ym];
    $("report-text").value = xm.toFixed(1) + " " + ym.toFixed(1);
    notice("Press Report to report this location", true);
  });
  $("btn-full").addEventListener("click", () => {
    if (document.fullscreenElement) document.exitFullscreen(); else document.documentElement.requestFullscreen();
  });
  document.addEventListener("fullscreenchange", () => {
    $("btn-full").textContent = document.fullscreenElement ? "Exit full screen" : "Full screen";
  });
  setInterval(updateCountdown, 100);
  setInterval(flushAcks, 250);
  setInterval(() => { if (!ended) sync(1); }, 5000);
  window.studyctlView = { clientId, state: () => ({ role, screen, offset, lastFrame, syncs: syncs.slice() }) };
  setRole(role);
  connect();
})();
