// brightpix view: draws what the server sends over its WebSocket
// (host/src/view/encode.rs documents the messages). Plain canvas; no
// library, nothing fetched from the network. Read-only: the page sends
// nothing but the WebSocket's own frames.
"use strict";

const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf"];
const HISTORY = 300; // samples kept for the time series

const view = {
  setup: null,
  results: null, // {frame, seen, dropped, rate, sx, sy, flux, state}
  pixels: null, // {width, height, frame, pixels, mask}
  health: null,
  chosen: [], // sub-aperture indices followed in the time series
  series: new Map(), // index -> {x: [], y: []}
  rates: [],
  updates: 0, // results drawn
  received: 0, // results received (more than drawn when the page is slower)
  drawn: 0, // `received` when last drawn
  pixelUpdates: 0,
  dirty: false,
  // The camera image and the N map are redrawn only when they change (a
  // 1280x1280 camera is 1.6 M pixels to colour).
  pixelsDirty: false,
  setupDirty: false,
};

const $ = (id) => document.getElementById(id);
const counts = $("counts");

function setCount(name, value) {
  counts.dataset[name] = String(value);
}

// --- messages ------------------------------------------------------------------

function onText(text) {
  const m = JSON.parse(text);
  if (m.type === "setup") {
    view.setup = m;
    view.results = null;
    view.pixels = null;
    view.chosen = view.chosen.filter((s) => s < m.windows.length);
    view.setupDirty = true;
    view.pixelsDirty = true;
    view.series.clear();
    const name = m.config.split("/").pop();
    $("source").textContent = `${m.source} · ${name} (digest ${m.digest}, ${m.windows.length} sub-apertures, ${m.camera.width}x${m.camera.height})`;
    $("source").title = m.config;
    $("camera-note").textContent = m.pixels
      ? "Selected pixels (the host reference's kept set, for display) in orange."
      : "No pixels from this source (a device's own camera, or a replay without frames).";
    setCount("subapertures", m.windows.length);
  } else if (m.type === "waiting") {
    view.setup = null;
    $("source").textContent = "waiting for a source…";
  } else if (m.type === "health") {
    view.health = m;
  } else if (m.type === "message") {
    const banner = $("banner");
    banner.hidden = !m.text;
    banner.textContent = m.text || "";
    setCount("message", m.text || "");
  }
  view.dirty = true;
}

function onBinary(buffer) {
  const kind = new Uint8Array(buffer, 0, 1)[0];
  const dv = new DataView(buffer);
  if (kind === 1) {
    const n = dv.getUint32(4, true);
    const r = {
      frame: dv.getFloat64(8, true),
      seen: dv.getFloat64(16, true),
      dropped: dv.getFloat64(24, true),
      rate: dv.getFloat64(32, true),
      sx: new Float32Array(buffer, 40, n),
      sy: new Float32Array(buffer, 40 + 4 * n, n),
      flux: new Float32Array(buffer, 40 + 8 * n, n),
      state: new Uint8Array(buffer, 40 + 12 * n, n),
    };
    view.results = r;
    view.received += 1;
    for (const s of view.chosen) {
      if (s >= n) continue;
      const h = view.series.get(s) || { x: [], y: [] };
      h.x.push(r.state[s] === 2 ? r.sx[s] : NaN);
      h.y.push(r.state[s] === 2 ? r.sy[s] : NaN);
      if (h.x.length > HISTORY) { h.x.shift(); h.y.shift(); }
      view.series.set(s, h);
    }
    view.rates.push(r.rate);
    if (view.rates.length > HISTORY) view.rates.shift();
  } else if (kind === 2) {
    const width = dv.getUint32(4, true);
    const height = dv.getUint32(8, true);
    const area = width * height;
    view.pixels = {
      width,
      height,
      frame: dv.getFloat64(16, true),
      pixels: new Uint16Array(buffer, 24, area),
      mask: new Uint8Array(buffer, 24 + 2 * area, area),
    };
    view.pixelUpdates += 1;
    view.pixelsDirty = true;
  }
  view.dirty = true;
}

