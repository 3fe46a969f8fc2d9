// The ctp page: a client of the JSON API like any other (POST /align, GET /jobs/{id}/events, results).
// Every call goes through fetch with the API key, when there is one, in the Authorization header (never
// in a URL); results are fetched as blobs and shown from blob URLs, so the same code works with keys on.
import { objectFacts, sceneSummary, wireScene } from "./scene.js";
import { Viewer, similarityParts } from "./viewer.js";

const $ = (id) => document.getElementById(id);
const ROLES = ["target", "source"];
const TERMINAL = ["succeeded", "failed", "canceled"];
const state = {
  config: null,
  key: sessionStorage.getItem("ctp-key") || "",
  files: { target: null, source: null },
  following: null, // AbortController of the event stream being read
  viewer: null,
  previews: { target: null, source: null }, // input previews (Viewer), made on the first file of each slot
  previewed: { target: null, source: null }, // the file each slot's preview is for (a newer one wins)
  seen: { target: null, source: null }, // what POST /inspect said of each slot's file (its up and front)
  chained: null, // {id, file}: the target slot holds that job's result scene, sent as target_job
  result: null, // {id, blobs: {file name: Blob}}
  urls: [], // blob URLs to revoke when the next result replaces this one
  figures: [], // the progress readout's figure (guide match, else -gap) over time, for the spark line
  readout: false, // whether this job's progress has shown a readout (then the objective is never shown)
  stageIndex: null, // the alignment of a scene (or of copies) the readout is about: the next one starts it afresh
  nextPage: null,
};

class ApiError extends Error {
  constructor(status, error) {
    super(`${error.code}: ${error.message}`);
    Object.assign(this, { status, code: error.code, detail: error.message, field: error.field });
  }
}

async function call(path, init = {}) {
  const headers = { ...(init.headers || {}) };
  if (state.key) headers.Authorization = `Bearer ${state.key}`;
  let response;
  try {
    response = await fetch(path, { ...init, headers });
  } catch (err) {
    if (err.name === "AbortError") throw err;
    throw new ApiError(0, { code: "network_error", message: `the service could not be reached (${err.message})` });
  }
  if (!response.ok) {
    let body = null;
    try { body = await response.json(); } catch { /* not the service's JSON: described below */ }
    const error = body && body.error ? body.error
      : { code: `http_${response.status}`, message: response.statusText || "the service answered with an error" };
    if (response.status === 401) askForKey(error.message);
    throw new ApiError(response.status, error);
  }
  return response;
}

const api = {
  json: async (path, init) => (await call(path, init)).json(),
  blob: async (path, init) => (await call(path, init)).blob(),
};

// -- messages ---------------------------------------------------------------------------------------

/** An error in the box beside the form it concerns (the pair form's, the scene form's). */
function showError(err, box = $("error")) {
  const code = document.createElement("code");
  code.textContent = err.code || "error";
  let where = "";
  if (ROLES.includes(err.field)) {
    const file = state.files[err.field];
    where = `${err.field} file${file ? ` "${file.name}"` : ""} refused: `;
  } else if (err.field) {
    where = `${err.field}: `;
  }
  box.replaceChildren(code, document.createTextNode(` ${where}${err.detail ?? err.message}`));
  box.hidden = false;
}

function clearError(box = $("error")) {
  box.hidden = true;
  box.replaceChildren();
}

function askForKey(message) {
  $("key-form").hidden = false;
  $("key-state").textContent = message || "";
  $("api-key").focus();
}

const duration = (s) => (s < 60 ? `${Math.round(s)} s` : `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`);
const size = (n) => (n < 1024 * 1024 ? `${(n / 1024).toFixed(1)} kB` : `${(n / 1024 / 1024).toFixed(1)} MB`);

// -- the form ---------------------------------------------------------------------------------------

/** Put a file in the target or source slot (a pick, a drop, an example; chaining a result will too). */
export function setFile(role, file) {
  state.files[role] = file;
  if (role === "target") $("grounds").hidden = true; // shown again for a chained scene (addObject)
  for (const name of ["up", "front"]) $(`${name}-${role}`).value = "file"; // a new file: its own frame first
  $(`chosen-${role}`).textContent = file ? `${file.name} (${size(file.size)})` : "or drop a mesh here";
  $(`drop-${role}`).classList.toggle("has-file", Boolean(file));
  previewInput(role, file);
}

/** The input preview: the file in a small 3D view as the browser reads it, and what the service makes of it
 * (POST /inspect: size in the file's units, faces, the up and front a job will use, drawn as arrows, and why),
 * so a wrong file, a model on its side or in the wrong units shows before the job; a file a job would refuse is
 * refused here. The up and front selects (and their flip buttons) are the job's options for this object. */
async function previewInput(role, file) {
  const box = $(`preview-${role}`);
  const info = $(`inspect-${role}`);
  state.previewed[role] = file;
  state.seen[role] = null;
  const current = () => state.previewed[role] === file;
  box.hidden = !file;
  $(`axes-${role}`).hidden = !file;
  delete box.dataset.ready;
  delete info.dataset.state;
  info.classList.remove("bad");
  info.textContent = file ? "reading..." : "";
  if (!file) return;
  state.previews[role] = state.previews[role] || new Viewer(box);
  const viewer = state.previews[role];
  const drawn = viewer.showFile(file).then(() => true, (err) => {
    if (current()) box.dataset.ready = "none";
    console.info(`preview of ${file.name}: ${err.message}`);
    return false;
  });
  await inspectAxes(role, file, drawn);
}

