// DeepCrashTest viewer: bird's-eye canvas, time slider, video frame, waypoint editing, simulate, save.
// World frame: x forward (drawn to the right), y left (drawn up), metres. Edits are computed by the
// server (POST /api/edit); this page keeps the undo/redo stacks of whole scenarios.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const canvas = $("bev");
  const ctx = canvas.getContext("2d");
  const EGO_COLOUR = "#e53935";
  const CLASS_COLOURS = {
    D0T1: "#42a5f5", D0T2: "#26c6da", D0T3: "#5c6bc0", D1T1: "#ffca28",
    D1T2: "#ffa726", D1T3: "#ab47bc", D1T4: "#8d6e63",
  };
  const S = {
    file: "", scenario: null, road: null, video: null, videoOffset: 0, simulator: false,
    undo: [], redo: [], t: 0, tmax: 1, playing: false, selected: 0, wp: null,
    view: { scale: 4, ox: 40, oy: 280 }, sim: null, simStale: false,
    drag: null, pan: null, frameLoading: false, framePending: false, busy: 0,
  };

  // ------------------------------------------------------------------ helpers
  const vehicles = () => (S.scenario ? [S.scenario.ego, ...S.scenario.agents] : []);
  const vehicleById = (id) => vehicles().find((v) => v.id === id) || null;
  const colour = (v) => (v.id === S.scenario.ego.id ? EGO_COLOUR : CLASS_COLOURS[v.trajectory_class] || "#90a4ae");
  const fmt = (x, d = 2) => (x === null || x === undefined ? "-" : typeof x === "number" ? x.toFixed(d) : String(x));

  function worldToScreen(x, y) {
    return [S.view.ox + x * S.view.scale, S.view.oy - y * S.view.scale];
  }
  function screenToWorld(px, py) {
    return [(px - S.view.ox) / S.view.scale, (S.view.oy - py) / S.view.scale];
  }
  function canvasPoint(e) {
    const r = canvas.getBoundingClientRect();
    return [((e.clientX - r.left) * canvas.width) / r.width, ((e.clientY - r.top) * canvas.height) / r.height];
  }
  function clientPoint(px, py) {
    const r = canvas.getBoundingClientRect();
    return [r.left + (px * r.width) / canvas.width, r.top + (py * r.height) / canvas.height];
  }

  function stateAt(v, t) {
    const tr = v.trajectory;
    const n = tr.t.length;
    if (t < tr.t[0] - 1e-9 || t > tr.t[n - 1] + 1e-9 || t < v.start_delay_s - 1e-9) return null;
    let lo = 0;
    let hi = n - 1;
    while (hi - lo > 1) {
      const mid = (lo + hi) >> 1;
      if (tr.t[mid] <= t) lo = mid; else hi = mid;
    }
    if (n === 1 || hi === lo) return { x: tr.x[lo], y: tr.y[lo], yaw: tr.yaw[lo], speed: tr.speed[lo] };
    const a = Math.min(Math.max((t - tr.t[lo]) / (tr.t[hi] - tr.t[lo]), 0), 1);
    const lerp = (k) => tr[k][lo] + a * (tr[k][hi] - tr[k][lo]);
    return { x: lerp("x"), y: lerp("y"), yaw: lerp("yaw"), speed: lerp("speed") };
  }

  function simStateAt(i, t) {
    const sim = S.sim;
    if (!sim || !sim.times.length) return null;
    let k = 0;
    let best = Infinity;
    for (let j = 0; j < sim.times.length; j++) {
      const d = Math.abs(sim.times[j] - t);
      if (d < best) { best = d; k = j; }
    }
    if (!sim.present[k][i]) return null;
    const s = sim.states[k][i];
    return s[0] === null ? null : { x: s[0], y: s[1], yaw: s[2], speed: s[3] };
  }

  function boxCorners(st, v) {
    const c = Math.cos(st.yaw);
    const s = Math.sin(st.yaw);
    const hl = v.length / 2;
    const hw = v.width / 2;
    return [[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]].map(([a, b]) => [st.x + a * c - b * s, st.y + a * s + b * c]);
  }

  function insideBox(px, py, st, v) {
    const [wx, wy] = screenToWorld(px, py);
    const dx = wx - st.x;
    const dy = wy - st.y;
    const c = Math.cos(st.yaw);
    const s = Math.sin(st.yaw);
    return Math.abs(dx * c + dy * s) <= v.length / 2 + 0.3 && Math.abs(-dx * s + dy * c) <= v.width / 2 + 0.3;
  }

  function setStatus(text, error = false) {
    const el = $("status");
    el.textContent = text;
    el.className = error ? "error" : "";
  }

  async function api(path, body) {
    S.busy++;
    try {
      const r = await fetch(path, {
        method: "POST",
        headers: { "Content-Type": "application/json" },
        body: JSON.stringify(body),
      });
      let data = null;
      try { data = await r.json(); } catch (e) { data = null; }
      if (!r.ok) {
        const err = new Error((data && data.error) || `HTTP ${r.status}`);
        err.status = r.status;
        throw err;
      }
      return data;
    } finally {
      S.busy--;
    }
  }

  // ------------------------------------------------------------------ drawing
  function polyline(points, close = false) {
    ctx.beginPath();
    points.forEach(([x, y], i) => {
      const [px, py] = worldToScreen(x, y);
      if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
    });
    if (close) ctx.closePath();
  }

  function drawRoad() {
    const b = S.road.boundaries;
    if (b.length >= 2) {
      polyline([...b[0], ...[...b[b.length - 1]].reverse()], true);
      ctx.fillStyle = "#555b5e";
      ctx.fill();
    }
    b.forEach((line, i) => {
      polyline(line);
      ctx.strokeStyle = "#f5f5f5";
      ctx.lineWidth = 1.5;
      ctx.setLineDash(i === 0 || i === b.length - 1 ? [] : [8, 8]);
      ctx.stroke();
    });
    ctx.setLineDash([]);
  }

  function drawVehicle(v, st, opts) {
    const corners = boxCorners(st, v);
    polyline(corners, true);
    ctx.globalAlpha = opts.ghost ? 0.15 : 0.75;
    ctx.fillStyle = colour(v);
    ctx.fill();
    ctx.globalAlpha = 1;
    ctx.setLineDash(opts.ghost ? [4, 3] : []);
    ctx.lineWidth = opts.selected ? 2.5 : 1;
    ctx.strokeStyle = opts.selected ? "#ffeb3b" : opts.ghost ? "#ffffff" : "#111";
    ctx.stroke();
    ctx.setLineDash([]);
    // heading tick
    const [fx, fy] = worldToScreen(st.x + (v.length / 2) * Math.cos(st.yaw), st.y + (v.length / 2) * Math.sin(st.yaw));
    const [cx, cy] = worldToScreen(st.x, st.y);
    ctx.beginPath();
    ctx.moveTo(cx, cy);
    ctx.lineTo(fx, fy);
    ctx.strokeStyle = "#111";
    ctx.lineWidth = 1;
    ctx.stroke();
    if (!opts.ghost) {
      ctx.fillStyle = "#fff";
      ctx.font = "12px sans-serif";
      ctx.fillText(v.id === S.scenario.ego.id ? "ego" : String(v.id), cx + 6, cy - 6);
    }
  }

  function draw() {
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#3b4a3f";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    if (!S.scenario) return;
    drawRoad();
    const showSim = S.sim && $("show-sim").checked;
    for (const v of vehicles()) {
      const tr = v.trajectory;
      polyline(tr.x.map((x, i) => [x, tr.y[i]]));
      ctx.strokeStyle = colour(v);
      ctx.globalAlpha = v.id === S.selected ? 1 : 0.5;
      ctx.lineWidth = v.id === S.selected ? 2 : 1;
      ctx.stroke();
      ctx.globalAlpha = 1;
    }
    if (showSim) {
      S.sim.vehicle_ids.forEach((id, i) => {
        const pts = [];
        S.sim.times.forEach((_, k) => { if (S.sim.present[k][i] && S.sim.states[k][i][0] !== null) pts.push(S.sim.states[k][i]); });
        if (pts.length < 2) return;
        polyline(pts.map((s) => [s[0], s[1]]));
        ctx.setLineDash([3, 4]);
        ctx.strokeStyle = "#ffffff";
        ctx.lineWidth = 1;
        ctx.stroke();
        ctx.setLineDash([]);
      });
    }
    const sel = vehicleById(S.selected);
    if (sel) {
      const tr = sel.trajectory;
      for (let i = 0; i < tr.t.length; i++) {
        let [x, y] = [tr.x[i], tr.y[i]];
        if (S.drag && S.drag.index === i) [x, y] = [S.drag.x, S.drag.y];
        const [px, py] = worldToScreen(x, y);
        ctx.beginPath();
        ctx.arc(px, py, i === S.wp ? 5 : 3, 0, 2 * Math.PI);
        ctx.fillStyle = i === S.wp ? "#ffeb3b" : "#ffffff";
        ctx.fill();
        ctx.strokeStyle = "#111";
        ctx.lineWidth = 1;
        ctx.stroke();
      }
    }
    for (const v of vehicles()) {
      const st = stateAt(v, S.t);
      if (st) drawVehicle(v, st, { selected: v.id === S.selected });
    }
    if (showSim) {
      S.sim.vehicle_ids.forEach((id, i) => {
        const v = vehicleById(id);
        const st = simStateAt(i, S.t);
        if (v && st) drawVehicle(v, st, { ghost: true });
      });
      const c = (S.sim.collisions || [])[0];
      if (c && c.point && c.point[0] !== null) {
        const [px, py] = worldToScreen(c.point[0], c.point[1]);
        ctx.strokeStyle = "#ff1744";
        ctx.lineWidth = 3;
        ctx.beginPath();
        ctx.moveTo(px - 8, py - 8); ctx.lineTo(px + 8, py + 8);
        ctx.moveTo(px + 8, py - 8); ctx.lineTo(px - 8, py + 8);
        ctx.stroke();
      }
    }
    ctx.fillStyle = "#fff";
    ctx.font = "12px sans-serif";
    const m = 10 ** Math.floor(Math.log10(120 / S.view.scale));
    const bar = [1, 2, 5].map((k) => k * m).filter((d) => d * S.view.scale <= 150).pop() || m;
    ctx.fillRect(12, canvas.height - 18, bar * S.view.scale, 3);
    ctx.fillText(`${bar} m`, 12, canvas.height - 24);
  }

  function fitView() {
    let xs = [];
    let ys = [];
    for (const v of vehicles()) { xs = xs.concat(v.trajectory.x); ys = ys.concat(v.trajectory.y); }
    for (const line of S.road.boundaries) line.forEach(([x, y]) => { xs.push(x); ys.push(y); });
    const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
    const scale = 0.92 * Math.min(canvas.width / Math.max(x1 - x0, 1), canvas.height / Math.max(y1 - y0, 1));
    S.view.scale = scale;
    S.view.ox = canvas.width / 2 - ((x0 + x1) / 2) * scale;
    S.view.oy = canvas.height / 2 + ((y0 + y1) / 2) * scale;
  }

  // ------------------------------------------------------------------ panels
  function refreshPanels() {
    const sel = $("vehicle");
    const keep = S.selected;
    sel.innerHTML = "";
    for (const v of vehicles()) {
      const o = document.createElement("option");
      o.value = String(v.id);
      o.textContent = v.id === S.scenario.ego.id ? `ego (${v.id})` : `agent ${v.id} ${v.category} ${v.trajectory_class || ""}`;
      sel.appendChild(o);
    }
    sel.value = String(keep);
    const v = vehicleById(S.selected);
    if (v) {
      const tr = v.trajectory;
      $("vehicle-info").textContent =
        `${v.category} ${v.length.toFixed(2)} x ${v.width.toFixed(2)} m, ${tr.t.length} samples, ` +
        `t ${tr.t[0].toFixed(2)}-${tr.t[tr.t.length - 1].toFixed(2)} s` + (v.spline ? ", spline" : "");
    }
    if (v && S.wp !== null && S.wp < v.trajectory.t.length) {
      const tr = v.trajectory;
      $("waypoint-label").textContent = `waypoint #${S.wp} at t=${tr.t[S.wp].toFixed(2)} s`;
      $("wp-x").value = tr.x[S.wp].toFixed(3);
      $("wp-y").value = tr.y[S.wp].toFixed(3);
    } else {
      S.wp = null;
      $("waypoint-label").textContent = "no waypoint selected";
      $("wp-x").value = "";
      $("wp-y").value = "";
    }
    const hist = $("history");
    hist.innerHTML = "";
    for (const h of S.scenario.provenance.history) {
      const li = document.createElement("li");
      li.textContent = h;
      hist.appendChild(li);
    }
    $("undo").disabled = S.undo.length === 0;
    $("redo").disabled = S.redo.length === 0;
    $("simulate").disabled = !S.simulator;
    $("simulate").title = S.simulator ? "" : "simulator not available in this build";
  }

  function showOutcome() {
    const dl = $("outcome");
    dl.innerHTML = "";
    if (!S.sim) return;
    const m = S.sim.metrics;
    const rows = [
      ["collided", m.collided ? "yes" : "no"],
      ["collision time", m.collided ? `${fmt(m.collision_time)} s` : "-"],
      ["with vehicle", m.collision_vehicle ?? "-"],
      ["delta-v ego", `${fmt(m.delta_v_ego)} m/s`],
      ["relative speed", `${fmt(m.relative_speed)} m/s`],
      ["min distance", `${fmt(m.min_distance)} m`],
      ["min TTC", `${fmt(m.min_ttc)} s`],
    ];
    if (S.simStale) rows.push(["note", "edited since this run"]);
    for (const [k, val] of rows) {
      const dt = document.createElement("dt");
      dt.textContent = k;
      const dd = document.createElement("dd");
      dd.textContent = String(val);
      dd.dataset.key = k;
      dl.append(dt, dd);
    }
  }

  function updateTimeRange() {
    let tmax = 0;
    for (const v of vehicles()) tmax = Math.max(tmax, v.trajectory.t[v.trajectory.t.length - 1]);
    if (S.sim && S.sim.times.length) tmax = Math.max(tmax, S.sim.times[S.sim.times.length - 1]);
    S.tmax = Math.max(tmax, 0.01);
    $("time").max = String(S.tmax);
    setTime(Math.min(S.t, S.tmax));
  }

  // ------------------------------------------------------------------ time and video
  function setTime(t) {
    S.t = Math.min(Math.max(t, 0), S.tmax);
    $("time").value = String(S.t);
    $("time-label").textContent = `${S.t.toFixed(2)} s`;
    draw();
    requestFrame();
  }

  function requestFrame() {
    if (!S.video) return;
    if (S.frameLoading) { S.framePending = true; return; }
    S.frameLoading = true;
    $("frame").src = `/api/frame?t=${S.t.toFixed(3)}`;
  }

  function frameDone() {
    S.frameLoading = false;
    if (S.framePending) { S.framePending = false; requestFrame(); }
  }

  let lastTick = null;
  function tick(now) {
    if (!S.playing) return;
    if (lastTick !== null) setTime(S.t + (now - lastTick) / 1000);
    lastTick = now;
    if (S.t >= S.tmax) { togglePlay(false); return; }
    requestAnimationFrame(tick);
  }
  function togglePlay(on) {
    S.playing = on === undefined ? !S.playing : on;
    $("play").textContent = S.playing ? "Pause" : "Play";
    if (S.playing) {
      if (S.t >= S.tmax) setTime(0);
      lastTick = null;
      requestAnimationFrame(tick);
    }
  }

  // ------------------------------------------------------------------ edits
  function setScenario(sc) {
    S.scenario = sc;
    if (!vehicleById(S.selected)) S.selected = sc.ego.id;
    if (S.sim) S.simStale = true;
    refreshPanels();
    showOutcome();
    updateTimeRange();
  }

  async function doEdit(edit) {
    try {
      const res = await api("/api/edit", { scenario: S.scenario, edit });
      S.undo.push(S.scenario);
      S.redo = [];
      setScenario(res.scenario);
      setStatus(`edited: ${res.description}`);
    } catch (err) {
      setStatus(`edit refused: ${err.message}`, true);
      draw();
    }
  }

  function undo() {
    if (!S.undo.length) return;
    S.redo.push(S.scenario);
    setScenario(S.undo.pop());
    setStatus("undone");
  }
  function redo() {
    if (!S.redo.length) return;
    S.undo.push(S.scenario);
    setScenario(S.redo.pop());
    setStatus("redone");
  }

  function numberField(id) {
    const v = Number($(id).value);
    if ($(id).value.trim() === "" || !Number.isFinite(v)) throw new Error(`${id}: enter a number`);
    return v;
  }

  // ------------------------------------------------------------------ mouse
  function hitWaypoint(px, py) {
    const v = vehicleById(S.selected);
    if (!v) return null;
    let best = null;
    let bestD = 8;
    v.trajectory.x.forEach((x, i) => {
      const [sx, sy] = worldToScreen(x, v.trajectory.y[i]);
      const d = Math.hypot(sx - px, sy - py);
      if (d <= bestD) { bestD = d; best = i; }
    });
    return best;
  }

  canvas.addEventListener("mousedown", (e) => {
    if (!S.scenario) return;
    const [px, py] = canvasPoint(e);
    const i = hitWaypoint(px, py);
    if (i !== null) {
      const v = vehicleById(S.selected);
      S.wp = i;
      setTime(v.trajectory.t[i]); // the video frame and every box at the waypoint's time
      S.drag = { index: i, x: v.trajectory.x[i], y: v.trajectory.y[i], px, py, moved: false };
      refreshPanels();
      draw();
      return;
    }
    for (const v of [...vehicles()].reverse()) {
      const st = stateAt(v, S.t);
      if (st && insideBox(px, py, st, v)) {
        S.selected = v.id;
        S.wp = null;
        refreshPanels();
        draw();
        return;
      }
    }
    S.pan = { px, py, ox: S.view.ox, oy: S.view.oy };
  });

  window.addEventListener("mousemove", (e) => {
    if (!S.drag && !S.pan) return;
    const [px, py] = canvasPoint(e);
    if (S.drag) {
      [S.drag.x, S.drag.y] = screenToWorld(px, py);
      S.drag.moved = S.drag.moved || Math.hypot(px - S.drag.px, py - S.drag.py) > 1;
      draw();
    } else {
      S.view.ox = S.pan.ox + (px - S.pan.px);
      S.view.oy = S.pan.oy + (py - S.pan.py);
      draw();
    }
  });

  window.addEventListener("mouseup", () => {
    if (S.drag) {
      const d = S.drag;
      S.drag = null;
      if (d.moved) {
        let falloff = 0.5;
        try { falloff = numberField("falloff"); } catch (err) { setStatus(err.message, true); draw(); return; }
        doEdit({ kind: "move_waypoint", vehicle_id: S.selected, index: d.index, x: d.x, y: d.y, falloff_s: falloff });
      } else {
        draw();
      }
    }
    S.pan = null;
  });

  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const [px, py] = canvasPoint(e);
    const [wx, wy] = screenToWorld(px, py);
    S.view.scale *= Math.exp(-e.deltaY * 0.0015);
    S.view.ox = px - wx * S.view.scale;
    S.view.oy = py + wy * S.view.scale;
    draw();
  }, { passive: false });

  // ------------------------------------------------------------------ buttons
  $("vehicle").addEventListener("change", (e) => {
    S.selected = Number(e.target.value);
    S.wp = null;
    refreshPanels();
    draw();
  });
  $("time").addEventListener("input", (e) => setTime(Number(e.target.value)));
  $("play").addEventListener("click", () => togglePlay());
  $("undo").addEventListener("click", undo);
  $("redo").addEventListener("click", redo);
  $("show-sim").addEventListener("change", draw);
  $("frame").addEventListener("load", frameDone);
  $("frame").addEventListener("error", frameDone);

  $("wp-move").addEventListener("click", () => {
    if (S.wp === null) { setStatus("select a waypoint first (click it on the canvas)", true); return; }
    try {
      const edit = { kind: "move_waypoint", vehicle_id: S.selected, index: S.wp, x: numberField("wp-x"), y: numberField("wp-y"), falloff_s: numberField("falloff") };
      doEdit(edit);
    } catch (err) { setStatus(err.message, true); }
  });

  $("shift").addEventListener("click", () => {
    try {
      doEdit({ kind: "shift", vehicle_id: S.selected, d_lon: numberField("d-lon"), d_lat: numberField("d-lat") });
    } catch (err) { setStatus(err.message, true); }
  });

  $("simulate").addEventListener("click", async () => {
    setStatus("simulating...");
    try {
      S.sim = await api("/api/simulate", { scenario: S.scenario });
      S.simStale = false;
      showOutcome();
      updateTimeRange();
      const m = S.sim.metrics;
      setStatus(`simulated: ${m.collided ? `collision at ${fmt(m.collision_time)} s` : "no collision"}`);
    } catch (err) {
      setStatus(`simulate: ${err.message}`, true);
    }
  });

  $("save").addEventListener("click", async () => {
    const filename = $("save-name").value.trim();
    try {
      let res;
      try {
        res = await api("/api/save", { scenario: S.scenario, filename, overwrite: false });
      } catch (err) {
        if (err.status !== 409 || !window.confirm(`${err.message}. Overwrite ${filename}?`)) throw err;
        res = await api("/api/save", { scenario: S.scenario, filename, overwrite: true });
      }
      setStatus(`saved ${res.saved}`);
    } catch (err) {
      setStatus(`save: ${err.message}`, true);
    }
  });

  document.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLInputElement && e.target.type !== "range") return;
    const mod = e.ctrlKey || e.metaKey;
    if (mod && e.key.toLowerCase() === "z" && !e.shiftKey) { e.preventDefault(); undo(); }
    else if (mod && (e.key.toLowerCase() === "y" || (e.key.toLowerCase() === "z" && e.shiftKey))) { e.preventDefault(); redo(); }
    else if (e.key === " " && e.target === canvas) { e.preventDefault(); togglePlay(); }
  });

  // ------------------------------------------------------------------ start
  async function start() {
    const r = await fetch("/api/scenario");
    const data = await r.json();
    if (!r.ok) { setStatus(data.error || `HTTP ${r.status}`, true); return; }
    S.file = data.file;
    S.road = data.road;
    S.video = data.video;
    S.videoOffset = data.video_offset_s;
    S.simulator = data.simulator;
    S.selected = data.scenario.ego.id;
    $("file").textContent = `${data.file}: ${data.scenario.name} (${data.scenario.agents.length} agents)`;
    $("frame").hidden = !S.video;
    $("no-video").hidden = !!S.video;
    $("no-video").textContent = S.video ? "" : `no video: ${data.video_note}`;
    S.scenario = data.scenario;
    fitView();
    setScenario(data.scenario);
    setStatus("ready");
    window.dct.ready = true;
  }

  // hooks for tests and for the console
  window.dct = {
    S, worldToScreen, screenToWorld, ready: false,
    waypointClientXY(id, index) {
      const v = vehicleById(id);
      const [px, py] = worldToScreen(v.trajectory.x[index], v.trajectory.y[index]);
      return clientPoint(px, py);
    },
    pixelsPerMetre() { return (S.view.scale * canvas.getBoundingClientRect().width) / canvas.width; },
    setTime,
  };
  start().catch((err) => setStatus(`cannot load the scenario: ${err.message}`, true));
})();