function connect() {
  const conn = $("conn");
  const ws = new WebSocket(`ws://${location.host}/ws`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { conn.dataset.state = "open"; conn.textContent = "live"; };
  ws.onmessage = (e) => (typeof e.data === "string" ? onText(e.data) : onBinary(e.data));
  ws.onclose = () => {
    conn.dataset.state = "closed";
    conn.textContent = "view server gone: retrying";
    setTimeout(connect, 1000);
  };
}

// --- drawing -------------------------------------------------------------------

// Camera pixels to canvas pixels for a canvas of `size` (the longer side).
function fit(canvas, size) {
  const cam = view.setup.camera;
  const scale = size / Math.max(cam.width, cam.height);
  const w = Math.round(cam.width * scale), h = Math.round(cam.height * scale);
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  return scale;
}

function drawPupil() {
  const canvas = $("pupil"), ctx = canvas.getContext("2d");
  const k = fit(canvas, 420);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const wins = view.setup.windows, r = view.results;
  const gain = Number($("scale").value);
  let valid = 0, invalid = 0, arrows = 0;
  ctx.lineWidth = 1;
  ctx.strokeStyle = "#ccd";
  ctx.beginPath();
  for (const [x, y, w, h] of wins) ctx.rect(x * k + 0.5, y * k + 0.5, w * k - 1, h * k - 1);
  ctx.stroke();
  if (r) {
    const none = new Path2D(), bad = new Path2D(), arrow = new Path2D();
    for (let s = 0; s < wins.length && s < r.state.length; s++) {
      const [x, y, w, h] = wins[s];
      const cx = (x + w / 2) * k, cy = (y + h / 2) * k, d = Math.min(w, h) * k * 0.25;
      if (r.state[s] === 0) {
        none.rect(x * k + 1, y * k + 1, w * k - 2, h * k - 2);
      } else if (r.state[s] === 1) {
        invalid += 1;
        bad.moveTo(cx - d, cy - d); bad.lineTo(cx + d, cy + d);
        bad.moveTo(cx + d, cy - d); bad.lineTo(cx - d, cy + d);
      } else {
        valid += 1;
        const ex = cx + r.sx[s] * k * gain, ey = cy + r.sy[s] * k * gain;
        arrow.moveTo(cx, cy); arrow.lineTo(ex, ey);
        const len = Math.hypot(ex - cx, ey - cy);
        if (len > 2) {
          const ux = (ex - cx) / len, uy = (ey - cy) / len, head = Math.min(len * 0.4, 2 + w * k * 0.12);
          arrow.moveTo(ex, ey); arrow.lineTo(ex - head * (ux - uy * 0.5), ey - head * (uy + ux * 0.5));
          arrow.moveTo(ex, ey); arrow.lineTo(ex - head * (ux + uy * 0.5), ey - head * (uy - ux * 0.5));
        } else {
          arrow.moveTo(cx + 1.5, cy); arrow.arc(cx, cy, 1.5, 0, 2 * Math.PI);
        }
        arrows += 1;
      }
    }
    ctx.fillStyle = "#ddd"; ctx.fill(none);
    ctx.strokeStyle = "#d22"; ctx.lineWidth = 1.5; ctx.stroke(bad);
    ctx.strokeStyle = "#123"; ctx.lineWidth = 1.2; ctx.stroke(arrow);
  }
  view.chosen.forEach((s, i) => {
    const [x, y, w, h] = wins[s];
    ctx.strokeStyle = COLORS[i % COLORS.length]; ctx.lineWidth = 2;
    ctx.strokeRect(x * k + 1, y * k + 1, w * k - 2, h * k - 2);
  });
  setCount("valid", valid);
  setCount("invalid", invalid);
  setCount("arrows", arrows);
}

// 256 colours of the maps, made once: building a CSS colour string per
// window per frame costs more than the drawing at 80x80.
const MAP_COLORS = Array.from({ length: 256 }, (_, i) => {
  const c = Math.round(30 + (200 * i) / 255);
  return `rgb(${c},${Math.round(c * 0.85)},${Math.round(90 + 0.5 * c)})`;
});

function drawMap(id, values, label, format) {
  const canvas = $(id), ctx = canvas.getContext("2d");
  const k = fit(canvas, 260);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  let lo = Infinity, hi = -Infinity;
  for (const v of values) if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  const wins = view.setup.windows;
  for (let s = 0; s < wins.length; s++) {
    const [x, y, w, h] = wins[s];
    const v = values[s];
    if (!Number.isFinite(v)) { ctx.fillStyle = "#eee"; }
    else {
      const t = hi > lo ? (v - lo) / (hi - lo) : 1;
      ctx.fillStyle = MAP_COLORS[Math.round(255 * t)];
    }
    ctx.fillRect(x * k, y * k, w * k - 1, h * k - 1);
    if (format && w * k >= 20 && Number.isFinite(v)) {
      ctx.fillStyle = "#000"; ctx.font = `${Math.min(12, w * k * 0.45)}px sans-serif`;
      ctx.textAlign = "center"; ctx.textBaseline = "middle";
      ctx.fillText(format(v), (x + w / 2) * k, (y + h / 2) * k);
    }
  }
  $(label).textContent = Number.isFinite(lo) ? `${lo.toFixed(0)} … ${hi.toFixed(0)}` : "";
}

let cameraImage = null;
function drawCamera() {
  const canvas = $("camera"), ctx = canvas.getContext("2d");
  const p = view.pixels;
  if (!p) {
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    $("camera-frame").textContent = "";
    return;
  }
  const k = fit(canvas, 420);
  if (!cameraImage || cameraImage.width !== p.width || cameraImage.height !== p.height) {
    cameraImage = document.createElement("canvas");
    cameraImage.width = p.width; cameraImage.height = p.height;
  }
  const ictx = cameraImage.getContext("2d");
  const img = ictx.createImageData(p.width, p.height);
  let lo = 65535, hi = 0, selected = 0;
  for (const v of p.pixels) { if (v < lo) lo = v; if (v > hi) hi = v; }
  const span = Math.max(1, hi - lo);
  for (let i = 0; i < p.pixels.length; i++) {
    const g = Math.round(255 * Math.sqrt((p.pixels[i] - lo) / span));
    const o = 4 * i;
    if (p.mask[i]) {
      selected += 1;
      img.data[o] = 255; img.data[o + 1] = Math.round(90 + 0.6 * g); img.data[o + 2] = 0;
    } else {
      img.data[o] = g; img.data[o + 1] = g; img.data[o + 2] = g;
    }
    img.data[o + 3] = 255;
  }
  ictx.putImageData(img, 0, 0);
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(cameraImage, 0, 0, canvas.width, canvas.height);
  ctx.strokeStyle = "#4af8"; ctx.lineWidth = 1;
  ctx.beginPath();
  for (const [x, y, w, h] of view.setup.windows) ctx.rect(x * k + 0.5, y * k + 0.5, w * k - 1, h * k - 1);
  ctx.stroke();
  $("camera-frame").textContent = `frame ${p.frame}, ${selected} pixels selected`;
  setCount("selectedPixels", selected);
}

function drawLines(id, lines) {
  const canvas = $(id), ctx = canvas.getContext("2d");
  const W = canvas.width, H = canvas.height, pad = 34;
  ctx.clearRect(0, 0, W, H);
  let lo = Infinity, hi = -Infinity;
  for (const l of lines) for (const v of l.values) if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!Number.isFinite(lo)) { lo = 0; hi = 1; }
  if (hi - lo < 1e-6) { lo -= 0.5; hi += 0.5; }
  const y = (v) => H - 12 - ((v - lo) / (hi - lo)) * (H - 24);
  ctx.strokeStyle = "#ccc"; ctx.lineWidth = 1; ctx.beginPath();
  ctx.moveTo(pad, 6); ctx.lineTo(pad, H - 6); ctx.lineTo(W, H - 6); ctx.stroke();
  ctx.fillStyle = "#556"; ctx.font = "10px sans-serif"; ctx.textAlign = "right";
  ctx.fillText(hi.toPrecision(3), pad - 3, 14); ctx.fillText(lo.toPrecision(3), pad - 3, H - 10);
  for (const l of lines) {
    ctx.strokeStyle = l.color; ctx.setLineDash(l.dash || []); ctx.lineWidth = 1.3;
    ctx.beginPath();
    let pen = false;
    l.values.forEach((v, i) => {
      const px = pad + ((W - pad) * i) / (HISTORY - 1);
      if (!Number.isFinite(v)) { pen = false; return; }
      if (pen) ctx.lineTo(px, y(v)); else ctx.moveTo(px, y(v));
      pen = true;
    });
    ctx.stroke();
  }
  ctx.setLineDash([]);
}