/** Ask POST /inspect what a job makes of ``file`` with this slot's up and front options, and draw them. */
async function inspectAxes(role, file, drawn) {
  const box = $(`preview-${role}`);
  const info = $(`inspect-${role}`);
  const current = () => state.previewed[role] === file;
  const body = new FormData();
  body.append("mesh", file, file.name);
  for (const name of ["up", "front"]) body.append(name, $(`${name}-${role}`).value);
  try {
    const seen = await api.json("inspect", { method: "POST", body });
    if (!current()) return;
    state.seen[role] = seen;
    info.textContent = describeInput(seen);
    info.dataset.state = "ok";
    info.classList.remove("bad");
    if (await drawn && current()) {
      state.previews[role].showAxes(seen.up, seen.front, seen.front_trusted);
      box.dataset.ready = "1";
    }
  } catch (err) {
    if (!current()) return;
    info.textContent = `${err.code}: ${err.detail ?? err.message}`;
    info.dataset.state = "refused";
    info.classList.add("bad");
  }
}

const AXES = ["+x", "-x", "+y", "-y", "+z", "-z"];

/** ``+y`` for a vector along an axis, else null. */
function axisName(vector) {
  const i = vector.findIndex((v) => Math.abs(v) > 0.999);
  return i < 0 ? null : `${vector[i] > 0 ? "+" : "-"}${"xyz"[i]}`;
}

/** Flip the slot's up or front: the option becomes the other way along the axis the service used. */
function flip(role, name) {
  const seen = state.seen[role];
  const used = seen && axisName(seen[name]);
  if (!used) return;
  const other = `${used[0] === "+" ? "-" : "+"}${used[1]}`;
  $(`${name}-${role}`).value = other;
  if (name === "up" && $(`front-${role}`).value[1] === other[1]) $(`front-${role}`).value = "file";
  axesChanged(role);
}

function axesChanged(role) {
  const file = state.previewed[role];
  if (file) inspectAxes(role, file, Promise.resolve(Boolean(state.previews[role]?.model)));
}

function wireAxes(role) {
  for (const name of ["up", "front"]) {
    const select = $(`${name}-${role}`);
    for (const value of ["file", "auto", ...AXES]) select.append(new Option(value, value, false, value === "file"));
    select.addEventListener("change", () => axesChanged(role));
    $(`flip-${name}-${role}`).addEventListener("click", () => flip(role, name));
  }
}

function describeInput(seen) {
  const number = (v) => (v >= 100 || v < 0.01 ? v.toPrecision(3) : v.toFixed(v < 1 ? 3 : 2));
  const named = (v) => axisName(v) || `(${v.map((x) => x.toFixed(2)).join(", ")})`;
  return `${seen.extents.map(number).join(" × ")} in the file's units, ${seen.faces.toLocaleString("en")} faces; `
    + `up: the file's ${named(seen.up)}${seen.turned ? " (turned upright)" : ""}, front: the file's `
    + `${named(seen.front)}${seen.front_trusted ? "" : " (a guess)"}. ${seen.reason}; ${seen.front_reason}`;
}

function wireDrop(role) {
  const zone = $(`drop-${role}`);
  const input = $(`file-${role}`);
  input.addEventListener("change", () => setFile(role, input.files[0] || null));
  zone.addEventListener("dragover", (e) => { e.preventDefault(); zone.classList.add("over"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("over");
    const file = e.dataTransfer && e.dataTransfer.files[0];
    if (file) {
      input.value = "";
      setFile(role, file);
    }
  });
}

async function useSample(sample) {
  clearError();
  try {
    const [target, source] = await Promise.all([sample.target_file, sample.source_file].map(
      (name) => api.blob(`samples/${encodeURIComponent(sample.name)}/${encodeURIComponent(name)}`)));
    setFile("target", new File([target], sample.target_file, { type: "model/gltf-binary" }));
    setFile("source", new File([source], sample.source_file, { type: "model/gltf-binary" }));
  } catch (err) {
    showError(err);
    return;
  }
  $("name-target").value = sample.target_name;
  $("name-source").value = sample.source_name;
  document.querySelector("input[name=guide][value=prompt]").checked = true;
  guideChanged();
  $("prompt").value = sample.prompt;
}

function guideChanged() {
  const byImage = document.querySelector("input[name=guide]:checked").value === "image";
  $("prompt").hidden = byImage;
  $("image").hidden = !byImage;
}

function options() {
  const out = {};
  if ($("opt-preset").value) out.preset = $("opt-preset").value;
  if ($("opt-scale").value) out.scale = $("opt-scale").value === "true";
  for (const name of ["seed", "restarts", "count"]) {
    const value = $(`opt-${name}`).value.trim();
    if (value !== "") out[name] = Number(value);
  }
  if ($("opt-arrangement").value) out.arrangement = $("opt-arrangement").value;
  for (const role of ROLES) {
    for (const name of ["up", "front"]) {
      const value = $(`${name}-${role}`).value;
      if (value && value !== "file") out[`${role}_${name}`] = value;
    }
  }
  return out;
}

async function submit(event) {
  event.preventDefault();
  clearError();
  // Nothing is checked here that the service checks: its answer (code, message, field) is what is shown.
  const data = new FormData();
  for (const role of ROLES) {
    const chained = role === "target" && state.chained && state.files.target === state.chained.file;
    if (chained) {
      data.append("target_job", state.chained.id); // the scene itself, read back as its objects
      for (const id of ["on-1", "on-2"]) if ($(id).value) data.append("on", $(id).value); // its grounds
    } else if (state.files[role]) data.append(role, state.files[role], state.files[role].name);
    const name = $(`name-${role}`).value.trim();
    if (name) data.append(`${role}_name`, name);
  }
  if (document.querySelector("input[name=guide]:checked").value === "image") {
    if ($("image").files[0]) data.append("image", $("image").files[0]);
  } else {
    data.append("prompt", $("prompt").value);
  }
  data.append("options", JSON.stringify(options()));
  await submitJob("align", data, $("submit"));
}

// A form to a job endpoint ("align", "assemble"): the button off while it is sent and while the job runs (until
// it ends or another job is followed); its errors in ``errors``, the box beside that form.
async function submitJob(path, data, button, errors = $("error")) {
  button.disabled = true;
  try {
    const accepted = await api.json(path, { method: "POST", body: data });
    refreshJobs();
    await follow(accepted.id, errors);
  } catch (err) {
    showError(err, errors);
  } finally {
    button.disabled = false;
  }
}

// -- progress ---------------------------------------------------------------------------------------

/** Read a server-sent event stream with fetch (EventSource cannot send the Authorization header);
 *  calls onProgress with each job state; returns the final job, or null when the stream broke off. */
async function readEvents(path, signal, onProgress) {
  const response = await call(path, { signal, headers: { Accept: "text/event-stream" } });
  const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return null;
    buffer += value;
    let cut;
    while ((cut = buffer.search(/\r?\n\r?\n/)) >= 0) {
      const block = buffer.slice(0, cut);
      buffer = buffer.slice(cut).replace(/^\r?\n\r?\n/, "");
      let kind = "message";
      const data = [];
      for (const line of block.split(/\r?\n/)) {
        if (line.startsWith("event:")) kind = line.slice(6).trim();
        else if (line.startsWith("data:")) data.push(line.slice(5).replace(/^ /, ""));
      }
      if (!data.length) continue; // a keep-alive comment
      const job = JSON.parse(data.join("\n"));
      onProgress(job);
      if (kind === "end") return job;
    }
  }
}

