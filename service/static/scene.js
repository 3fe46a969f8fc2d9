// A scene from one sentence on the page: several meshes and one description are read into a plan
// (POST /plans/read), shown as a list a person can correct (each step's prompt and what it relates to; what it
// stands on, the other relations said of it and its warnings shown beside it), then
// placed as that plan says (POST /assemble: the edited plan, not the sentence, is what runs; the sentence is the
// job's label). A step whose prompt or grounds are edited is read again, so its relation and support are the edited
// prompt's. The page's own calls, option fields and job submitter are passed in by page.js (wireScene), so this
// module holds no state of the page's and imports nothing from it; it also words a scene's result (objectFacts).

const $ = (id) => document.getElementById(id);

/** The name the service gives a file when none is said (ctp_core.reading.names.default_name). */
const stemName = (file) => file.name.replace(/\.[^.]*$/, "").replace(/[_-]/g, " ").trim() || "object";

export function wireScene({ api, options, showError, clearError, submitJob }) {
  const scene = { files: [], plan: null };

  $("scene-files").addEventListener("change", () => {
    scene.files = [...$("scene-files").files];
    $("scene-names").placeholder = scene.files.map(stemName).join(", ") || "from the file names";
    clearPlan();
  });

  function clearPlan() {
    scene.plan = null;
    $("scene-plan").replaceChildren();
    $("scene-warnings").textContent = "";
    $("scene-place").disabled = true;
  }

  function names() {
    const said = $("scene-names").value.split(",").map((n) => n.trim()).filter(Boolean);
    return said.length ? said : scene.files.map(stemName);
  }

  $("scene-read").addEventListener("click", async () => {
    clearError();
    clearPlan();
    try {
      scene.plan = await readPlan($("scene-prompt").value, names());
    } catch (err) {
      showError(err);
      return;
    }
    showPlan(scene.plan);
  });

  function readPlan(prompt, objectNames) {
    return api.json("plans/read", { method: "POST", body: JSON.stringify({ prompt, names: objectNames }),
                                    headers: { "Content-Type": "application/json" } });
  }

  /** A step's prompt or grounds edited: the step read again (POST /plans/read of its prompt over its object and
   * its grounds), so that its relation and what it stands on are the edited prompt's; a prompt the reader
   * cannot read is said beside the step (the service still checks it when the scene is placed). */
  async function rereadStep(i) {
    const step = scene.plan.steps[i];
    const row = document.querySelector(`#scene-plan li[data-step='${i}']`);
    const on = row.querySelector(".step-on").value.split(",").map((n) => n.trim()).filter(Boolean);
    const objectName = names()[step.upload] ?? step.name;
    const note = row.querySelector(".step-reread");
    row.dataset.reading = "1";
    const asked = [...new Set([...(on.length ? on : [scene.plan.base]), objectName])];
    try {
      const read = await readPlan(row.querySelector(".step-prompt").value, asked);
      const found = read.steps.find((s) => s.upload === asked.indexOf(objectName));
      if (found) Object.assign(step, { relation: found.relation, floor: found.floor,
                                       support: supportIn(scene.plan, found.support, on) });
      note.textContent = found ? "" : `this prompt does not place the ${objectName}`;
    } catch (err) {
      note.textContent = `not read: ${err.detail ?? err.message}`;
    }
    row.querySelector(".step-name").textContent = stepLabel(step);
    row.querySelector(".step-support").textContent = `stands on ${step.support}`;
    delete row.dataset.reading;
  }

  /** The plan as a list: the base, then one row per step with its prompt and grounds editable. */
  function showPlan(plan) {
    const list = $("scene-plan");
    const base = document.createElement("li");
    base.textContent = `${plan.base} stays put (stands on the floor)`;
    list.append(base);
    plan.steps.forEach((step, i) => {
      const row = document.createElement("li");
      row.dataset.step = i;
      const what = Object.assign(document.createElement("span"), { className: "step-name", textContent: stepLabel(step) });
      const prompt = Object.assign(document.createElement("input"), { type: "text", value: step.prompt,
                                                                     className: "step-prompt" });
      const on = Object.assign(document.createElement("input"), { type: "text", value: step.on.join(", "),
                                                                 className: "step-on", title: "relates to" });
      const stands = Object.assign(document.createElement("span"), {
        className: "step-support", textContent: `stands on ${step.support}`,
      });
      for (const field of [prompt, on]) field.addEventListener("change", () => rereadStep(i));
      const reread = Object.assign(document.createElement("div"), { className: "step-reread hint" });
      row.append(what, " ", prompt, " relates to ", on, " ", stands, reread);
      for (const also of step.also) {  // what the description says of the object besides
        row.append(Object.assign(document.createElement("div"), {
          className: "step-also hint", textContent: `also ${also.relation} ${also.on.join(" and ")}`,
        }));
      }
      for (const warning of step.warnings) {  // each warning next to its step
        row.append(Object.assign(document.createElement("div"), { className: "step-warning hint",
                                                                  textContent: `warning: ${warning}` }));
      }
      list.append(row);
    });
    const stepWarnings = new Set(plan.steps.flatMap((step) => step.warnings));
    $("scene-warnings").textContent = plan.warnings.filter((w) => !stepWarnings.has(w)).join("; ");
    $("scene-place").disabled = false;
  }

  /** The plan as the list now says it, as POST /assemble takes it. */
  function editedSteps() {
    return scene.plan.steps.map((step, i) => {
      const row = document.querySelector(`#scene-plan li[data-step='${i}']`);
      const on = row.querySelector(".step-on").value.split(",").map((n) => n.trim()).filter(Boolean);
      return { file: scene.files[step.upload].name, name: step.name, prompt: row.querySelector(".step-prompt").value,
               on: on.length === 1 ? on[0] : on };
    });
  }

  $("scene-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    clearError();
    const plan = scene.plan;
    const data = new FormData();
    const base = scene.files[plan.base_upload];
    data.append("base", base, base.name);
    data.append("base_name", plan.base);
    const used = new Set(plan.steps.map((s) => s.upload));
    for (const index of used) data.append("source", scene.files[index], scene.files[index].name);
    data.append("plan", JSON.stringify(editedSteps()));
    data.append("description", plan.description); // the job's label: the sentence the plan was read from
    data.append("options", JSON.stringify(options()));
    await submitJob("assemble", data, $("scene-place")); // off until the job ends
    $("scene-place").disabled = !scene.plan;
  });
}