function drawSeries() {
  const lines = [];
  view.chosen.forEach((s, i) => {
    const h = view.series.get(s);
    if (!h) return;
    const color = COLORS[i % COLORS.length];
    lines.push({ values: h.x, color }, { values: h.y, color, dash: [4, 3] });
  });
  drawLines("series", lines);
  drawLines("rate", [{ values: view.rates, color: "#333" }]);
  const r = view.results;
  $("rate-now").textContent = r ? `${r.rate.toFixed(1)} frames/s` : "";
}

function row(label, value, warn) {
  return `<tr class="${warn ? "warn" : ""}"><td>${label}</td><td class="value">${value ?? "–"}</td></tr>`;
}

function drawHealth() {
  const h = view.health || {}, r = view.results, s = view.setup;
  const rows = [
    row("frames seen by the host", r ? r.seen : 0),
    row("frames dropped or incomplete (host)", r ? r.dropped : 0, r && r.dropped > 0),
    row("frame rate (host)", r ? `${r.rate.toFixed(1)} /s` : null),
    row("device: frames processed", h.frames_processed),
    row("device: frames dropped", h.frames_dropped, h.frames_dropped > 0),
    row("device: CRC errors", h.crc_errors, h.crc_errors > 0),
    row("device: decode errors", h.decode_errors, h.decode_errors > 0),
    row("device: overruns", h.overruns, h.overruns > 0),
    row("device: pixel errors", h.pixel_errors, h.pixel_errors > 0),
    row("device: configuration digest", h.config_digest, s && h.config_digest && h.config_digest !== s.digest),
    row("configuration", s ? `${s.config} (${s.digest}), ${s.rule}` : null),
  ];
  $("health").tBodies[0].innerHTML = rows.join("");
  const boards = h.boards || [];
  $("boards").hidden = boards.length === 0;
  $("boards").tBodies[0].innerHTML = boards.map((b, i) => {
    const subs = s && s.boards[i] ? s.boards[i].subapertures.length : "";
    const load = b.load == null ? "–" : `${(100 * b.load).toFixed(0)}%`;
    return `<tr class="${b.error || b.frames_dropped > 0 ? "warn" : ""}"><td>${b.name}</td><td>${subs}</td><td>${load}</td><td>${b.frames_done}</td><td>${b.frames_dropped}</td><td>${b.error || ""}</td></tr>`;
  }).join("");
  setCount("deviceProcessed", h.frames_processed ?? "");
  setCount("deviceDropped", h.frames_dropped ?? "");
}