async function follow(id, errors = $("error")) {
  if (state.following) state.following.abort();
  const controller = new AbortController();
  state.following = controller;
  state.stageIndex = null;
  resetReadout();
  $("progress").hidden = false;
  $("result").hidden = true;
  $("job-id").textContent = id;
  $("cancel").onclick = () => cancel(id);
  let final = null;
  while (!final && !controller.signal.aborted) {
    try {
      final = await readEvents(`jobs/${id}/events`, controller.signal, renderProgress);
    } catch (err) {
      if (controller.signal.aborted) return;
      if (err instanceof ApiError && err.status !== 0) {
        showError(err, errors);
        return;
      }
    }
    // A dropped connection: reconnect; the stream starts again with the job's current state.
    if (!final) await new Promise((resolve) => setTimeout(resolve, 1000));
  }
  if (controller.signal.aborted) return;
  state.following = null;
  refreshJobs();
  if (final.status === "succeeded") await showResult(final.id);
  else if (final.error) showError(final.error, errors);
}

/** The quality line and its spark line emptied: a new job, or the next object of a scene (its figures are its own). */
function resetReadout() {
  state.figures = [];
  state.readout = false;
  drawSpark();
  $("quality").textContent = "";
}

function stageName(job) {
  if (job.status !== "running") return job.status;
  const p = job.progress;
  return p.stage && p.stage.name !== "queued" ? p.stage.name : p.kind;
}

function renderProgress(job) {
  const p = job.progress;
  const name = stageName(job);
  let stage = name;
  const several = p.stage && p.stage.count > 1;
  if (job.kind === "assemble" && ["search", "refine"].includes(name)) { // counted as uploaded: the first stays put
    stage += ` - placing object ${p.stage.index + 1} of ${p.stage.count + 1}${p.stage.label ? `: ${p.stage.label}` : ""}`;
  } else if (several) {
    stage += ` - copy ${p.stage.index} of ${p.stage.count}${p.stage.label ? ` (${p.stage.label})` : ""}`;
  }
  const perObject = job.kind === "assemble" || several; // one readout per object placed
  if (perObject && state.stageIndex !== p.stage.index) { // the next object: its own readout
    if (state.stageIndex !== null) resetReadout();
    state.stageIndex = p.stage.index;
  }
  if (p.phase && p.phases && job.status === "running") stage += ` - phase ${p.phase} of ${p.phases}`; // none in the search
  $("stage").textContent = stage;
  // 100 % once the job has succeeded, not while its results are still being written.
  const percent = job.status === "succeeded" ? 100 : Math.min(99, Math.floor(100 * p.fraction));
  $("bar").value = percent;
  $("percent").textContent = `${percent} %`;
  $("steps").textContent = p.steps
    ? `${name === "search" ? "candidate" : "step"} ${p.step} of ${p.steps}${p.restarts ? `, ${p.restarts} restarts` : ""}`
    : "";
  const times = [];
  if (p.eta_s != null && !TERMINAL.includes(job.status)) {
    times.push(`about ${duration(p.eta_s)} left${perObject ? " for this one" : ""}`);
  }
  if (p.elapsed_s) times.push(`${duration(p.elapsed_s)} elapsed`);
  $("eta").textContent = times.join(", ");
  const quality = readout(p);
  if (quality) { // nothing at a phase start: the last figures stay up
    $("quality").textContent = quality;
    const figure = p.guide_match ?? (p.contact_gap == null ? null : -p.contact_gap); // higher is better
    if (figure != null && state.figures.at(-1) !== figure) state.figures.push(figure);
    drawSpark();
  }
  $("guide").textContent = job.guide ? `guide: ${job.guide}${job.guide === "none" ? " (the geometry and the "
    + "prompt's relation place it)" : ""}` : "";
  $("guide").title = job.guide_why || "";
  $("message").textContent = p.message + (job.cancel_requested && job.status === "running" ? " - cancel requested" : "");
  $("cancel").disabled = TERMINAL.includes(job.status) || job.cancel_requested;
}

// What a person reads instead of the objective (its scale changes with each phase's weights): the relation's
// verdict, the answer's match to the guide and its gap to the target (the restart the run would answer with now,
// its answer at the end); the objective only when none is known.
function readout(p) {
  const parts = [];
  if (p.relation && p.relation_checked) {
    const what = p.stage && p.stage.name === "search" ? "candidates scored" : "restarts";
    parts.push(`'${p.relation}' holds for ${p.relation_holds} of ${p.relation_checked} ${what}`);
  }
  if (p.guide_match != null) parts.push(`guide match ${p.guide_match.toFixed(3)} (the answer; higher is better)`);
  if (p.contact_gap != null) {
    parts.push(p.contact_gap < 0.005 ? "touching" : `gap ${(100 * p.contact_gap).toFixed(1)} % of the source's size`);
  }
  // the objective only while no readout came (a run without a relation, before its refinement); the exporting
  // and done events carry none, and the last readout stays up
  if (!parts.length && p.objective != null && !state.figures.length && !state.readout) {
    return `objective ${p.objective.toFixed(4)} (best so far; lower is better)`;
  }
  if (parts.length) state.readout = true;
  return parts.join(" - ");
}