/** What a re-read step stands on in the whole plan: the reader of the step alone knows its grounds but not what
 * they stand on, so where it says the floor and its grounds all stand on one thing, that thing (the rule of
 * ``PlannedStep.support``: beside objects on the same top, on that top). */
function supportIn(plan, support, on) {
  if (support !== "floor" || !on.length) return support;
  const of = (name) => (name === plan.base ? plan.base_support : plan.steps.find((s) => s.name === name)?.support);
  const below = new Set(on.map(of));
  const [only] = below;
  return below.size === 1 && only ? only : support;
}

/** A step as the plan list names it: "toolbox (on)", "stool (left, on the floor)". */
function stepLabel(step) {
  return `${step.name} (${step.relation}${step.floor ? ", on the floor" : ""})`;
}

const RELATION_WORDS = { left: "left of", right: "right of", front: "in front of", near: "near", next: "next to" };

/** A relation as a person says it: "on the workbench", "left of the bench", "between the sofa and the armchair". */
export function relationWords(relation, on) {
  return `${RELATION_WORDS[relation] ?? relation} ${on.join(" and ")}`;
}

const mm = (v) => `${Number(v) < 10 ? Number(v).toFixed(1) : Math.round(Number(v))} mm`;

/** An object's verdict on the final scene (the report's ``whole``, each relation judged again) in words: whether its
 * relation holds, and each said of it besides (``also``), whether it may tip, how deep it sinks into another object
 * or below the floor (millimetres, measured on the meshes: the scene's units are metres in a glTF), what it stands
 * on. */
export function objectFacts(judged, standsOn, also = []) {
  const parts = [judged.relation ? `${relationWords(judged.relation, judged.on)}: `
    + (judged.holds ? "holds" : "does not hold") : `placed by ${judged.on.join(" and ")}`];
  for (const a of also) {
    if (a.relation) parts.push(`${relationWords(a.relation, a.on)}: ${a.holds ? "holds" : "does not hold"}`);
  }
  if (judged.stable === false) parts.push("may tip over");
  if (standsOn) parts.push(`stands on ${standsOn === "floor" ? "the floor" : standsOn}`);
  if (Number(judged.below_floor_mm) >= 0.5) parts.push(`${mm(judged.below_floor_mm)} below the floor`);
  if (Number(judged.penetration_mm) >= 0.5 && judged.into) parts.push(`${mm(judged.penetration_mm)} into ${judged.into}`);
  else if (judged.intersects) parts.push("intersects another object");
  return parts.join("; ");
}

/** The scene in one line: how many relations hold on the final scene, and whether any object intersects another. */
export function sceneSummary(whole) {
  const held = whole.relations.filter((r) => r.holds).length;
  return `${held} of ${whole.relations.length} relations hold; ${whole.none_intersect ? "no object intersects another"
    : "some objects intersect"}`;
}