function draw() {
  requestAnimationFrame(draw);
  if (!view.dirty) return;
  view.dirty = false;
  const t0 = performance.now();
  if (view.setup) {
    let t = performance.now();
    drawPupil();
    setCount("pupilMs", (performance.now() - t).toFixed(1));
    t = performance.now();
    const r = view.results, n = view.setup.windows.length;
    const flux = new Array(n).fill(NaN);
    if (r) for (let s = 0; s < n && s < r.state.length; s++) if (r.state[s]) flux[s] = r.flux[s];
    drawMap("flux", flux, "flux-range", null);
    setCount("fluxMs", (performance.now() - t).toFixed(1));
    if (view.setupDirty) {
      drawMap("nmap", view.setup.n, "n-range", (v) => v.toFixed(0));
      view.setupDirty = false;
    }
    if (view.pixelsDirty) {
      drawCamera();
      view.pixelsDirty = false;
    }
  }
  drawSeries();
  drawHealth();
  const r = view.results;
  setCount("frame", r ? r.frame : -1);
  setCount("frames", r ? r.seen : 0);
  setCount("dropped", r ? r.dropped : 0);
  setCount("rate", r ? r.rate.toFixed(2) : 0);
  if (view.received !== view.drawn) {
    view.updates += 1;
    view.drawn = view.received;
  }
  setCount("updates", view.updates);
  setCount("received", view.received);
  setCount("pixelUpdates", view.pixelUpdates);
  setCount("chosen", view.chosen.join(","));
  setCount("drawMs", (performance.now() - t0).toFixed(1));
}

$("pupil").addEventListener("click", (e) => {
  if (!view.setup) return;
  const canvas = $("pupil"), rect = canvas.getBoundingClientRect();
  const k = canvas.width / Math.max(view.setup.camera.width, view.setup.camera.height);
  const cx = (e.clientX - rect.left) * (canvas.width / rect.width) / k;
  const cy = (e.clientY - rect.top) * (canvas.height / rect.height) / k;
  const s = view.setup.windows.findIndex(([x, y, w, h]) => cx >= x && cx < x + w && cy >= y && cy < y + h);
  if (s < 0) return;
  const at = view.chosen.indexOf(s);
  if (at >= 0) { view.chosen.splice(at, 1); view.series.delete(s); }
  else { view.chosen.push(s); if (view.chosen.length > COLORS.length) view.series.delete(view.chosen.shift()); }
  view.dirty = true;
});
$("scale").addEventListener("change", () => { view.dirty = true; });

connect();
requestAnimationFrame(draw);