function drawSpark() {
  const canvas = $("spark");
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const values = state.figures;
  canvas.hidden = values.length < 2;
  if (values.length < 2) return;
  const lo = Math.min(...values);
  const span = Math.max(...values) - lo || 1;
  ctx.strokeStyle = "#2563eb";
  ctx.lineWidth = 2;
  ctx.beginPath();
  values.forEach((v, i) => {
    const x = (i / (values.length - 1)) * (canvas.width - 4) + 2;
    const y = 2 + (1 - (v - lo) / span) * (canvas.height - 4);
    if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y);
  });
  ctx.stroke();
}

async function cancel(id) {
  try {
    renderProgress(await api.json(`jobs/${id}`, { method: "DELETE" }));
  } catch (err) {
    showError(err);
  }
}

// -- the result -------------------------------------------------------------------------------------

/** "Add an object to this scene": the next job's target is this result's scene (target_job), its objects
 * kept apart and in place; the form keeps the other settings, and the scene shows in the target's preview. */
async function addObject() {
  const { id, blobs } = state.result;
  const file = new File([blobs["result.glb"]], `scene-${id.slice(0, 8)}.glb`, { type: "model/gltf-binary" });
  setFile("target", file);
  state.chained = { id, file };
  $("chosen-target").textContent = `the scene of job ${id.slice(0, 8)} (its objects stay put)`;
  const names = await glbNodeNames(blobs["result.glb"]);
  fillGrounds($("on-1"), "the last placed (or the two a \"between\" prompt names)", names);
  fillGrounds($("on-2"), "no other", names);
  $("grounds").hidden = false;
  setFile("source", null);
  for (const field of ["name-target", "name-source", "prompt"]) $(field).value = "";
  $("new-job").scrollIntoView();
  $("prompt").focus();
}

/** The names of a GLB's mesh nodes, as the service reads the scene back (its JSON chunk; the 3D view's names are
 * three.js's, with spaces replaced). */
async function glbNodeNames(glb) {
  const buffer = await glb.arrayBuffer();
  const length = new DataView(buffer).getUint32(12, true);
  const json = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 20, length)));
  return (json.nodes || []).filter((node) => node.mesh !== undefined && node.name).map((node) => node.name);
}

/** A "relates to" select: "" (``none``: the service's default), then the scene's objects. */
function fillGrounds(select, none, names) {
  select.replaceChildren(new Option(none, ""), ...names.map((name) => new Option(name, name)));
}

async function showResult(id) {
  clearError();
  clearError($("scene-error"));
  delete $("viewer").dataset.ready; // set again once this result is drawn (showScene)
  let job, glb, report, preview, strip;
  try {
    [job, glb, report, preview, strip] = await Promise.all([
      api.json(`jobs/${id}`), api.blob(`jobs/${id}/result.glb`), api.blob(`jobs/${id}/report.json`),
      api.blob(`jobs/${id}/preview.png`).catch(() => null), // a run may have no preview
      api.blob(`jobs/${id}/alternatives.png`).catch(() => null), // nor an assembly alternatives
    ]);
  } catch (err) {
    showError(err);
    return;
  }
  state.urls.forEach((url) => URL.revokeObjectURL(url));
  state.urls = [];
  state.result = { id, job, alternative: 0, glbs: { 0: glb },
                   blobs: { "result.glb": glb, "report.json": report, "preview.png": preview } };
  $("result").hidden = false;
  $("result-id").textContent = id;
  const facts = JSON.parse(await report.text());
  state.result.facts = facts;
  showFacts(facts);
  document.querySelector("[data-file='original.glb']").hidden = !facts.adjusted;
  showAlternatives(facts.alternatives || [], strip);
  $("objects").hidden = !facts.objects;
  if (preview) {
    const url = URL.createObjectURL(preview);
    state.urls.push(url);
    $("preview").src = url;
  }
  $("preview").hidden = !preview;
  document.querySelector("[data-file='preview.png']").disabled = !preview;
  try {
    await showScene(glb);
  } catch (err) {
    showError({ code: "viewer_error", detail: `the scene could not be shown: ${err.message}` });
  }
}

/** Draw a result GLB in the 3D view, with its parts' toggles and the handles on its source; the view is marked
 * ready once it is drawn. */
async function showScene(glb) {
  const viewerBox = $("viewer");
  delete viewerBox.dataset.ready;
  state.viewer = state.viewer || new Viewer(viewerBox);
  viewerBox.viewer = state.viewer; // for scripts (the browser test finds the handles through it)
  const parts = await state.viewer.show(await glb.arrayBuffer());
  showParts(parts);
  state.result.parts = parts;
  if (state.result.facts.objects) showObjects(state.result.shownFacts); // the thumbnails are the view's
  makeAdjustable(parts);
  viewerBox.dataset.ready = "1";
}

/** The strip of alternatives: each distinct placement the run refined (the answer first) as a thumbnail cut
 * from alternatives.png (the views side by side), with its relation verdict and guide match; a click shows it
 * in the 3D view, and the GLB download follows the one shown. */
