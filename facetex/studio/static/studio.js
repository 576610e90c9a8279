// facetex studio: helpers shared by the pages (no framework, no build step)
"use strict";

// the page's nav entry is marked; every page has <header> from this script
function studioHeader(active) {
  const pages = [["/", "Studio"], ["/transfer", "Transfer"], ["/persona", "Persona"], ["/puppet", "Puppet"], ["/live", "Live"]];
  const h = document.createElement("header");
  h.innerHTML = '<span class="brand">facetex studio</span><nav></nav>';
  for (const [href, name] of pages.slice(1)) {
    const a = document.createElement("a");
    a.href = href; a.textContent = name;
    if (href === active) a.className = "active";
    h.querySelector("nav").appendChild(a);
  }
  h.querySelector(".brand").addEventListener("click", () => { location.href = "/"; });
  document.body.prepend(h);
}

// JSON of an API call; a failed call throws an Error whose message is the server's one line
async function api(url, options) {
  const r = await fetch(url, options);
  let body = null;
  try { body = await r.json(); } catch (e) { body = null; }
  if (!r.ok) throw new Error((body && body.error) || `${r.status} ${r.statusText}`);
  return body;
}

function showError(el, message) {
  el.textContent = message ? "error: " + message : "";
  el.classList.toggle("hidden", !message);
}

function fileUrl(job, name, download) {
  return `/api/jobs/${job.id}/files/${encodeURIComponent(name)}` + (download ? "?download=1" : "");
}

const FINISHED = ["done", "failed", "cancelled"];

// follow a job over Server-Sent Events until it is done, failed or cancelled; onUpdate(job) each change
function watchJob(jobId, onUpdate) {
  return new Promise((resolve) => {
    const es = new EventSource(`/api/jobs/${jobId}/events`);
    es.onmessage = (ev) => {
      const job = JSON.parse(ev.data);
      onUpdate(job);
      if (FINISHED.includes(job.state)) { es.close(); resolve(job); }
    };
    es.onerror = () => {  // the stream ended without a final state: ask once more
      es.close();
      api(`/api/jobs/${jobId}`).then((job) => { onUpdate(job); resolve(job); });
    };
  });
}

// submit a job (POST ``url`` with the FormData ``body``), follow it in the page's #progress block and
// call show(job) once it is done; a failure is shown in #error as the CLI's one line, a cancelled job
// only in the progress block; ``button`` is disabled meanwhile
async function runJob(url, body, button, show) {
  const byId = (id) => document.getElementById(id);
  button.disabled = true;
  try {
    const job = await api(url, { method: "POST", body });
    const done = await watchJob(job.id, progressView(byId("progress")));
    if (done.state === "failed") throw new Error(done.error);
    if (done.state === "cancelled") return;  // the progress block says so
    await show(done);
  } catch (e) {
    showError(byId("error"), e.message);
  } finally {
    button.disabled = false;
  }
}

// a progress block: <progress>, the stage, the list of stages seen (each marked done when the next
// starts) and a Cancel button while the job is queued or running (the studio stops its command and
// removes its folder)
function progressView(root) {
  const bar = root.querySelector("progress"), stage = root.querySelector(".stage"), list = root.querySelector("ol.stages");
  let cancel = root.querySelector("button.cancel");
  if (!cancel) {
    cancel = document.createElement("button");
    cancel.type = "button"; cancel.className = "secondary cancel"; cancel.textContent = "Cancel";
    stage.after(cancel);
  }
  const seen = [];
  return (job) => {
    root.classList.remove("hidden");
    const active = job.state === "queued" || job.state === "running";
    cancel.classList.toggle("hidden", !active);
    cancel.onclick = () => {
      cancel.disabled = true;
      api(`/api/jobs/${job.id}/cancel`, { method: "POST" }).catch((e) => { stage.textContent = `error: ${e.message}`; });
    };
    if (active) cancel.disabled = false;
    if (job.state === "cancelled") {
      stage.textContent = "cancelled" + (job.seconds != null ? ` after ${job.seconds.toFixed(1)} s` : "");
      return;
    }
    const n = job.steps.length, step = Math.min(job.step, n - 1);
    bar.value = job.state === "done" ? 1 : (step + job.progress) / Math.max(1, n);
    const where = job.state === "queued" ? `queued (position ${job.position + 1})` : job.stage || job.state;
    stage.textContent = `${where} — ${Math.round(100 * bar.value)} %` + (job.seconds != null ? `, ${job.seconds.toFixed(1)} s` : "");
    if (list && job.stage && job.state !== "queued" && seen[seen.length - 1] !== job.stage) {
      seen.push(job.stage);
      const li = document.createElement("li");
      li.textContent = job.stage;
      for (const old of list.children) old.className = "done";
      list.appendChild(li);
    }
    if (list && job.state === "done") for (const li of list.children) li.className = "done";
  };
}

// fill a <select> of the bundled samples (first option: upload a file)
function fillSamples(select, samples, chosen) {
  for (const s of samples) {
    const o = document.createElement("option");
    o.value = s; o.textContent = s;
    if (s === chosen) o.selected = true;
    select.appendChild(o);
  }
}

async function fillPersonas(select) {
  const list = await api("/api/personas");
  const keep = select.value;
  select.innerHTML = "";
  for (const p of list) {
    const o = document.createElement("option");
    o.value = p.id; o.textContent = p.name;
    select.appendChild(o);
  }
  if (keep && list.some((p) => p.id === keep)) select.value = keep;
  if (!list.length) {
    const o = document.createElement("option");
    o.value = ""; o.textContent = "(no persona yet: build or upload one)";
    select.appendChild(o);
  }
  return list;
}
