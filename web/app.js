// The scene page: photos in (dropped, chosen, or the bundled example), POST /v1/reconstruct
// with progress, then the Gaussians in 3D (RGB or instance colours, cameras), the instance
// list, and text queries that highlight the named instances in 3D and on the photos.
// `body[data-state]` says where the page is (idle, uploading, reconstructing, loading, ready,
// querying, error) for people and tests alike.

import { getBytes, postForm, postJson } from "./api.js";
import { DIMMED, HIGHLIGHT, css, instanceColour } from "./colours.js";
import { readScene } from "./ply.js";
import { Viewer } from "./viewer.js";
import { Views } from "./views.js";

const $ = (selector) => document.querySelector(selector);
const EXAMPLE = ["000.png", "001.png", "002.png", "003.png"].map((f) => `/web/example/${f}`);

const viewer = new Viewer($("#viewer"));
const views = new Views($("#views"));
let photos = [];
let scene = null; // { id, gaussians, instances }
let highlighted = new Set();

function setState(state, message = "") {
  document.body.dataset.state = state;
  const busy = ["uploading", "reconstructing", "loading", "querying"].includes(state);
  $("#progress span").textContent = message;
  $("#progress").classList.toggle("error", state === "error");
  $("#run").disabled = busy || photos.length < 2 || photos.length > 16;
}

function choose(files) {
  photos = [...files];
  const count = photos.length;
  const fits = count >= 2 && count <= 16;
  setState("idle", `${count} photo${count === 1 ? "" : "s"} chosen${fits ? "" : ": inssplat needs 2–16"}`);
}

$("#photos").addEventListener("change", (e) => choose(e.target.files));
$("#drop").addEventListener("dragover", (e) => e.preventDefault());
$("#drop").addEventListener("drop", (e) => {
  e.preventDefault();
  choose([...e.dataTransfer.files].filter((f) => f.type.startsWith("image/")));
});
$("#example").addEventListener("click", async () => {
  const blobs = await Promise.all(EXAMPLE.map(async (url) => (await fetch(url)).blob()));
  choose(blobs.map((b, i) => new File([b], EXAMPLE[i].split("/").pop(), { type: b.type })));
});

$("#upload").addEventListener("submit", async (e) => {
  e.preventDefault();
  const form = new FormData();
  for (const photo of photos) form.append("images", photo, photo.name);
  if ($("#vocab").value.trim()) form.append("vocab", $("#vocab").value);
  if ($("#refine-steps").value.trim()) form.append("refine_steps", $("#refine-steps").value.trim());
  const progress = $("#progress progress");
  progress.hidden = false;
  progress.removeAttribute("value");
  const started = performance.now();
  const tick = setInterval(() => {
    if (document.body.dataset.state === "reconstructing") {
      setState("reconstructing", `Reconstructing… ${((performance.now() - started) / 1000).toFixed(0)} s`);
    }
  }, 500);
  try {
    setState("uploading", "Uploading…");
    const result = await postForm("/v1/reconstruct", form, (fraction) => {
      progress.value = fraction;
      if (fraction >= 1) setState("reconstructing", "Reconstructing…");
    });
    clearInterval(tick);
    setState("loading", "Loading the Gaussians…");
    progress.removeAttribute("value");
    await showScene(result);
    setState("ready", `Scene ${result.scene_id} in ${((performance.now() - started) / 1000).toFixed(1)} s`);
  } catch (err) {
    setState("error", `Failed: ${err.message}`);
  } finally {
    clearInterval(tick);
    progress.hidden = true;
  }
});

/** Loads the reconstruction `result` (a ReconstructResponse) into the page. */
async function showScene(result) {
  const bytes = await getBytes(`/v1/scenes/${result.scene_id}/scene.ply`);
  const gaussians = readScene(bytes);
  scene = { id: result.scene_id, gaussians, instances: result.instances };
  highlighted = new Set();
  $("#result").hidden = false;
  await viewer.show(bytes, gaussians, result.cameras);
  viewer.showCameras($("#show-cameras").checked);
  await views.show(photos);
  listInstances(result.instances);
  $("#summary").textContent =
    `${result.gaussians_kept} Gaussians (of ${result.gaussians_in}), ${result.cameras.length} views, ` +
    result.timings.map((t) => `${t.stage} ${t.ms.toFixed(0)} ms`).join(", ") +
    (result.refinement
      ? `; refined for ${result.refinement.steps} steps: input views ` +
        `${result.refinement.input_psnr_before.toFixed(2)} → ${result.refinement.input_psnr_after.toFixed(2)} dB PSNR, ` +
        `photos' gains ${result.refinement.photo_gains.map((g) => g.toFixed(2)).join(" ")}`
      : "");
  $("#query-result").textContent = "";
  paint();
}

function listInstances(instances) {
  $("#instances").replaceChildren(
    ...instances.map((inst) => {
      const item = document.createElement("li");
      item.dataset.id = inst.id;
      item.dataset.label = inst.label;
      const swatch = document.createElement("span");
      swatch.className = "swatch";
      swatch.style.background = css(instanceColour(inst.id));
      const button = document.createElement("button");
      button.type = "button";
      button.className = "label";
      button.textContent = inst.label;
      button.addEventListener("click", () => query(inst.label));
      const info = document.createElement("span");
      info.textContent = ` #${inst.id} · ${inst.gaussians} Gaussians · score ${inst.score.toFixed(2)}`;
      item.append(swatch, button, info);
      return item;
    }),
  );
}

/** Paints the Gaussians in the chosen colours, the highlighted instances over them. */
function paint() {
  const { count, rgba, instanceIds } = scene.gaussians;
  const byInstance = $("input[name=colours]:checked").value === "instances";
  const out = new Uint8Array(rgba);
  for (let i = 0; i < count; i++) {
    const id = instanceIds[i];
    const colour = highlighted.size
      ? highlighted.has(id) ? HIGHLIGHT : DIMMED
      : byInstance ? instanceColour(id) : null;
    if (colour) out.set(colour, 4 * i);
    if (highlighted.size && highlighted.has(id)) out[4 * i + 3] = 255;
  }
  viewer.setColours(out);
  for (const item of document.querySelectorAll("#instances li")) {
    item.classList.toggle("highlighted", highlighted.has(Number(item.dataset.id)));
  }
}

async function query(text) {
  $("#query-text").value = text;
  setState("querying", `Looking for “${text}”…`);
  try {
    const answer = await postJson(`/v1/scenes/${scene.id}/query`, { text });
    highlighted = new Set(answer.matches.map((m) => m.instance_id));
    const found = answer.matches.map((m) => `${m.label} #${m.instance_id} (${m.score.toFixed(2)})`).join(", ");
    $("#query-result").textContent = answer.matches.length ? `“${text}”: ${found}` : answer.message;
    $("#query-result").dataset.matches = answer.matches.length;
    views.paint(answer.matches);
    paint();
    setState("ready", "");
  } catch (err) {
    setState("error", `Query failed: ${err.message}`);
  }
}

$("#query").addEventListener("submit", (e) => {
  e.preventDefault();
  const text = $("#query-text").value.trim();
  if (text && scene) query(text);
});
$("#clear").addEventListener("click", () => {
  highlighted = new Set();
  $("#query-result").textContent = "";
  delete $("#query-result").dataset.matches;
  views.paint([]);
  paint();
});
for (const radio of document.querySelectorAll("input[name=colours]")) radio.addEventListener("change", () => scene && paint());
$("#show-cameras").addEventListener("change", (e) => viewer.showCameras(e.target.checked));
setState("idle");