function showAlternatives(alternatives, strip) {
  const box = $("alternatives");
  box.replaceChildren();
  box.hidden = alternatives.length < 2 || !strip;
  $("alternatives-order").hidden = box.hidden;
  if (box.hidden) return;
  const url = URL.createObjectURL(strip);
  state.urls.push(url);
  alternatives.forEach((alt, k) => {
    const button = Object.assign(document.createElement("button"), { type: "button", className: "alternative" });
    button.dataset.alternative = String(k);
    button.style.backgroundImage = `url(${url})`;
    button.style.backgroundSize = `${alternatives.length * 100}% 100%`;
    button.style.backgroundPosition = `${(100 * k) / (alternatives.length - 1)}% 0`;
    const holds = alt.relation ? (alt.relation.holds ? ` - '${alt.relation.name}' holds` : ` - not '${alt.relation.name}'`) : "";
    const match = alt.clip ? ` - guide match ${(-alt.clip).toFixed(2)}` : "";
    const caption = document.createElement("span");
    caption.textContent = `${k === 0 ? "answer" : `#${k + 1}`}${holds}${match}`;
    button.append(caption);
    button.title = caption.textContent;
    button.addEventListener("click", () => chooseAlternative(k));
    box.append(button);
  });
  markAlternative();
}

async function chooseAlternative(k) {
  const result = state.result;
  try {
    result.glbs[k] = result.glbs[k] || await api.blob(`jobs/${result.id}/result.glb?alternative=${k}`);
    if (state.result !== result) return; // another result was opened meanwhile
    result.alternative = k;
    result.blobs["result.glb"] = result.glbs[k];
    const alt = result.facts.alternatives[k]; // the facts table shows the placement shown
    showFacts({ ...result.facts, transform: alt.transform, relation: alt.relation, contact: alt.contact });
    await showScene(result.glbs[k]);
  } catch (err) {
    showError(err);
  }
  markAlternative();
}

function markAlternative() {
  const k = state.result.alternative;
  $("viewer").dataset.alternative = String(k);
  for (const button of document.querySelectorAll("#alternatives button")) {
    button.classList.toggle("chosen", button.dataset.alternative === String(k));
  }
  // a chained job builds on the job's answer (its result.glb): offered while the answer is shown
  $("add-object").disabled = k !== 0;
  $("add-object").title = k === 0 ? "" : "the next object is added to the job's answer: show it first";
}

function showParts(parts) {
  const box = $("parts");
  box.replaceChildren();
  for (const part of parts) {
    const label = document.createElement("label");
    const check = Object.assign(document.createElement("input"), { type: "checkbox", checked: true });
    check.addEventListener("change", () => state.viewer.setVisible(part, check.checked));
    const swatch = document.createElement("span");
    swatch.className = "swatch";
    swatch.style.background = `#${part.tint.toString(16).padStart(6, "0")}`;
    label.append(check, " ", swatch, ` ${part.name}`);
    box.append(label);
  }
  const tint = document.createElement("label");
  const check = Object.assign(document.createElement("input"), { type: "checkbox", id: "tint" });
  check.addEventListener("change", () => state.viewer.setTinted(check.checked));
  tint.append(check, " tint each object");
  box.append(tint);
}

// Scale mode (report.extra.scale): where the scale started and why, beside the scale found.
function scaleOrigin(scale) {
  if (!scale) return "";
  const why = scale.from === "geometry" ? scale.constraint.kind
    : `the priors' size ratio ${Number(scale.size_ratio).toPrecision(3)} (${scale.names.source} / ${scale.names.target})`;
  return ` (found; started at ${Number(scale.initial).toFixed(3)} from ${why})`;
}

function showFacts(report) {
  state.result.shownFacts = report;
  const job = state.result.job || {};
  const label = report.objects ? job.description : report.prompt;
  $("result-prompt").textContent = label ? `"${label}"` : job.image_guided ? "guided by a reference image" : "";
  const rows = report.objects ? sceneRows(report) : pairRows(report);
  if (report.adjusted) {
    const which = report.adjustment.object ? `${report.adjustment.object} moved ` : "";
    rows.push(["adjusted", `${which}by hand, saved ${new Date(report.adjustment.saved_at).toLocaleString()} `
      + "(original.glb keeps the run's placement)"]);
  }
  const table = $("transform");
  table.replaceChildren();
  for (const [name, value] of rows) {
    if (value === "" || value == null) continue; // no empty rows
    const tr = table.insertRow();
    tr.insertCell().textContent = name;
    tr.insertCell().textContent = value;
  }
  if (report.objects) showObjects(report);
}

// Lengths as the files give them: glTF files are in metres (their spec), other formats say no unit.
const UNITS = "in the files' units (metres for glTF)";

/** Where the source was put, in words: how far from the target's origin, turned by how many degrees about which
 * axis, at what size; the relation's verdict and contact; who chose among the placements. */
function pairRows(report) {
  const t = report.transform || {};
  const fixed = (values, digits) => (values || []).map((v) => Number(v).toFixed(digits)).join(", ");
  const rows = report.copies ? copyRows(report, fixed) : [
    ["position", t.translation ? `${fixed(t.translation, 3)} from the target's origin, ${UNITS}` : ""],
    ["turn", t.rotation_wxyz ? turnWords(t.rotation_wxyz) : ""],
    ["size", t.scale != null ? sizeWords(Number(t.scale)) + scaleOrigin((report.extra || {}).scale) : ""],
  ];
  const verdict = report.relation || {};
  if (!report.copies && report.relation !== undefined) {
    rows.push(["relation", report.relation ? `'${verdict.name}' ${verdict.holds ? "holds" : "does not hold"}`
      + (verdict.stable === false ? ", may tip over" : "") : "none read from the prompt"]);
  }
  if (report.contact) {
    rows.push(["contact", report.contact.touching ? "touching"
      : `not touching: a gap of ${(100 * report.contact.gap).toFixed(1)} % of the source's size`]);
  }
  if (verdict.usual) { // the relation's usual place and the ground's part it is on (predicates.RelationVerdict)
    rows.push(["usual place", (verdict.place ? `the prompt names "${verdict.place}": ` : "") + verdict.usual]);
  }
  if (verdict.pose) rows.push(["source pose", verdict.pose]); // how it stands against how it is set down
  const named = (report.extra || {}).parts || [];
  if (named.length) rows.push(["the ground's parts", named.join("; ")]); // relations.parts, with why
  const grounds = (report.extra || {}).grounds || [];
  if (grounds.length) rows.push(["relates to", grounds.join(" and ")]); // a scene target's objects it was placed by
  if (report.guide_say) rows.push(["who chose", report.guide_say.summary]); // the guide's say (ordering.GuideSay)
  rows.push(["guided by", report.model && report.guide !== "none" ? report.model : "the geometry and the relation"]);
  rows.push(["run", `preset ${report.preset ?? "default"}, seed ${report.seed ?? "default"}`]);
  return rows;
}

