// Puppet page: a driver clip and a persona in, the puppet video out
"use strict";
studioHeader("/puppet");
const $ = (id) => document.getElementById(id);
fillPersonas($("persona")).catch((e) => showError($("error"), e.message));

$("persona-file").addEventListener("change", async () => {
  const f = $("persona-file").files[0];
  if (!f) return;
  showError($("error"), "");
  const fd = new FormData();
  fd.append("persona", f);
  try {
    const job = await api("/api/personas", { method: "POST", body: fd });
    await fillPersonas($("persona"));
    $("persona").value = `job-${job.id}`;
  } catch (e) { showError($("error"), e.message); }
});

$("form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  showError($("error"), "");
  $("result").classList.add("hidden");
  const f = $("driver").files[0];
  if (!f) { showError($("error"), "no driver clip: choose a video"); return; }
  const fd = new FormData();
  fd.append("driver", f);
  fd.append("persona", $("persona").value);
  fd.append("mode", $("mode").value);
  fd.append("size", $("size").value);
  fd.append("side_by_side", $("side-by-side").checked ? "true" : "false");
  if ($("max-frames").value) fd.append("max_frames", $("max-frames").value);
  await runJob("/api/puppet", fd, $("render"), (done) => {
    $("result").classList.remove("hidden");
    const v = $("video");
    v.src = fileUrl(done, "puppet.mp4");
    v.play().catch(() => {});  // autoplay may be refused: the controls stay
    $("dl-video").href = fileUrl(done, "puppet.mp4", true);
    $("dl-sidecar").href = fileUrl(done, "puppet.mp4.json", true);
    const r = (done.result && done.result.puppet) || {};
    $("summary").textContent = `${done.info.driver} driving ${done.info.persona}: ${r.frames ?? "?"} frames, ` +
      `${r.lost_frames ?? 0} with the face lost; ${done.seconds.toFixed(1)} s`;
  });
});
