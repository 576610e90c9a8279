// Live page: camera frames stream to the studio over a WebSocket (each with an id, at most a few
// unanswered at once); puppet frames come back tagged with the id they were made from, so the page
// measures latency (send to receive of that id), puppet fps, dropped frames and p50/p95 in its own clock.
// Both ways a frame is one binary message: 4-byte id + JPEG to the studio (the camera frame scaled down
// to the "frame_side" the studio asks for), a 12-byte header (id, kind, server ms) + JPEG back
"use strict";
studioHeader("/live");
const $ = (id) => document.getElementById(id);
fillPersonas($("persona")).catch((e) => showError($("error"), e.message));

// counters of the page (window.liveStats: what the page shows, also for tests). sent: camera frames
// sent; received: puppet frames shown; lost / warmup: replies of those kinds; dropped: frames sent that
// never came back (the studio dropped them as stale: a newer one came first); held: camera frames not
// sent because MAX_IN_FLIGHT were unanswered
const stats = window.liveStats = { first: null, sent: 0, received: 0, lost: 0, warmup: 0, dropped: 0, held: 0,
  fps: 0, p50: null, p95: null, latencies: [], times: [], server: null };
let MAX_IN_FLIGHT = 4, FRAME_SIDE = 0;  // from the studio's "ready" message (0: the camera's size)
const KINDS = ["warmup", "puppet", "lost"], HEADER = 12;
let ws = null, stream = null, running = false, nextId = 0;
const inFlight = new Map();  // id -> send time (performance.now()), in the order sent
const canvas = document.createElement("canvas");

function percentile(values, q) {
  const s = [...values].sort((a, b) => a - b);
  return s[Math.min(s.length - 1, Math.floor(q * s.length))];
}

function showCounters() {
  const now = performance.now();
  // puppet frames received in the last 5 s (or since the first one): steady enough to read, recent enough to follow
  stats.times = stats.times.filter((t) => now - t < 5000);
  if (stats.first == null && stats.times.length) stats.first = stats.times[0];
  const span = stats.first == null ? 5 : Math.min(5, Math.max(1, (now - stats.first) / 1000));
  stats.fps = stats.times.length / span;
  const recent = stats.latencies.slice(-250);
  stats.p50 = recent.length ? percentile(recent, 0.5) : null;
  stats.p95 = recent.length ? percentile(recent, 0.95) : null;
  $("fps").textContent = stats.fps.toFixed(1);
  $("p50").textContent = stats.p50 == null ? "–" : `${stats.p50.toFixed(0)} ms`;
  $("p95").textContent = stats.p95 == null ? "–" : `${stats.p95.toFixed(0)} ms`;
  $("server").textContent = stats.server == null ? "–" : `${stats.server.toFixed(0)} ms`;
  for (const k of ["sent", "received", "dropped", "held", "lost"]) $(k).textContent = stats[k];
}
setInterval(showCounters, 250);

// a reply for `id`: the older ids still unanswered were dropped by the studio (it replies in order)
function answered(id) {
  const sentAt = inFlight.get(id);
  for (const k of inFlight.keys()) {
    if (k === id) break;
    inFlight.delete(k);
    stats.dropped++;
  }
  inFlight.delete(id);
  return sentAt;
}

// each camera frame: sent with its id unless MAX_IN_FLIGHT are unanswered (then held back: the next is newer)
function onCameraFrame() {
  if (!running) return;
  const video = $("camera");
  if (ws && ws.readyState === WebSocket.OPEN && ws.ready && video.videoWidth) {
    if (inFlight.size >= MAX_IN_FLIGHT) {
      stats.held++;
    } else {
      const id = nextId++;
      inFlight.set(id, null);  // counted while the JPEG is being made
      // the frame at the size the studio works at: a smaller JPEG to encode, send and decode
      const w = video.videoWidth, h = video.videoHeight;
      const k = FRAME_SIDE ? Math.min(1, FRAME_SIDE / Math.max(w, h)) : 1;
      const cw = Math.round(w * k), ch = Math.round(h * k);
      if (canvas.width !== cw || canvas.height !== ch) { canvas.width = cw; canvas.height = ch; }
      canvas.getContext("2d").drawImage(video, 0, 0, cw, ch);
      canvas.toBlob((blob) => {
        if (!blob || !ws || ws.readyState !== WebSocket.OPEN) { inFlight.delete(id); return; }
        const head = new DataView(new ArrayBuffer(4));
        head.setUint32(0, id);  // big-endian
        inFlight.set(id, performance.now());
        stats.sent++;
        ws.send(new Blob([head.buffer, blob]));
      }, "image/jpeg", 0.85);
    }
  }
  if (video.requestVideoFrameCallback) video.requestVideoFrameCallback(onCameraFrame);
  else setTimeout(onCameraFrame, 40);
}