/** A rotation (a unit quaternion w, x, y, z) in degrees about its axis, in the target's file frame. */
function turnWords([w, x, y, z]) {
  const angle = (2 * Math.acos(Math.min(1, Math.abs(w))) * 180) / Math.PI;
  if (angle < 0.05) return "not turned";
  const n = Math.hypot(x, y, z) * Math.sign(w || 1);
  const axis = [x, y, z].map((v) => (v / n).toFixed(2)).join(", ");
  return `turned ${angle.toFixed(1)}° about (${axis})`;
}

function sizeWords(scale) {
  return Math.abs(scale - 1) < 5e-4 ? "as in its file" : `${scale.toFixed(3)} times its file's size`;
}

/** A scene (an assembly's report): the scene's verdict, the run's settings; each object is in the objects list. */
function sceneRows(report) {
  const first = (report.stages || [])[0] || {};
  return [
    ["the scene", report.whole ? sceneSummary(report.whole) : ""],
    ["objects", `${report.objects.length}: ${report.objects[0].name} stays put, the others placed in order`],
    ["guided by", first.guide && first.guide !== "none" ? first.guide : "the geometry and each relation"],
    ["run", `preset ${report.preset ?? "default"}, seed ${report.seed ?? "default"}`],
  ];
}

/** Each object of a scene: a thumbnail (the scene drawn with it in its colour), its relation, what it stands on and
 * its verdict on the final scene. */
function showObjects(report) {
  const list = $("objects");
  const relations = (report.whole || {}).relations || [];
  const judged = new Map(relations.filter((r) => !r.also).map((r) => [r.name, r]));
  const parts = state.result.parts || [];
  list.replaceChildren(...report.objects.map((object, k) => {
    const item = document.createElement("li");
    item.dataset.object = object.name;
    const image = Object.assign(document.createElement("img"), { className: "thumb", alt: object.name });
    if (parts[k] && state.viewer) image.src = state.viewer.thumbnail(parts[k]);
    const facts = k === 0 ? `stays put; stands on ${object.stands_on === "floor" ? "the floor" : object.stands_on}`
      : judged.has(object.name) ? objectFacts(judged.get(object.name), object.stands_on,
        relations.filter((r) => r.also && r.name === object.name)) : "";
    const words = Object.assign(document.createElement("span"), { className: "object-facts" });
    words.append(Object.assign(document.createElement("strong"), { textContent: object.name }), ` - ${facts}`);
    item.append(image, words);
    return item;
  }));
}

/** A run of several copies (``copies_report``): the set's measures, then each copy's place and verdict. */
function copyRows(report, fixed) {
  const m = report.metrics || {};
  const spacing = m.min_spacing == null ? "" : `, closest two ${Number(m.min_spacing).toFixed(3)} source diagonals apart`;
  const rows = [
    ["copies", `${report.count} (${report.arrangement}), each judged "${report.relation ?? "no relation"}"`],
    ["the set", `${m.relation_holds ?? 0} of ${m.judged ?? 0} hold; ${m.none_intersect ? "none intersect" : "some intersect"}`
      + spacing],
  ];
  for (const c of report.copies) {
    const verdict = c.relation ? (c.relation.holds ? "holds" : "fails") + ` on ${c.on}` : "";
    rows.push([c.name, `${fixed(c.transform.translation, 3)} (target file frame); ${verdict}; ${c.seconds} s`]);
  }
  return rows;
}

async function download(file) {
  const result = state.result;
  if (!result) return;
  let blob = result.blobs[file];
  if (!blob && file === "original.glb") { // the run's own placement, once an adjustment was saved
    try {
      blob = result.blobs[file] = await api.blob(`jobs/${result.id}/original.glb`);
    } catch (err) {
      showError(err);
      return;
    }
  }
  if (!blob) return;
  const url = URL.createObjectURL(blob);
  const k = file === "result.glb" ? state.result.alternative : 0;
  const name = k ? `${state.result.id}-result-${k + 1}.glb` : `${state.result.id}-${file}`;
  const link = Object.assign(document.createElement("a"), { href: url, download: name });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 60_000);
}

// -- adjusting the result by hand -------------------------------------------------------------------

/** Handles on the result's source (an alignment's last node; one of several copies, chosen in the copy select; one
 * placed object of a scene, chosen in the object select) and the buttons that settle, reset and save it (POST
 * /jobs/{id}/adjust, run by a worker: the settling is the search's own; a scene's relations are all judged again). */
