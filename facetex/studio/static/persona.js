// Persona page: upload photos (files, a folder or a zip), build stage by stage, browse the textures
"use strict";
studioHeader("/persona");
const $ = (id) => document.getElementById(id);

function chosenFiles() {
  const images = /\.(jpe?g|png|webp|zip)$/i;  // a folder brings every file: keep the photos
  return [...$("photos").files, ...[...$("folder").files].filter((f) => images.test(f.name))];
}
for (const id of ["photos", "folder"]) {
  $(id).addEventListener("change", () => { $("chosen").textContent = `${chosenFiles().length} file(s) chosen`; });
}

$("form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  showError($("error"), "");
  $("result").classList.add("hidden");
  $("progress").querySelector("ol.stages").innerHTML = "";
  const files = chosenFiles();
  if (!files.length) { showError($("error"), "no photos: choose images, a folder or a zip archive"); return; }
  const fd = new FormData();
  for (const f of files) fd.append("photos", f);
  fd.append("min_photos", $("min-photos").value);
  if ($("name").value) fd.append("name", $("name").value);
  await runJob("/api/persona", fd, $("build"), showResult);
});

function figure(caption, ...srcs) {
  const fig = document.createElement("figure");
  const pair = document.createElement("div");
  pair.className = "pair";
  srcs.forEach(([src, cls, alt]) => {
    const img = document.createElement("img");
    img.src = src; img.className = cls; img.alt = alt;
    pair.appendChild(img);
  });
  const cap = document.createElement("figcaption");
  cap.textContent = caption;
  fig.append(pair, cap);
  return fig;
}

function showResult(job) {
  $("result").classList.remove("hidden");
  $("dl-persona").href = fileUrl(job, "persona.persona", true);
  $("dl-sidecar").href = fileUrl(job, "persona.persona.json", true);
  const built = (job.result && job.result.build) || {};
  const skipped = (built.skipped || []).length;
  $("summary").textContent = `${job.info.name}: ${built.photos_used ?? "?"} photos used, ${skipped} skipped; ` +
    `built in ${job.seconds.toFixed(1)} s. Each texture is the persona's blend for the expression of the photo beside it.`;
  const box = $("textures");
  box.innerHTML = "";
  box.appendChild(figure("average (stage d)", [fileUrl(job, "average.png"), "", "average texture"]));
  job.info.references.forEach((ref, k) => {
    if (!job.files.includes(`texture_${k}.png`)) return;  // a photo without a usable face
    box.appendChild(figure(`expression of photo ${k + 1}`, [fileUrl(job, ref), "ref", `photo ${k + 1}`],
                           [fileUrl(job, `texture_${k}.png`), "", `texture ${k + 1}`]));
  });
}
