// Live page: camera -> JPEG over a WebSocket -> puppet JPEG back; fps and latency measured here
"use strict";
studioHeader("/live");
const $ = (id) => document.getElementById(id);
fillPersonas($("persona")).catch((e) => showError($("error"), e.message));

// counters of the page (window.liveStats: what the page shows, also for tests)
const stats = window.liveStats = { first: null, received: 0, dropped: 0, noface: 0, sent: 0, fps: 0, p50: null, p95: null, latencies: [], times: [] };
let ws = null, stream = null, inFlight = false, sentAt = 0, lastUrl = null, running = false;
const canvas = document.createElement("canvas");

function percentile(values, q) {
  const s = [...values].sort((a, b) => a - b);
  return s[Math.min(s.length - 1, Math.floor(q * s.length))];
}

function showCounters() {
  const now = performance.now();
  // frames received in the last 5 s (or since the first one): steady enough to read, recent enough to follow
  stats.times = stats.times.filter((t) => now - t < 5000);
  if (stats.first == null && stats.times.length) stats.first = stats.times[0];
  const span = stats.first == null ? 5 : Math.min(5, Math.max(1, (now - stats.first) / 1000));
  stats.fps = stats.times.length / span;
  const recent = stats.latencies.slice(-100);
  stats.p50 = recent.length ? percentile(recent, 0.5) : null;
  stats.p95 = recent.length ? percentile(recent, 0.95) : null;
  $("fps").textContent = stats.fps.toFixed(1);
  $("p50").textContent = stats.p50 == null ? "–" : `${stats.p50.toFixed(0)} ms`;
  $("p95").textContent = stats.p95 == null ? "–" : `${stats.p95.toFixed(0)} ms`;
  for (const k of ["received", "dropped", "noface"]) $(k).textContent = stats[k];
}
setInterval(showCounters, 250);

function replied() {
  stats.latencies.push(performance.now() - sentAt);
  if (stats.latencies.length > 1000) stats.latencies.splice(0, 500);
  inFlight = false;
}

// each camera frame: sent when none is in flight, else dropped (the next one is newer)
function onCameraFrame() {
  if (!running) return;
  const video = $("camera");
  if (ws && ws.readyState === WebSocket.OPEN && ws.ready && video.videoWidth) {
    if (inFlight) {
      stats.dropped++;
    } else {
      inFlight = true;
      canvas.width = video.videoWidth; canvas.height = video.videoHeight;
      canvas.getContext("2d").drawImage(video, 0, 0);
      canvas.toBlob((blob) => {
        if (!blob || !ws || ws.readyState !== WebSocket.OPEN) { inFlight = false; return; }
        sentAt = performance.now();
        stats.sent++;
        ws.send(blob);
      }, "image/jpeg", 0.85);
    }
  }
  if (video.requestVideoFrameCallback) video.requestVideoFrameCallback(onCameraFrame);
  else setTimeout(onCameraFrame, 33);
}

async function start() {
  showError($("error"), "");
  if (!$("persona").value) { showError($("error"), "no persona: build one on the Persona page or upload one on the Puppet page"); return; }
  try {
    stream = await navigator.mediaDevices.getUserMedia({ video: { width: 320, height: 240 }, audio: false });
  } catch (e) {
    showError($("error"), `no camera: ${e.message}`);
    return;
  }
  $("camera").srcObject = stream;
  $("start").disabled = true; $("stop").disabled = false;
  const q = new URLSearchParams({ persona: $("persona").value, mode: $("mode").value, size: $("size").value });
  ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/api/live?${q}`);
  ws.binaryType = "blob";
  ws.onmessage = (ev) => {
    if (typeof ev.data === "string") {
      const m = JSON.parse(ev.data);
      if (m.error) { showError($("error"), m.error); stop(); return; }
      if (m.status === "loading") $("status").textContent = `loading ${m.persona}…`;
      if (m.status === "ready") { ws.ready = true; $("status").textContent = `running (${m.engine}, ${m.size} px, ${m.mode})`; }
      if ("server_ms" in m) $("server").textContent = `${m.server_ms.toFixed(0)} ms`;
      if (m.face === false) { stats.noface++; replied(); }
      return;
    }
    replied();  // the puppet frame: one reply per frame sent
    stats.received++;
    stats.times.push(performance.now());
    if (lastUrl) URL.revokeObjectURL(lastUrl);
    lastUrl = URL.createObjectURL(ev.data);
    $("puppet").src = lastUrl;
  };
  ws.onclose = () => { if (running) { $("status").textContent = "disconnected"; stop(); } };
  running = true;
  onCameraFrame();
}

function stop() {
  running = false;
  if (ws) { const w = ws; ws = null; if (w.readyState <= WebSocket.OPEN) w.close(); }
  if (stream) { stream.getTracks().forEach((t) => t.stop()); stream = null; }
  inFlight = false;
  $("start").disabled = false; $("stop").disabled = true;
  if ($("status").textContent.startsWith("running")) $("status").textContent = "stopped";
}

$("start").addEventListener("click", start);
$("stop").addEventListener("click", stop);