function makeAdjustable(parts) {
  const facts = state.result.facts;
  const box = $("adjust");
  box.hidden = !(facts.transform || facts.copies || facts.objects) || parts.length < 2;
  $("adjust-copy-label").hidden = !facts.copies;
  $("adjust-object-label").hidden = !facts.objects;
  if (box.hidden) return;
  if (facts.objects) { // the GLB's nodes are the report's objects, in order; the first (the base) stays put
    const select = $("adjust-object");
    select.replaceChildren(...facts.objects.slice(1).map((o, i) => new Option(o.name, String(i + 1))));
    select.value = String(state.result.object || facts.objects.length - 1);
    select.onchange = () => {
      resetAdjusted();
      state.result.object = Number(select.value);
      makeAdjustable(parts);
    };
    state.result.object = Number(select.value);
    state.viewer.adjustable(parts[state.result.object]);
  } else if (facts.copies) {
    const select = $("adjust-copy");
    select.replaceChildren(...facts.copies.map((c, i) => new Option(c.name, String(i + 1))));
    select.value = String(state.result.copy || 1);
    select.onchange = () => {
      resetAdjusted(); // an unsaved move of the copy left is dropped
      state.result.copy = Number(select.value);
      makeAdjustable(parts);
    };
    state.result.copy = Number(select.value);
    state.viewer.adjustable(parts.find((p) => p.name === facts.copies[state.result.copy - 1].name));
  } else {
    state.viewer.adjustable(parts.at(-1));
  }
  state.viewer.onAdjust = (rows) => {
    state.result.dirty = true;
    showTransform(rows);
    setAdjustState("moved", "moved by hand - not saved");
  };
  state.result.shown = state.viewer.sourceMatrix(); // what Reset goes back to
  state.result.dirty = false;
  setAdjustState("idle", facts.adjusted ? "this placement was adjusted by hand and saved" : "");
}

/** The adjust line's state (``data-state``: idle, moved, busy, settled, unsettled, saved, failed) and text; Save
 * is offered while the placement shown differs from the stored one. */
function setAdjustState(name, text, bad = false) {
  const line = $("adjust-state");
  line.dataset.state = name;
  line.textContent = text;
  line.classList.toggle("bad", bad);
  for (const id of ["adjust-drop", "adjust-push", "adjust-reset"]) $(id).disabled = name === "busy";
  $("adjust-save").disabled = name === "busy" || !state.result.dirty;
}

/** The facts table follows the source (or the copy adjusted) as it is moved (the report's other numbers stay the
 * run's). */
function showTransform(rows) {
  const facts = state.result.shownFacts;
  if (facts.objects) return; // a scene's facts are its relations: judged again by a drop, a push or a save
  if (!facts.copies) {
    showFacts({ ...facts, transform: similarityParts(rows) });
    return;
  }
  const k = state.result.copy - 1;
  showFacts({ ...facts, copies: facts.copies.map((c, i) => (i === k ? { ...c, transform: similarityParts(rows) } : c)) });
}