// a reply (ArrayBuffer): the header (id, kind, server ms), then the JPEG unless it is a warm-up frame
function onReply(buf) {
  const now = performance.now();
  const head = new DataView(buf, 0, HEADER);
  const id = head.getUint32(0), kind = KINDS[head.getUint8(4)] || "warmup";
  const sentAt = answered(id);
  stats.server = head.getFloat32(8);
  if (kind === "warmup") {
    stats.warmup++;
    $("status").textContent = "warming up (the first frames of your face make its reference)…";
    return;
  }
  if (kind === "lost") stats.lost++;
  $("status").textContent = kind === "lost" ? "no face: showing the camera" : `running (${ws.info})`;
  if (kind === "puppet") {
    if (sentAt != null) {
      stats.latencies.push(now - sentAt);
      if (stats.latencies.length > 2000) stats.latencies.splice(0, 1000);
    }
    stats.received++;
    stats.times.push(now);
  }
  if (buf.byteLength > HEADER) show(new Blob([new Uint8Array(buf, HEADER)], { type: "image/jpeg" }));
}

// a frame is drawn once decoded (createImageBitmap decodes off the main thread; an <img> whose src
// changes 25 times a second shows nothing between loads); `shown` keeps a late decode from drawing
// over a newer frame
let decoded = 0, shown = 0;
function show(blob) {
  const n = ++decoded;
  createImageBitmap(blob).then((bmp) => {
    if (n > shown) {
      shown = n;
      const c = $("puppet");
      if (c.width !== bmp.width || c.height !== bmp.height) { c.width = bmp.width; c.height = bmp.height; }
      c.getContext("2d").drawImage(bmp, 0, 0);
    }
    bmp.close();
  }).catch((e) => showError($("error"), `a puppet frame could not be shown: ${e.message}`));
}

async function start() {
  showError($("error"), "");
  if (!$("persona").value) { showError($("error"), "no persona: build one on the Persona page or upload one on the Puppet page"); return; }
  try {
    stream = await navigator.mediaDevices.getUserMedia({ video: { width: 320, height: 240, frameRate: { ideal: 25 } }, audio: false });
  } catch (e) {
    showError($("error"), `no camera: ${e.message}`);
    return;
  }
  $("camera").srcObject = stream;
  $("start").disabled = true; $("stop").disabled = false;
  inFlight.clear();
  const q = new URLSearchParams({ persona: $("persona").value, mode: $("mode").value, size: $("size").value });
  ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/api/live?${q}`);
  ws.binaryType = "arraybuffer";
  ws.onmessage = (ev) => {
    if (typeof ev.data !== "string") { onReply(ev.data); return; }
    const m = JSON.parse(ev.data);
    if (m.error) { showError($("error"), m.error); stop(); return; }
    if (m.status === "loading") $("status").textContent = `loading ${m.persona}…`;
    if (m.status === "ready") {
      MAX_IN_FLIGHT = m.max_in_flight || MAX_IN_FLIGHT;
      FRAME_SIDE = m.frame_side || 0;
      ws.info = `${m.engine}, ${m.size} px, ${m.mode}`;
      ws.ready = true;
      $("status").textContent = "warming up…";
    }
  };
  ws.onclose = () => { if (running) { $("status").textContent = "disconnected"; stop(); } };
  running = true;
  onCameraFrame();
}

function stop() {
  running = false;
  if (ws) { const w = ws; ws = null; if (w.readyState <= WebSocket.OPEN) w.close(); }
  if (stream) { stream.getTracks().forEach((t) => t.stop()); stream = null; }
  inFlight.clear();
  $("start").disabled = false; $("stop").disabled = true;
  const s = $("status").textContent;
  if (s.startsWith("running") || s.startsWith("warming") || s.startsWith("no face")) $("status").textContent = "stopped";
}

$("start").addEventListener("click", start);
$("stop").addEventListener("click", stop);
