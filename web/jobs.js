// The batch jobs page: submit named photo sets or an archive of dataset scenes
// (POST /v1/jobs), and follow each job this browser knows (kept in localStorage) from its
// server-sent events: progress, each scene's state, its artefacts and evaluation metrics.

import { followJob, getJson } from "./api.js";

const $ = (selector) => document.querySelector(selector);
const KNOWN = "inssplat-jobs";
const sets = new Map();
const known = () => JSON.parse(localStorage.getItem(KNOWN) ?? "[]");

function remember(id) {
  localStorage.setItem(KNOWN, JSON.stringify([id, ...known().filter((j) => j !== id)].slice(0, 50)));
}

function refreshForm() {
  $("#sets").replaceChildren(
    ...[...sets].map(([name, files]) => {
      const item = document.createElement("li");
      item.textContent = `${name}: ${files.length} photos`;
      return item;
    }),
  );
  $("#submit").disabled = sets.size === 0 && !$("#archive").files.length;
}

$("#add-set").addEventListener("submit", (e) => {
  e.preventDefault();
  sets.set($("#set-name").value, [...$("#set-photos").files]);
  e.target.reset();
  refreshForm();
});
$("#archive").addEventListener("change", refreshForm);

$("#submit").addEventListener("click", async () => {
  const archive = $("#archive").files[0];
  const body = new FormData();
  const headers = {};
  if (archive) body.append("archive", archive, archive.name);
  else for (const [name, files] of sets) for (const f of files) body.append(name, f, f.name);
  if ($("#refine-steps").value.trim()) body.append("refine_steps", $("#refine-steps").value.trim());
  const key = localStorage.getItem("inssplat-api-key");
  if (key) headers.Authorization = `Bearer ${key}`;
  $("#submit-status").textContent = "Submitting…";
  const response = await fetch("/v1/jobs", { method: "POST", body, headers });
  const answer = await response.json();
  if (!response.ok) {
    $("#submit-status").textContent = `Failed: ${answer.error}`;
    return;
  }
  $("#submit-status").textContent = `Job ${answer.job_id}: ${answer.scenes.length} scene(s)`;
  sets.clear();
  $("#archive").value = "";
  refreshForm();
  show(answer.job_id);
});

$("#open").addEventListener("submit", (e) => {
  e.preventDefault();
  show($("#job-id").value);
});

/** A few of an evaluated scene's metrics, as text. */
function metricsText(metrics) {
  if (!metrics) return "";
  return Object.entries(metrics)
    .filter(([, v]) => typeof v === "number")
    .slice(0, 6)
    .map(([k, v]) => `${k} ${Number.isInteger(v) ? v : v.toFixed(3)}`)
    .join(" · ");
}

function render(card, status) {
  card.querySelector("progress").max = status.total;
  card.querySelector("progress").value = status.done;
  card.querySelector(".state").textContent = `${status.state} · ${status.done}/${status.total}`;
  card.querySelector("tbody").replaceChildren(
    ...status.scenes.map((s) => {
      const row = document.createElement("tr");
      const links = s.scene_id
        ? `<a href="/v1/scenes/${s.scene_id}/preview.png">preview</a> <a href="/v1/scenes/${s.scene_id}/scene.ply">scene.ply</a>`
        : "";
      row.innerHTML = `<td></td><td>${s.state}</td><td>${links}</td><td class="metrics"></td>`;
      row.firstChild.textContent = s.name;
      row.lastChild.textContent = s.error ?? metricsText(s.metrics);
      return row;
    }),
  );
}

function show(id) {
  remember(id);
  let card = document.getElementById(`job-${id}`);
  if (!card) {
    card = document.createElement("article");
    card.id = `job-${id}`;
    card.innerHTML = `<h3></h3><progress></progress> <span class="state">…</span>
      <table><thead><tr><th>scene</th><th>state</th><th>results</th><th>metrics</th></tr></thead><tbody></tbody></table>`;
    card.querySelector("h3").textContent = `Job ${id}`;
    $("#jobs").prepend(card);
  }
  followJob(
    id,
    (status) => render(card, status),
    (err) => (card.querySelector(".state").textContent = err.message),
  );
}

/** Jobs the service no longer knows (expired, or another data folder) leave the list. */
function forget(id) {
  localStorage.setItem(KNOWN, JSON.stringify(known().filter((j) => j !== id)));
}

for (const id of known().reverse()) getJson(`/v1/jobs/${id}`).then(() => show(id), () => forget(id));