/** Send an adjustment and wait for it (Prefer: wait, then reading it until it ends); a failed one throws. */
async function adjustment(body) {
  if (state.result.facts.copies) body.copy_index = state.result.copy;
  if (state.result.facts.objects) body.object = state.result.facts.objects[state.result.object].name;
  let adjusted = await api.json(`jobs/${state.result.id}/adjust`, {
    method: "POST", body: JSON.stringify(body), headers: { "Content-Type": "application/json", Prefer: "wait=30" } });
  while (!["succeeded", "failed"].includes(adjusted.status)) {
    await new Promise((resolve) => setTimeout(resolve, 500));
    adjusted = await api.json(adjusted.link.replace(/^\//, ""));
  }
  if (adjusted.status === "failed") throw new ApiError(422, adjusted.error);
  return adjusted.result;
}

function describeOutcome(outcome, how) {
  const percent = (v) => `${(100 * v).toFixed(1)} %`;
  if (outcome.settled === false) return "nothing to touch that way: left where it was";
  const parts = [how === "drop" ? "dropped" : "pushed"];
  parts.push(outcome.on_floor ? "resting on the floor"
    : outcome.contact_gap < 0.005 ? "touching" : `a gap of ${percent(outcome.contact_gap)} of its size`);
  parts.push(outcome.penetration > 0.0005 ? `sunk ${percent(outcome.penetration)} of its size into what it touches`
    : "not sunk");
  if (outcome.relation) parts.push(`'${outcome.relation.name}' ${outcome.relation.holds ? "holds" : "does not hold"}`);
  if (outcome.whole) parts.push(`the scene: ${sceneSummary(outcome.whole)}`); // every relation judged again
  return `${parts.join(" - ")} - not saved`;
}

/** "Drop to contact" (along the target's up) or "Push along view" (the way the camera looks). */
async function settle(how) {
  const { viewer } = state;
  const result = state.result;
  const body = { transform: viewer.sourceMatrix(), settle: how };
  if (how === "push") body.direction = viewer.viewDirection();
  const before = $("adjust-state").dataset.state;
  setAdjustState("busy", how === "drop" ? "dropping..." : "pushing...");
  try {
    const outcome = await adjustment(body);
    if (state.result !== result) return; // another result was opened meanwhile
    if (outcome.settled) {
      viewer.placeSource(outcome.transform);
      showTransform(outcome.transform);
      result.dirty = true;
      if (outcome.whole) { // a scene: each object's verdict with this one where it was dropped
        const objects = result.facts.objects.map((o) => ({ ...o, stands_on: outcome.stands_on[o.name] ?? o.stands_on }));
        showFacts({ ...result.facts, whole: outcome.whole, objects });
      }
    }
    setAdjustState(outcome.settled ? "settled" : "unsettled", describeOutcome(outcome, how));
  } catch (err) {
    if (state.result === result) setAdjustState(before, `${err.code}: ${err.detail ?? err.message}`, true);
  }
}

async function saveAdjusted() {
  const result = state.result;
  setAdjustState("busy", "saving...");
  try {
    await adjustment({ transform: state.viewer.sourceMatrix(), save: true });
    if (state.result !== result) return;
    await showResult(result.id); // the job's result is the adjusted scene now
    setAdjustState("saved", "saved: the job's result.glb is this placement (original.glb keeps the run's own)");
  } catch (err) {
    if (state.result === result) setAdjustState("failed", `${err.code}: ${err.detail ?? err.message}`, true);
  }
}

function resetAdjusted() {
  state.viewer.placeSource(state.result.shown);
  showTransform(state.result.shown);
  state.result.dirty = false;
  setAdjustState("idle", "");
}

// -- recent jobs ------------------------------------------------------------------------------------

async function refreshJobs(more = false) {
  const path = more && state.nextPage ? state.nextPage.replace(/^\//, "") : "jobs?limit=10";
  let page;
  try {
    page = await api.json(path);
  } catch (err) {
    if (err.status !== 401) showError(err); // 401: the key form already asks
    return;
  }
  const body = $("jobs-body");
  if (!more) body.replaceChildren();
  for (const [job, depth] of grouped(page.jobs)) {
    const row = body.insertRow();
    row.dataset.id = job.id;
    row.insertCell().textContent = new Date(job.created_at).toLocaleString();
    const status = row.insertCell();
    status.textContent = job.status + (job.error && job.error.code !== job.status ? ` (${job.error.code})` : "");
    status.className = `status-${job.status}`;
    const what = row.insertCell();
    what.textContent = `${"↳ ".repeat(depth)}${job.description ?? job.prompt ?? (job.image_guided ? "(reference image)" : "")}`
      + (job.kind === "assemble" ? ` (a scene of ${job.stages + 1} objects)` : "")
      + (job.target_job ? ` (added to the scene of ${job.target_job.slice(0, 8)})` : "");
    const open = document.createElement("button");
    open.type = "button";
    open.textContent = job.status === "succeeded" ? "Open" : TERMINAL.includes(job.status) ? "Details" : "Follow";
    open.addEventListener("click", () => reopen(job));
    row.insertCell().append(open);
  }
  state.nextPage = page.next;
  $("jobs-more").hidden = !page.next;
}

/** The page's jobs with each job that adds to another's scene right under it (newest first, as listed), and
 * its depth in the chain: a scene built object by object reads as one group. */
function grouped(jobs) {
  const listed = new Set(jobs.map((job) => job.id));
  const children = new Map();
  for (const job of jobs) {
    if (job.target_job && listed.has(job.target_job)) {
      children.set(job.target_job, [...(children.get(job.target_job) || []), job]);
    }
  }
  const out = [];
  const visit = (job, depth) => {
    out.push([job, depth]);
    for (const child of children.get(job.id) || []) visit(child, depth + 1);
  };
  for (const job of jobs) if (!(job.target_job && listed.has(job.target_job))) visit(job, 0);
  return out;
}

async function reopen(job) {
  clearError();
  if (job.status === "succeeded") {
    if (state.following) state.following.abort();
    $("progress").hidden = true;
    await showResult(job.id);
  } else {
    // a running job's progress; an ended one's final state and error, beside the form of its kind
    follow(job.id, job.kind === "assemble" ? $("scene-error") : $("error"));
  }
}

// -- start ------------------------------------------------------------------------------------------

// One line over the page when jobs run without a guide (/readyz: model auto without the default model's weights).
async function showGuide() {
  let ready;
  try { ready = await (await fetch("readyz")).json(); } catch { return; } // the page works without it
  if (ready.guide !== "none") return;
  const banner = $("guide-banner");
  banner.textContent = `No guide: the geometry and the prompt's relation place the source (the default model is `
    + `not on the workers). ${ready.get_model ? `\`${ready.get_model}\` gets it.` : ""}`;
  banner.title = ready.why;
  banner.hidden = false;
}

async function init() {
  const config = (state.config = await (await fetch("page/config")).json());
  showGuide();
  $("formats").textContent = config.formats.join(" ");
  for (const role of ROLES) {
    $(`file-${role}`).accept = config.formats.join(",");
    $(`name-${role}`).maxLength = config.name_max;
    wireDrop(role);
    wireAxes(role);
  }
  const samples = $("samples");
  for (const sample of config.samples) {
    const button = Object.assign(document.createElement("button"), { type: "button", textContent: sample.prompt });
    button.dataset.sample = sample.name;
    button.addEventListener("click", () => useSample(sample));
    samples.append(button, " ");
  }
  for (const preset of config.presets) {
    $("opt-preset").append(new Option(preset, preset, false, preset === config.default_preset));
  }
  for (const [name, bounds] of Object.entries(config.bounds)) {
    if (bounds.minimum != null) $(`opt-${name}`).min = bounds.minimum;
    if (bounds.maximum != null) $(`opt-${name}`).max = bounds.maximum;
  }
  $("prompt").maxLength = config.prompt_max;
  document.querySelectorAll("input[name=guide]").forEach((r) => r.addEventListener("change", guideChanged));
  $("align-form").addEventListener("submit", submit);
  document.querySelectorAll("[data-file]").forEach((b) => b.addEventListener("click", () => download(b.dataset.file)));
  $("add-object").addEventListener("click", addObject);
  wireScene({ api, options, showError: (err) => showError(err, $("scene-error")),
              clearError: () => clearError($("scene-error")),
              submitJob: (path, data, button) => submitJob(path, data, button, $("scene-error")) });
  document.querySelectorAll("input[name=adjust-mode]").forEach((r) => r.addEventListener("change", () => {
    state.viewer?.setHandles(document.querySelector("input[name=adjust-mode]:checked").value || null);
  }));
  $("adjust-drop").addEventListener("click", () => settle("drop"));
  $("adjust-push").addEventListener("click", () => settle("push"));
  $("adjust-reset").addEventListener("click", resetAdjusted);
  $("adjust-save").addEventListener("click", saveAdjusted);
  $("jobs-refresh").addEventListener("click", () => refreshJobs());
  $("jobs-more").addEventListener("click", () => refreshJobs(true));
  $("key-form").addEventListener("submit", (e) => {
    e.preventDefault();
    state.key = $("api-key").value.trim();
    sessionStorage.setItem("ctp-key", state.key);
    $("key-state").textContent = state.key ? "key set" : "";
    clearError();
    refreshJobs();
  });
  if (config.auth) {
    $("key-form").hidden = false;
    $("api-key").value = state.key;
    if (!state.key) askForKey("this service needs an API key");
  }
  if (!config.auth || state.key) refreshJobs();
  document.body.dataset.ready = "1";
}

init().catch((err) => showError({ code: "page_error", detail: `the page could not start: ${err.message}` }));
