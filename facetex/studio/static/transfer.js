// Transfer page: submit a job, follow it, show the before/after slider and the 1:1 zooms
"use strict";
studioHeader("/transfer");
const $ = (id) => document.getElementById(id);
const ZOOM = 100;  // native pixels shown in each zoom canvas
let focus = null;  // the zoomed spot, in the image's own pixels

api("/api/info").then((info) => {
  fillSamples($("content-sample"), info.samples, "frl_004_neutral.jpg");
  fillSamples($("style-sample"), info.samples, "frl_005_neutral.jpg");
  for (const [sel, values, chosen] of [[$("method"), info.methods, "facetex"], [$("preset"), info.presets, "preview"]]) {
    for (const v of values) { const o = document.createElement("option"); o.value = v; o.textContent = v; o.selected = v === chosen; sel.appendChild(o); }
  }
}).catch((e) => showError($("error"), e.message));

// a chosen file wins over the sample list, and picking a sample drops the file: what is shown is what is sent
for (const role of ["content", "style"]) {
  $(`${role}-file`).addEventListener("change", () => { if ($(`${role}-file`).files.length) $(`${role}-sample`).value = ""; });
  $(`${role}-sample`).addEventListener("change", () => { if ($(`${role}-sample`).value) $(`${role}-file`).value = ""; });
}

$("form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  showError($("error"), "");
  $("result").classList.add("hidden");
  const fd = new FormData();
  for (const role of ["content", "style"]) {
    const f = $(`${role}-file`).files[0];
    if (f) fd.append(role, f); else fd.append(`${role}_sample`, $(`${role}-sample`).value);
  }
  fd.append("method", $("method").value);
  fd.append("preset", $("preset").value);
  if ($("size").value) fd.append("size", $("size").value);
  await runJob("/api/transfer", fd, $("run"), showResult);
});

function loaded(img, src) {
  return new Promise((ok, bad) => { img.onload = ok; img.onerror = () => bad(new Error(`cannot show ${src}`)); img.src = src; });
}

async function showResult(job) {
  $("result").classList.remove("hidden");
  await Promise.all([loaded($("before"), fileUrl(job, "content")), loaded($("after"), fileUrl(job, "result.png"))]);
  $("dl-result").href = fileUrl(job, "result.png", true);
  $("dl-sidecar").href = fileUrl(job, "result.png.json", true);
  const a = $("after");
  $("summary").textContent = `${job.info.content} ← ${job.info.style}: ${job.info.method}, ${job.info.preset}; ` +
    `${a.naturalWidth}x${a.naturalHeight} px in ${job.seconds.toFixed(1)} s`;
  focus = null;
  setSlider();
  drawZooms();
}

function setSlider() {
  const v = $("slider").value;
  $("after").style.clipPath = `inset(0 0 0 ${v}%)`;
  $("divider").style.left = `${v}%`;
}
$("slider").addEventListener("input", setSlider);

// the zoom follows the pointer over the compare view: native pixels of both images at that spot
function drawZooms() {
  const b = $("before"), a = $("after");
  if (!b.naturalWidth || !a.naturalWidth) return;
  const f = focus || [0.5, 0.42];  // default: near the face's centre
  for (const [img, id] of [[b, "zoom-before"], [a, "zoom-after"]]) {
    const cx = f[0] * img.naturalWidth, cy = f[1] * img.naturalHeight;
    const ctx = $(id).getContext("2d");
    ctx.imageSmoothingEnabled = false;
    ctx.fillStyle = "#ddd"; ctx.fillRect(0, 0, ZOOM, ZOOM);
    ctx.drawImage(img, Math.round(cx - ZOOM / 2), Math.round(cy - ZOOM / 2), ZOOM, ZOOM, 0, 0, ZOOM, ZOOM);
  }
}
function pointAt(ev) {
  const r = $("compare").getBoundingClientRect();
  focus = [Math.min(1, Math.max(0, (ev.clientX - r.left) / r.width)), Math.min(1, Math.max(0, (ev.clientY - r.top) / r.height))];
  drawZooms();
}
$("compare").addEventListener("mousemove", pointAt);
$("compare").addEventListener("click", pointAt);
