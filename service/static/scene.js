// A scene from one sentence on the page: several meshes and one description are read into a plan
// (POST /plans/read), shown as a list a person can correct (each step's prompt and what it relates to; what it
// stands on, the other relations said of it and its warnings shown beside it), then
// placed as that plan says (POST /assemble: the edited plan, not the sentence, is what runs). The page's own
// calls, option fields and job submitter are passed in by page.js (wireScene), so this module holds no state
// of the page's and imports nothing from it.

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
      const body = JSON.stringify({ prompt: $("scene-prompt").value, names: names() });
      scene.plan = await api.json("plans/read", { method: "POST", body,
                                                  headers: { "Content-Type": "application/json" } });
    } catch (err) {
      showError(err);
      return;
    }
    showPlan(scene.plan);
  });

  /** The plan as a list: the base, then one row per step with its prompt and grounds editable. */
  function showPlan(plan) {
    const list = $("scene-plan");
    const base = document.createElement("li");
    base.textContent = `${plan.base} stays put (stands on the floor)`;
    list.append(base);
    plan.steps.forEach((step, i) => {
      const row = document.createElement("li");
      row.dataset.step = i;
      const what = Object.assign(document.createElement("span"), {
        className: "step-name", textContent: `${step.name} (${step.relation}${step.floor ? ", on the floor" : ""})`,
      });
      const prompt = Object.assign(document.createElement("input"), { type: "text", value: step.prompt,
                                                                     className: "step-prompt" });
      const on = Object.assign(document.createElement("input"), { type: "text", value: step.on.join(", "),
                                                                 className: "step-on", title: "relates to" });
      const stands = Object.assign(document.createElement("span"), {
        className: "step-support", textContent: `stands on ${step.support}`,
      });
      row.append(what, " ", prompt, " relates to ", on, " ", stands);
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
    data.append("options", JSON.stringify(options()));
    await submitJob("assemble", data, $("scene-place"));
  });
}

/** The facts of an assembly's final scene (the report's ``whole``): one row per relation, judged again. */
export function wholeRows(report) {
  const whole = report.whole;
  if (!whole) return [];
  const rows = whole.relations.map((r) => [
    `${r.name} ${r.relation} ${r.on.join(" and ")}`,
    `${r.holds ? "holds" : "does not hold"}${r.stable === false ? ", not stable" : ""}`
      + `${r.intersects ? ", intersects another object" : ""}`,
  ]);
  const held = whole.relations.filter((r) => r.holds).length;
  rows.unshift(["the scene", `${held} of ${whole.relations.length} relations hold; `
    + `${whole.none_intersect ? "none intersect" : "some intersect"}`]);
  return rows;
}
