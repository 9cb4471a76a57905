// DeepCrashTest viewer: bird's-eye canvas, timeline, video frame, waypoint editing, simulate, save.
// World frame: x forward (drawn to the right), y left (drawn up), metres. Scenario time t in seconds.
// Edits are computed by the server (POST /api/edit); this page keeps undo/redo stacks of whole scenarios.
//
// Time: the slider is scenario time. The ONE mapping to the video is the Scenario's (scenario.py,
// Scenario.video_frame): video time = t - offset_s, frame = floor(video time * fps + 1e-6), no frame
// before 0 or from frame_count on; where the file's frame rate varies, the frame is the last one whose
// listed video time (frame_times) is not after it. The server sends offset_s, fps, frame_count and
// frame_times (/api/scenario "time"); frameIndex(), videoFrame() and frameTime() below are that mapping.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const canvas = $("bev");
  const ctx = canvas.getContext("2d");
  const READABLE_PX_PER_M = 6; // the least scale of the first view: a car 27 px long
  const READABLE_SPAN_M = 90; // the first view and "Ego": about this many metres across the canvas
  const CROSS_WINDOW_S = 0.1; // a collision's cross is drawn within this many seconds of its time
  const S = {
    file: "", scenario: null, original: null, road: null, video: null, time: null, style: null,
    undo: [], redo: [], t: 0, tmin: 0, tmax: 1, playing: false, speed: 1, selected: 0, wp: null,
    view: { scale: READABLE_PX_PER_M, ox: 40, oy: 280 }, sim: null, simStale: false, projection: null,
    drag: null, pan: null, frameShown: null, frameLoading: false, framePending: false, busy: 0, w: 900, h: 560,
  };

  // ------------------------------------------------------------------ time mapping (Scenario.video_frame)
  function frameIndex(t) {
    // the frame shown at scenario time t, not clamped to the video (Scenario.video_frame)
    const T = S.time;
    const vt = t - T.offset_s;
    const ft = T.frame_times;
    if (!ft) return Math.floor(vt * T.fps + 1e-6);
    const last = ft.length - 1;
    if (vt + 1e-6 >= ft[last] + 1 / T.fps) return last + Math.floor((vt - ft[last]) * T.fps + 1e-6);
    if (vt < ft[0] - 1e-6) return -1;
    let lo = 0;
    let hi = last;
    while (lo < hi) {
      const mid = (lo + hi + 1) >> 1;
      if (ft[mid] <= vt + 1e-6) lo = mid;
      else hi = mid - 1;
    }
    return lo;
  }
  function videoFrame(t) {
    const T = S.time;
    if (!T) return null;
    const f = frameIndex(t);
    return f < 0 || f >= T.frame_count ? null : f;
  }
  function frameTime(f) {
    const T = S.time;
    const ft = T.frame_times;
    if (!ft || f < 0) return f / T.fps + T.offset_s;
    if (f < ft.length) return ft[f] + T.offset_s;
    return ft[ft.length - 1] + (f - ft.length + 1) / T.fps + T.offset_s;
  }
  const videoTime = (t) => t - S.time.offset_s;

  // ------------------------------------------------------------------ helpers
  const vehicles = () => (S.scenario ? [S.scenario.ego, ...S.scenario.agents] : []);
  const vehicleById = (id) => vehicles().find((v) => v.id === id) || null;
  const isEgo = (v) => v.id === S.scenario.ego.id;
  const colour = (v) => (isEgo(v) ? S.style.ego : S.style.classes[v.trajectory_class] || S.style.unclassified);
  const fmt = (x, d = 2) => (x === null || x === undefined ? "-" : typeof x === "number" ? x.toFixed(d) : String(x));
  const name = (id) => (S.scenario && id === S.scenario.ego.id ? "ego" : `agent ${id}`);
  const deg = (rad) => ((((rad * 180) / Math.PI) % 360) + 540) % 360 - 180;

  function worldToScreen(x, y) {
    return [S.view.ox + x * S.view.scale, S.view.oy - y * S.view.scale];
  }
  function screenToWorld(px, py) {
    return [(px - S.view.ox) / S.view.scale, (S.view.oy - py) / S.view.scale];
  }
  function canvasPoint(e) {
    const r = canvas.getBoundingClientRect();
    return [e.clientX - r.left, e.clientY - r.top];
  }
  function clientPoint(px, py) {
    const r = canvas.getBoundingClientRect();
    return [r.left + px, r.top + py];
  }

  function sampleIndex(tr, t) {
    let lo = 0;
    let hi = tr.t.length - 1;
    while (hi - lo > 1) {
      const mid = (lo + hi) >> 1;
      if (tr.t[mid] <= t) lo = mid; else hi = mid;
    }
    return [lo, hi];
  }

  function stateAt(v, t) {
    const tr = v.trajectory;
    const n = tr.t.length;
    if (t < tr.t[0] - 1e-9 || t > tr.t[n - 1] + 1e-9 || t < v.start_delay_s - 1e-9) return null;
    const [lo, hi] = sampleIndex(tr, t);
    const a = n === 1 || hi === lo ? 0 : Math.min(Math.max((t - tr.t[lo]) / (tr.t[hi] - tr.t[lo]), 0), 1);
    const lerp = (k) => tr[k][lo] + a * (tr[k][hi] - tr[k][lo]);
    const near = a < 0.5 ? lo : hi;
    const observed = tr.observed ? tr.observed[near] : true;
    return { x: lerp("x"), y: lerp("y"), yaw: lerp("yaw"), speed: lerp("speed"), observed };
  }

  function simIndex(t) {
    const times = S.sim.times;
    let lo = 0;
    let hi = times.length - 1;
    while (hi - lo > 1) {
      const mid = (lo + hi) >> 1;
      if (times[mid] <= t) lo = mid; else hi = mid;
    }
    return Math.abs(times[hi] - t) < Math.abs(times[lo] - t) ? hi : lo;
  }

  function simStateAt(i, t) {
    const sim = S.sim;
    if (!sim || !sim.times.length || t < sim.times[0] - 1e-6 || t > sim.times[sim.times.length - 1] + 1e-6) return null;
    const k = simIndex(t);
    if (!sim.present[k][i]) return null;
    const s = sim.states[k][i];
    return s[0] === null ? null : { x: s[0], y: s[1], yaw: s[2], speed: s[3], observed: true };
  }

  function footprint(st, v) {
    // polygon (world) of a road user from above, by category (see viz/style.py CATEGORY_SHAPES)
    const c = Math.cos(st.yaw);
    const s = Math.sin(st.yaw);
    const hl = v.length / 2;
    const hw = v.width / 2;
    const shape = S.style.category_shapes[v.category] || "box";
    let local;
    if (shape === "disc") {
      const r = Math.max(hl, hw, 0.3);
      local = Array.from({ length: 12 }, (_, k) => [r * Math.cos((k * Math.PI) / 6), r * Math.sin((k * Math.PI) / 6)]);
    } else if (shape === "diamond") {
      local = [[hl, 0], [0, -hw], [-hl, 0], [0, hw]];
    } else {
      local = [[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]];
    }
    return local.map(([a, b]) => [st.x + a * c - b * s, st.y + a * s + b * c]);
  }

  function insideBox(px, py, st, v, pad = 0.3) {
    const [wx, wy] = screenToWorld(px, py);
    const dx = wx - st.x;
    const dy = wy - st.y;
    const c = Math.cos(st.yaw);
    const s = Math.sin(st.yaw);
    const padM = Math.max(pad, 4 / S.view.scale); // at least 4 px around tiny boxes
    return Math.abs(dx * c + dy * s) <= v.length / 2 + padM && Math.abs(-dx * s + dy * c) <= v.width / 2 + padM;
  }

  let toastTimer = null;
  function setStatus(text, error = false) {
    const el = $("status");
    el.textContent = text;
    el.title = text;
    el.className = error ? "error" : "";
    const toast = $("toast");
    if (error) { // the whole message, over the canvas: it never pushes the page
      toast.textContent = text;
      toast.className = "";
      toast.hidden = false;
      clearTimeout(toastTimer);
      toastTimer = setTimeout(() => { toast.hidden = true; }, 12000);
    } else {
      toast.hidden = true;
    }
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

  function niceStep(minPx) {
    const m = 10 ** Math.floor(Math.log10(minPx / S.view.scale));
    return [1, 2, 5, 10].map((k) => k * m).find((d) => d * S.view.scale >= minPx) || 10 * m;
  }

  function drawGrid() {
    const step = niceStep(70);
    const [x0, y1] = screenToWorld(0, 0);
    const [x1, y0] = screenToWorld(S.w, S.h);
    ctx.lineWidth = 1;
    ctx.strokeStyle = "rgba(255,255,255,0.09)";
    ctx.fillStyle = "rgba(255,255,255,0.6)";
    ctx.font = "10px sans-serif";
    for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
      const [px] = worldToScreen(x, 0);
      ctx.beginPath(); ctx.moveTo(px, 0); ctx.lineTo(px, S.h); ctx.stroke();
      ctx.fillText(`${+x.toFixed(6)} m`, px + 2, S.h - 6);
    }
    for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
      const [, py] = worldToScreen(0, y);
      ctx.beginPath(); ctx.moveTo(0, py); ctx.lineTo(S.w, py); ctx.stroke();
      ctx.fillText(`${+y.toFixed(6)} m`, 4, py - 2);
    }
    // axes directions and a scale bar
    ctx.fillStyle = "#fff";
    ctx.font = "11px sans-serif";
    const bx = 12;
    const by = S.h - 40;
    ctx.fillRect(bx, by, step * S.view.scale, 3);
    ctx.fillText(`${+step.toFixed(6)} m`, bx, by - 4);
    arrow(S.w - 70, S.h - 40, S.w - 30, S.h - 40);
    arrow(S.w - 70, S.h - 40, S.w - 70, S.h - 80);
    ctx.fillText("x fwd", S.w - 58, S.h - 28);
    ctx.fillText("y left", S.w - 64, S.h - 84);
  }

  function arrow(x0, y0, x1, y1, col = "#fff") {
    const a = Math.atan2(y1 - y0, x1 - x0);
    ctx.strokeStyle = col;
    ctx.fillStyle = col;
    ctx.lineWidth = 1.5;
    ctx.beginPath(); ctx.moveTo(x0, y0); ctx.lineTo(x1, y1); ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(x1, y1);
    ctx.lineTo(x1 - 7 * Math.cos(a - 0.4), y1 - 7 * Math.sin(a - 0.4));
    ctx.lineTo(x1 - 7 * Math.cos(a + 0.4), y1 - 7 * Math.sin(a + 0.4));
    ctx.closePath();
    ctx.fill();
  }

  function drawCarriageway(b, oncoming) {
    // one direction's lanes: surface, solid outer edges, dashed lane lines; the edge next to the other
    // direction (the ego carriageway's left edge, its right edge in left-hand traffic; the oncoming lanes'
    // inner edge) solid yellow
    const ownDivider = S.road.driving_side === "left" ? b[0] : b[b.length - 1];
    if (b.length >= 2) {
      polyline([...b[0], ...[...b[b.length - 1]].reverse()], true);
      ctx.fillStyle = "#555b5e";
      ctx.fill();
    }
    b.forEach((line, i) => {
      const edge = i === 0 || i === b.length - 1;
      const divider = oncoming.length > 0 && line === (b === oncoming ? b[0] : ownDivider);
      polyline(line);
      ctx.strokeStyle = divider ? "#f0c828" : "#f5f5f5";
      ctx.lineWidth = 1.5;
      ctx.setLineDash(edge ? [] : [8, 8]);
      ctx.stroke();
    });
    ctx.setLineDash([]);
  }

  function drawRoad() {
    const oncoming = S.road.oncoming || [];
    drawCarriageway(S.road.boundaries, oncoming);
    drawCarriageway(oncoming, oncoming);
  }

  function drawPath(v, opts) {
    // observed samples solid, extrapolated / lead-in / step-back samples dashed and faded
    const tr = v.trajectory;
    const obs = tr.observed;
    let start = 0;
    for (let i = 1; i <= tr.t.length; i++) {
      const runEnds = i === tr.t.length || (obs && obs[i] !== obs[start]);
      if (!runEnds) continue;
      const seen = obs ? obs[start] : true;
      const pts = [];
      for (let k = Math.max(start - 1, 0); k < i; k++) pts.push([tr.x[k], tr.y[k]]);
      polyline(pts);
      ctx.strokeStyle = opts.colour || colour(v);
      ctx.globalAlpha = (opts.alpha ?? 1) * (seen ? 1 : 0.55);
      ctx.lineWidth = opts.width ?? 1;
      ctx.setLineDash(opts.dash || (seen ? [] : [5, 4]));
      ctx.stroke();
      start = i;
    }
    ctx.setLineDash([]);
    ctx.globalAlpha = 1;
  }

  const labels = [];
  function label(text, px, py, col = "#fff", force = false) {
    ctx.font = "12px sans-serif";
    const w = ctx.measureText(text).width + 4;
    const r = [px, py - 12, px + w, py + 2];
    const hit = labels.some((q) => r[0] < q[2] && q[0] < r[2] && r[1] < q[3] && q[1] < r[3]);
    if (hit && !force) return;
    labels.push(r);
    ctx.fillStyle = "rgba(0,0,0,0.45)";
    ctx.fillRect(r[0] - 1, r[1], w, 14);
    ctx.fillStyle = col;
    ctx.fillText(text, px + 1, py);
  }

  function drawVehicle(v, st, opts) {
    const corners = footprint(st, v);
    polyline(corners, true);
    const faded = opts.ghost || !st.observed;
    ctx.globalAlpha = opts.ghost ? 0.15 : st.observed ? 0.8 : 0.35;
    ctx.fillStyle = opts.fill || colour(v);
    ctx.fill();
    ctx.globalAlpha = 1;
    ctx.setLineDash(faded ? [4, 3] : []);
    ctx.lineWidth = opts.selected || opts.hit ? 2.5 : 1;
    ctx.strokeStyle = opts.hit ? "#ff1744" : opts.selected ? "#ffeb3b" : opts.ghost ? opts.stroke || "#ffffff" : "#111";
    ctx.stroke();
    ctx.setLineDash([]);
    const shape = S.style.category_shapes[v.category] || "box";
    if (shape === "long box") { // cab line of a truck or bus
      const a = 0.3 * v.length;
      const c = Math.cos(st.yaw);
      const s = Math.sin(st.yaw);
      polyline([[st.x + a * c + (v.width / 2) * s, st.y + a * s - (v.width / 2) * c], [st.x + a * c - (v.width / 2) * s, st.y + a * s + (v.width / 2) * c]]);
      ctx.strokeStyle = "#111";
      ctx.lineWidth = 1;
      ctx.stroke();
    }
    // direction arrow from the centre to the front
    const [cx, cy] = worldToScreen(st.x, st.y);
    const reach = Math.max(v.length / 2 + 0.8, 10 / S.view.scale);
    const [fx, fy] = worldToScreen(st.x + reach * Math.cos(st.yaw), st.y + reach * Math.sin(st.yaw));
    arrow(cx, cy, fx, fy, opts.ghost ? opts.stroke || "#fff" : "#111");
    if (!opts.ghost) label(isEgo(v) ? "ego" : String(v.id), cx + 6, cy - 6, "#fff", isEgo(v) || opts.selected);
  }

  function drawCross(px, py, text) {
    ctx.strokeStyle = "#ff1744";
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.moveTo(px - 9, py - 9); ctx.lineTo(px + 9, py + 9);
    ctx.moveTo(px + 9, py - 9); ctx.lineTo(px - 9, py + 9);
    ctx.stroke();
    label(text, px + 10, py + 16, "#ff8a80", true);
  }

  function changed(v) {
    const o = S.original && S.original.get(v.id);
    if (!o) return false;
    const tr = v.trajectory;
    if (o.x.length !== tr.x.length) return true;
    for (let i = 0; i < tr.x.length; i++) if (o.x[i] !== tr.x[i] || o.y[i] !== tr.y[i]) return true;
    return false;
  }

  function activeCollisions() {
    // collisions whose time is within CROSS_WINDOW_S of now: [{pair, point, text}]
    const out = [];
    for (const c of allCollisions()) {
      if (Math.abs(c.t - S.t) <= CROSS_WINDOW_S) out.push(c);
    }
    return out;
  }

  function draw() {
    ctx.setTransform(devicePixelRatio, 0, 0, devicePixelRatio, 0, 0);
    ctx.fillStyle = "#3b4a3f";
    ctx.fillRect(0, 0, S.w, S.h);
    if (!S.scenario) return;
    labels.length = 0;
    if ($("follow").checked) centreOnEgo(false);
    drawRoad();
    drawGrid();
    const showSim = S.sim && $("show-sim").checked;
    const showOriginal = $("show-original").checked;
    for (const v of vehicles()) {
      if (showOriginal && changed(v)) {
        const o = S.original.get(v.id);
        drawPath({ ...v, trajectory: o }, { colour: "#e0e0e0", dash: [2, 3], alpha: 0.8 });
      }
      drawPath(v, { alpha: v.id === S.selected ? 1 : 0.6, width: v.id === S.selected ? 2.5 : 1.2 });
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
    if (sel) drawWaypoints(sel);
    const active = activeCollisions();
    const hitIds = new Set(active.flatMap((c) => c.pair));
    if (showOriginal) {
      for (const v of vehicles()) {
        if (!changed(v)) continue;
        const st = stateAt({ ...v, trajectory: S.original.get(v.id) }, S.t);
        if (st) drawVehicle(v, st, { ghost: true, stroke: "#e0e0e0" });
      }
    }
    const drawn = vehicles().map((v) => [v, stateAt(v, S.t)]).filter(([, st]) => st);
    drawn.sort(([a], [b]) => (a.id === S.selected) - (b.id === S.selected) || isEgo(a) - isEgo(b)); // on top last
    for (const [v, st] of drawn) drawVehicle(v, st, { selected: v.id === S.selected, hit: hitIds.has(v.id) });
    if (showSim) {
      S.sim.vehicle_ids.forEach((id, i) => {
        const v = vehicleById(id);
        const st = simStateAt(i, S.t);
        if (v && st) drawVehicle(v, st, { ghost: true });
      });
    }
    for (const c of active) {
      if (c.point) {
        const [px, py] = worldToScreen(c.point[0], c.point[1]);
        drawCross(px, py, `${c.kind}: ${c.pair.map(name).join(" x ")}`);
      }
    }
  }

  function drawWaypoints(v) {
    const tr = v.trajectory;
    let last = null;
    for (let i = 0; i < tr.t.length; i++) {
      let [x, y] = [tr.x[i], tr.y[i]];
      if (S.drag && S.drag.index === i) [x, y] = [S.drag.x, S.drag.y];
      const [px, py] = worldToScreen(x, y);
      const special = i === S.wp || (S.drag && S.drag.index === i);
      if (!special && last && Math.hypot(px - last[0], py - last[1]) < 6) continue; // dense samples: every few
      last = [px, py];
      ctx.beginPath();
      ctx.arc(px, py, special ? 5 : 2.5, 0, 2 * Math.PI);
      ctx.fillStyle = special ? "#ffeb3b" : tr.observed && !tr.observed[i] ? "#bdbdbd" : "#ffffff";
      ctx.fill();
      ctx.strokeStyle = "#111";
      ctx.lineWidth = 1;
      ctx.stroke();
    }
  }

  function bringIntoView(x, y) {
    // centre the view on world (x, y) when it is off the canvas (or under the legend / tools)
    const [px, py] = worldToScreen(x, y);
    const c = canvas.getBoundingClientRect();
    const l = $("legend").getBoundingClientRect();
    const underLegend = px > l.left - c.left - 30 && py < l.bottom - c.top + 30;
    if (px < 40 || py < 60 || px > S.w - 40 || py > S.h - 40 || underLegend) {
      $("follow").checked = false;
      S.view.ox = S.w / 2 - x * S.view.scale;
      S.view.oy = S.h / 2 + y * S.view.scale;
    }
  }

  function bounds() {
    let [x0, x1, y0, y1] = [Infinity, -Infinity, Infinity, -Infinity];
    const add = (x, y) => { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); };
    for (const v of vehicles()) v.trajectory.x.forEach((x, i) => add(x, v.trajectory.y[i]));
    return [x0, x1, y0, y1];
  }

  function fitView() {
    const [x0, x1, y0, y1] = bounds();
    const scale = 0.9 * Math.min(S.w / Math.max(x1 - x0, 1), S.h / Math.max(y1 - y0, 1));
    S.view.scale = scale;
    S.view.ox = S.w / 2 - ((x0 + x1) / 2) * scale;
    S.view.oy = S.h / 2 + ((y0 + y1) / 2) * scale;
  }

  function centreOnEgo(rescale) {
    const ego = S.scenario.ego;
    const tr = ego.trajectory;
    const st = stateAt(ego, Math.min(Math.max(S.t, tr.t[0]), tr.t[tr.t.length - 1]));
    if (rescale) S.view.scale = readableScale();
    S.view.ox = S.w / 2 - st.x * S.view.scale;
    S.view.oy = S.h / 2 + st.y * S.view.scale;
  }

  const readableScale = () => Math.max(READABLE_PX_PER_M, S.w / READABLE_SPAN_M);

  function firstView() {
    fitView();
    if (S.view.scale < readableScale()) { // too far out to read the boxes: centre on the ego instead
      S.view.scale = readableScale();
      centreOnEgo(false);
    }
  }

  function resize() {
    const wrap = $("bev-wrap");
    const w = Math.max(wrap.clientWidth, 50);
    const h = Math.max(wrap.clientHeight, 50);
    if (S.scenario) { // keep the world point at the centre where it was
      S.view.ox += (w - S.w) / 2;
      S.view.oy += (h - S.h) / 2;
    }
    S.w = w;
    S.h = h;
    canvas.width = Math.round(w * devicePixelRatio);
    canvas.height = Math.round(h * devicePixelRatio);
    draw();
    drawOverlay();
  }

  // ------------------------------------------------------------------ legend
  function buildLegend() {
    const st = S.style;
    const used = new Set(S.scenario.agents.map((a) => a.trajectory_class || "unclassified"));
    const cats = new Set(vehicles().map((v) => v.category));
    const rows = [[st.ego, "ego (the camera car)", ""]];
    for (const [k, col] of Object.entries(st.classes)) {
      if (used.has(k)) rows.push([col, `${k} ${st.class_short[k]}`, st.class_descriptions[k]]);
    }
    if (used.has("unclassified")) rows.push([st.unclassified, "unclassified", ""]);
    const rowsExtra = [
      ["border-top:2px solid #333", "observed path", ""],
      ["border-top:2px dashed #777", "not observed (extrapolated, lead-in, step-back)", st.observed_note],
      ["border-top:2px dotted #999", "original, before your edits", ""],
      ["border:1px dashed #555;background:#fff", "simulated (after Simulate)", ""],
      ["background:#ff1744;height:3px", "collision (cross at its time only)", ""],
    ];
    const body = $("legend-body");
    body.innerHTML = "";
    for (const [css, text, title] of [...rows.map(([c, t, d]) => [`background:${c}`, t, d]), ...rowsExtra]) {
      const r = document.createElement("div");
      r.className = "row";
      r.title = title;
      r.innerHTML = `<span class="sw" style="${css}"></span>`;
      r.appendChild(document.createTextNode(text));
      body.appendChild(r);
    }
    const note = document.createElement("div");
    note.className = "note";
    const shapes = [...cats].map((c) => `${c} ${st.category_shapes[c] || "box"}`).join(", ");
    note.textContent = `shapes: ${shapes}; arrow: heading; yellow: selected`;
    body.appendChild(note);
    const help = document.createElement("details");
    help.innerHTML = "<summary>mouse and keys</summary>";
    help.appendChild(document.createTextNode(
      "Drag empty space to pan, wheel to zoom, click a box to select it, drag the selected one's waypoints to " +
      "move them. Space: play/pause; Left/Right: one video frame (Shift: 1 s); Home/End; F: fit all; E: ego; " +
      "Ctrl+Z/Ctrl+Y: undo/redo.",
    ));
    body.appendChild(help);
  }

  // ------------------------------------------------------------------ panels
  function refreshPanels() {
    const sel = $("vehicle");
    const keep = S.selected;
    sel.innerHTML = "";
    for (const v of vehicles()) {
      const o = document.createElement("option");
      o.value = String(v.id);
      o.textContent = isEgo(v) ? `ego (${v.id})` : `agent ${v.id} ${v.category} ${v.trajectory_class || ""}`;
      sel.appendChild(o);
    }
    sel.value = String(keep);
    const v = vehicleById(S.selected);
    if (v) {
      const tr = v.trajectory;
      const nObs = tr.observed ? tr.observed.filter(Boolean).length : tr.t.length;
      $("vehicle-info").textContent =
        `${v.category}${v.trajectory_class ? ` ${v.trajectory_class}` : ""}, ${v.length.toFixed(2)} x ${v.width.toFixed(2)} m, ` +
        `${tr.t.length} samples (${nObs} observed), t ${tr.t[0].toFixed(2)}-${tr.t[tr.t.length - 1].toFixed(2)} s` +
        (v.spline ? ", spline" : "");
    }
    if (v && S.wp !== null && S.wp < v.trajectory.t.length) {
      const tr = v.trajectory;
      const seen = tr.observed ? (tr.observed[S.wp] ? "observed" : "not observed") : "observed";
      $("waypoint-label").textContent = `waypoint #${S.wp} at t=${tr.t[S.wp].toFixed(2)} s (${seen})`;
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
    refreshReadout();
  }

  function refreshReadout() {
    const v = vehicleById(S.selected);
    const el = $("vehicle-state");
    if (!v) { el.textContent = ""; return; }
    const st = stateAt(v, S.t);
    el.textContent = st
      ? `at t=${S.t.toFixed(2)} s: x ${st.x.toFixed(2)} m, y ${st.y.toFixed(2)} m\n` +
        `speed ${st.speed.toFixed(2)} m/s (${(st.speed * 3.6).toFixed(1)} km/h), heading ${deg(st.yaw).toFixed(1)} deg, ` +
        (st.observed ? "observed" : "extrapolated")
      : `not in the scenario at t=${S.t.toFixed(2)} s`;
  }

  function egoCollision() {
    // the simulated collision of the ego (its entry carries the ego's delta-v)
    if (!S.sim) return null;
    const ego = S.scenario.ego.id;
    return (S.sim.collisions || []).find((c) => c.vehicles.includes(ego)) || null;
  }

  function timeText(t) {
    const f = videoFrame(t);
    return f === null ? `${t.toFixed(2)} s (outside the video)` : `${t.toFixed(2)} s (video ${videoTime(t).toFixed(2)} s, frame ${f})`;
  }

  function showOutcome() {
    const dl = $("outcome");
    dl.innerHTML = "";
    if (!S.sim) { refreshCollisionList(); return; }
    const m = S.sim.metrics;
    const ec = egoCollision();
    const egoId = String(S.scenario.ego.id);
    const dvEgo = m.delta_v_ego ?? (ec && ec.delta_v ? ec.delta_v[egoId] : null);
    const n = (S.sim.collisions || []).length;
    const rows = [
      ["ego collided", m.collided ? "yes" : "no"],
      ["collision time", m.collided ? timeText(m.collision_time) : "-"],
      ["with", m.collision_vehicle === null || m.collision_vehicle === undefined ? "-" : name(m.collision_vehicle)],
      ["delta-v ego", `${fmt(dvEgo)} m/s`],
      ["relative speed", `${fmt(m.relative_speed ?? (ec ? ec.relative_speed : null))} m/s`],
      ["min distance", `${fmt(m.min_distance)} m`],
      ["min TTC", `${fmt(m.min_ttc)} s`],
      ["all collisions", `${n} (${n - (ec ? 1 : 0)} without the ego)`],
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
    refreshCollisionList();
  }

  function allCollisions() {
    // every collision: the scenario's (from the video, labels or the user) and every simulated one
    const out = [];
    const c = S.scenario && S.scenario.collision;
    if (c) {
      out.push({
        kind: c.source === "simulated" ? "simulated" : c.source === "user" ? "user" : "video",
        t: c.time_s, pair: [c.other_id, c.agent_id],
        point: c.x !== null && c.y !== null ? [c.x, c.y] : null,
        text: `${c.source}: ${name(c.other_id)} x ${name(c.agent_id)}` +
          (c.relative_speed !== null ? `, ${c.relative_speed.toFixed(2)} m/s` : ""),
      });
    }
    if (S.sim && $("show-sim").checked) {
      for (const s of S.sim.collisions || []) {
        const dv = Object.entries(s.delta_v || {}).filter(([, v]) => v !== null).map(([k, v]) => `dv ${name(Number(k))} ${v.toFixed(2)}`);
        out.push({
          kind: "sim", t: s.time, pair: s.vehicles, point: s.point && s.point[0] !== null ? s.point : null,
          text: `simulated: ${s.vehicles.map(name).join(" x ")}, ${fmt(s.relative_speed)} m/s` + (dv.length ? `, ${dv.join(", ")} m/s` : ""),
        });
      }
    }
    return out;
  }

  function refreshCollisionList() {
    const list = $("collision-list");
    const strip = $("markers");
    list.innerHTML = "";
    strip.innerHTML = "";
    for (const c of allCollisions()) {
      const jump = () => {
        S.selected = c.pair.includes(S.scenario.ego.id) ? c.pair.find((id) => id !== S.scenario.ego.id) : c.pair[0];
        S.wp = null;
        if (c.point) bringIntoView(c.point[0], c.point[1]);
        setTime(c.t);
        refreshPanels();
      };
      const li = document.createElement("li");
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = `t=${c.t.toFixed(2)} s`;
      b.addEventListener("click", jump);
      li.append(b, document.createTextNode(` ${c.text}`));
      list.appendChild(li);
      const mk = document.createElement("button");
      mk.type = "button";
      mk.className = `marker ${c.kind === "sim" ? "sim" : "video"}`;
      mk.style.left = `${pct(c.t)}%`;
      mk.title = `${c.text} at ${timeText(c.t)}: click to jump`;
      mk.dataset.t = String(c.t);
      mk.dataset.pair = c.pair.join("-");
      mk.addEventListener("click", jump);
      strip.appendChild(mk);
    }
    markActive();
  }

  function markActive() {
    for (const mk of $("markers").children) mk.classList.toggle("active", Math.abs(Number(mk.dataset.t) - S.t) <= CROSS_WINDOW_S);
  }

  // slider position (percent of the track, with the thumb's inset) of a time
  function pct(t) {
    return ((t - S.tmin) / Math.max(S.tmax - S.tmin, 1e-9)) * 100;
  }

  function updateTimeRange() {
    let tmin = 0;
    let tmax = 0;
    for (const v of vehicles()) {
      tmin = Math.min(tmin, v.trajectory.t[0]);
      tmax = Math.max(tmax, v.trajectory.t[v.trajectory.t.length - 1]);
    }
    if (S.sim && S.sim.times.length) tmax = Math.max(tmax, S.sim.times[S.sim.times.length - 1]);
    if (S.video && S.time.frame_count > 0) {
      tmin = Math.min(tmin, S.time.video_start_s);
      tmax = Math.max(tmax, S.time.video_end_s - 1 / S.time.fps);
    }
    S.tmin = tmin;
    S.tmax = Math.max(tmax, tmin + 0.01);
    $("time").min = String(S.tmin);
    $("time").max = String(S.tmax);
    const span = $("video-span");
    if (S.time.frame_count > 0) {
      const a = pct(S.time.video_start_s);
      const b = pct(S.time.video_end_s);
      span.hidden = false;
      span.style.left = `${Math.max(a, 0)}%`;
      span.style.width = `${Math.max(Math.min(b, 100) - Math.max(a, 0), 0)}%`;
      span.title = `the video: scenario t ${S.time.video_start_s.toFixed(2)}-${S.time.video_end_s.toFixed(2)} s`;
    } else {
      span.hidden = true;
    }
    refreshCollisionList();
    setTime(Math.min(Math.max(S.t, S.tmin), S.tmax));
  }

  // ------------------------------------------------------------------ time and video
  function setTime(t) {
    S.t = Math.min(Math.max(t, S.tmin), S.tmax);
    $("time").value = String(S.t);
    const f = videoFrame(S.t);
    $("time-label").textContent = `t ${S.t.toFixed(2)} s | ` + (f === null ? "no video frame" : `video ${videoTime(S.t).toFixed(2)} s #${f}`);
    draw();
    refreshReadout();
    markActive();
    requestFrame();
  }

  function requestFrame() {
    const f = videoFrame(S.t);
    const img = $("frame");
    const msg = $("no-video");
    if (!S.video) return;
    if (f === null) {
      const before = S.t < S.time.video_start_s;
      img.hidden = true;
      $("overlay").hidden = true;
      msg.hidden = false;
      msg.className = "outside";
      msg.textContent = before
        ? `before the video: it starts at scenario t = ${S.time.video_start_s.toFixed(2)} s (the lead-in is extrapolated)`
        : `after the video: it ended at scenario t = ${S.time.video_end_s.toFixed(2)} s`;
      $("video-caption").textContent = "";
      S.frameShown = null;
      return;
    }
    msg.hidden = true;
    img.hidden = false;
    drawOverlay();
    if (f === S.frameShown && !S.framePending) return;
    if (S.frameLoading) { S.framePending = true; return; }
    S.frameLoading = true;
    S.frameShown = f;
    img.src = `/api/frame?frame=${f}`;
    S.caption = `frame ${f}, video ${videoTime(frameTime(f)).toFixed(2)} s = scenario ${frameTime(f).toFixed(2)} s`;
    $("video-caption").textContent = S.caption;
  }

  function frameDone() {
    S.frameLoading = false;
    if (S.framePending) { S.framePending = false; requestFrame(); }
  }

  // projected 3D boxes of the simulated (or, before a run, the scenario's) road users over the frame
  function drawOverlay() {
    const oc = $("overlay");
    const P = S.projection;
    const f = videoFrame(S.t);
    const boxes = P && f !== null ? P.frames[String(f)] : null;
    if (!boxes || !S.video || $("frame").hidden) {
      oc.hidden = true;
      if (S.caption && !$("frame").hidden) $("video-caption").textContent = S.caption;
      return;
    }
    oc.hidden = false;
    const r = oc.getBoundingClientRect();
    oc.width = Math.round(r.width * devicePixelRatio);
    oc.height = Math.round(r.height * devicePixelRatio);
    const g = oc.getContext("2d");
    const k = Math.min(r.width / P.width, r.height / P.height); // object-fit: contain
    const ox = (r.width - k * P.width) / 2;
    const oy = (r.height - k * P.height) / 2;
    g.setTransform(devicePixelRatio * k, 0, 0, devicePixelRatio * k, devicePixelRatio * ox, devicePixelRatio * oy);
    for (const [id, segments] of boxes) {
      const v = vehicleById(id);
      g.strokeStyle = v ? colour(v) : "#fff";
      g.lineWidth = 2 / k;
      g.beginPath();
      for (const [u0, v0, u1, v1] of segments) {
        g.moveTo(u0, v0);
        g.lineTo(u1, v1);
      }
      g.stroke();
    }
    $("video-caption").textContent = `${S.caption} | 3D boxes: ${P.source}`;
  }

  async function refreshProjection() {
    if (!S.video) return;
    const body = { scenario: S.scenario };
    if (S.sim && $("show-sim").checked) body.sim = { times: S.sim.times, vehicle_ids: S.sim.vehicle_ids, states: S.sim.states };
    try {
      S.projection = await api("/api/project", body);
    } catch (err) {
      S.projection = null;
    }
    drawOverlay();
  }

  let lastTick = null;
  function tick(now) {
    if (!S.playing) return;
    if (lastTick !== null) setTime(S.t + (S.speed * (now - lastTick)) / 1000);
    lastTick = now;
    if (S.t >= S.tmax) { togglePlay(false); return; }
    requestAnimationFrame(tick);
  }
  function togglePlay(on) {
    S.playing = on === undefined ? !S.playing : on;
    $("play").textContent = S.playing ? "Pause" : "Play";
    if (S.playing) {
      if (S.t >= S.tmax) setTime(S.tmin);
      lastTick = null;
      requestAnimationFrame(tick);
    }
  }

  function stepFrames(n) {
    // one video frame per step (between frames: the time grid of the video, continued outside it)
    togglePlay(false);
    setTime(frameTime(frameIndex(S.t) + n));
  }

  // ------------------------------------------------------------------ edits
  function setScenario(sc) {
    S.scenario = sc;
    if (!vehicleById(S.selected)) S.selected = sc.ego.id;
    if (S.sim) S.simStale = true;
    refreshPanels();
    showOutcome();
    updateTimeRange();
    scheduleProjection();
  }

  let projTimer = null;
  function scheduleProjection() {
    clearTimeout(projTimer);
    projTimer = setTimeout(refreshProjection, 300);
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
    let bestD = 6;
    v.trajectory.x.forEach((x, i) => {
      const [sx, sy] = worldToScreen(x, v.trajectory.y[i]);
      const d = Math.hypot(sx - px, sy - py);
      if (d <= bestD) { bestD = d; best = i; }
    });
    return best;
  }

  function vehicleAt(px, py, pad = 0.3) {
    // topmost road user whose box (at the current time) contains the point
    for (const v of [...vehicles()].reverse()) {
      const st = stateAt(v, S.t);
      if (st && insideBox(px, py, st, v, pad)) return [v, st];
    }
    return null;
  }

  canvas.addEventListener("mousedown", (e) => {
    if (!S.scenario) return;
    canvas.focus();
    const [px, py] = canvasPoint(e);
    // another road user's box wins over the selected vehicle's waypoints under it: select it
    const hit = vehicleAt(px, py);
    if (hit && hit[0].id !== S.selected) {
      S.selected = hit[0].id;
      S.wp = null;
      refreshPanels();
      draw();
      return;
    }
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
    S.pan = { px, py, ox: S.view.ox, oy: S.view.oy };
    if (!hit) $("follow").checked = false;
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

  canvas.addEventListener("mousemove", (e) => {
    const hover = $("hover");
    if (!S.scenario || S.drag || S.pan) { hover.hidden = true; return; }
    const [px, py] = canvasPoint(e);
    const [wx, wy] = screenToWorld(px, py);
    let text = `x ${wx.toFixed(1)} m, y ${wy.toFixed(1)} m`;
    const hit = vehicleAt(px, py, 0);
    if (hit) {
      const [v, st] = hit;
      text = `${name(v.id)}: ${v.category}${v.trajectory_class ? ` ${v.trajectory_class}` : ""}\n` +
        `speed ${st.speed.toFixed(1)} m/s (${(st.speed * 3.6).toFixed(0)} km/h)\nheading ${deg(st.yaw).toFixed(0)} deg\n` +
        `${st.observed ? "observed" : "extrapolated / not seen"}\n${text}`;
    } else {
      const i = hitWaypoint(px, py);
      const v = vehicleById(S.selected);
      if (i !== null && v) {
        const tr = v.trajectory;
        text = `${name(v.id)} waypoint #${i}, t=${tr.t[i].toFixed(2)} s\nspeed ${tr.speed[i].toFixed(1)} m/s, ` +
          `${tr.observed && !tr.observed[i] ? "extrapolated" : "observed"}\n${text}`;
      }
    }
    hover.textContent = text;
    hover.hidden = false;
    hover.style.left = `${Math.min(px + 14, S.w - 200)}px`;
    hover.style.top = `${Math.min(py + 14, S.h - 80)}px`;
  });
  canvas.addEventListener("mouseleave", () => { $("hover").hidden = true; });

  window.addEventListener("mouseup", () => {
    if (S.drag) {
      const d = S.drag;
      S.drag = null;
      if (d.moved) {
        let falloff = 1.5;
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
    S.view.scale = Math.min(Math.max(S.view.scale * Math.exp(-e.deltaY * 0.0015), 0.02), 400);
    S.view.ox = px - wx * S.view.scale;
    S.view.oy = py + wy * S.view.scale;
    draw();
  }, { passive: false });

  // ------------------------------------------------------------------ buttons
  $("vehicle").addEventListener("change", (e) => {
    S.selected = Number(e.target.value);
    S.wp = null;
    const v = vehicleById(S.selected);
    const st = v && (stateAt(v, S.t) || stateAt(v, v.trajectory.t[0]));
    if (st) bringIntoView(st.x, st.y);
    refreshPanels();
    draw();
  });
  $("time").addEventListener("input", (e) => { togglePlay(false); setTime(Number(e.target.value)); });
  $("play").addEventListener("click", () => togglePlay());
  $("step-back").addEventListener("click", () => stepFrames(-1));
  $("step-fwd").addEventListener("click", () => stepFrames(1));
  $("speed").addEventListener("change", (e) => { S.speed = Number(e.target.value); });
  $("undo").addEventListener("click", undo);
  $("redo").addEventListener("click", redo);
  $("show-sim").addEventListener("change", () => { refreshCollisionList(); draw(); scheduleProjection(); });
  $("show-original").addEventListener("change", draw);
  $("follow").addEventListener("change", draw);
  $("fit").addEventListener("click", () => { $("follow").checked = false; fitView(); draw(); });
  $("to-ego").addEventListener("click", () => { centreOnEgo(true); draw(); });
  $("frame").addEventListener("load", frameDone);
  $("frame").addEventListener("error", frameDone);
  $("toast").addEventListener("click", () => { $("toast").hidden = true; });

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
      scheduleProjection();
      const m = S.sim.metrics;
      const n = (S.sim.collisions || []).length;
      setStatus(`simulated: ${m.collided ? `ego collision at ${fmt(m.collision_time)} s` : "no ego collision"}, ${n} collision(s) in all`);
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
    const typing = (e.target instanceof HTMLInputElement && e.target.type !== "range" && e.target.type !== "checkbox") ||
      e.target instanceof HTMLSelectElement || e.target instanceof HTMLTextAreaElement;
    if (typing) return;
    const mod = e.ctrlKey || e.metaKey;
    const key = e.key;
    if (mod && key.toLowerCase() === "z" && !e.shiftKey) { e.preventDefault(); undo(); }
    else if (mod && (key.toLowerCase() === "y" || (key.toLowerCase() === "z" && e.shiftKey))) { e.preventDefault(); redo(); }
    else if (mod) return;
    else if (key === " ") { e.preventDefault(); togglePlay(); }
    else if (key === "ArrowRight") { e.preventDefault(); if (e.shiftKey) setTime(S.t + 1); else stepFrames(1); }
    else if (key === "ArrowLeft") { e.preventDefault(); if (e.shiftKey) setTime(S.t - 1); else stepFrames(-1); }
    else if (key === "Home") { e.preventDefault(); setTime(S.tmin); }
    else if (key === "End") { e.preventDefault(); setTime(S.tmax); }
    else if (key === "f" || key === "F") { fitView(); draw(); }
    else if (key === "e" || key === "E") { centreOnEgo(true); draw(); }
  });

  new ResizeObserver(resize).observe($("bev-wrap"));
  new ResizeObserver(drawOverlay).observe($("video-wrap"));

  // ------------------------------------------------------------------ start
  async function start() {
    const r = await fetch("/api/scenario");
    const data = await r.json();
    if (!r.ok) { setStatus(data.error || `HTTP ${r.status}`, true); return; }
    S.file = data.file;
    S.road = data.road;
    S.video = data.video;
    S.time = data.time;
    S.style = data.style;
    S.selected = data.scenario.ego.id;
    S.original = new Map([data.scenario.ego, ...data.scenario.agents].map((v) => [v.id, v.trajectory]));
    $("falloff").value = String(data.default_falloff_s);
    $("file").textContent = `${data.file}: ${data.scenario.name} (${data.scenario.agents.length} road users besides the ego)`;
    $("frame").hidden = !S.video;
    $("no-video").hidden = !!S.video;
    $("no-video").textContent = S.video ? "" : `no video: ${data.video_note}`;
    S.scenario = data.scenario;
    resize();
    buildLegend();
    firstView();
    setScenario(data.scenario);
    setStatus("ready");
    window.dct.ready = true;
  }

  // hooks for tests and for the console
  window.dct = {
    S, worldToScreen, screenToWorld, videoFrame, frameTime, ready: false,
    waypointClientXY(id, index) {
      const v = vehicleById(id);
      const [px, py] = worldToScreen(v.trajectory.x[index], v.trajectory.y[index]);
      return clientPoint(px, py);
    },
    vehicleClientXY(id) {
      const st = stateAt(vehicleById(id), S.t);
      return st ? clientPoint(...worldToScreen(st.x, st.y)) : null;
    },
    clientXY(x, y) { return clientPoint(...worldToScreen(x, y)); },
    pixelsPerMetre() { return S.view.scale; },
    setTime, setStatus,
  };
  start().catch((err) => setStatus(`cannot load the scenario: ${err.message}`, true));
})();
