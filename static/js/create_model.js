// The create-model page: action-space kind, the discrete table editor, algorithm rules.
"use strict";
(function () {
  const form = document.getElementById("create-form");
  if (!form) return;
  const MIN_ACTIONS = 2;
  const MAX_ACTIONS = 30;
  const table = document.querySelector("#action-table tbody");
  const count = document.getElementById("action-count");
  const addButton = document.getElementById("add-action");

  const checked = (name) => (form.querySelector(`[name=${name}]:checked`) || {}).value;

  function renumber() {
    const rows = table.querySelectorAll("tr.action-row");
    rows.forEach((row, i) => (row.querySelector(".idx").textContent = i));
    count.textContent = rows.length;
    addButton.disabled = rows.length >= MAX_ACTIONS;
    rows.forEach((row) => (row.querySelector(".remove-row").disabled = rows.length <= MIN_ACTIONS));
  }

  addButton.addEventListener("click", () => {
    const rows = table.querySelectorAll("tr.action-row");
    if (rows.length >= MAX_ACTIONS) return;
    const copy = rows[rows.length - 1].cloneNode(true);
    copy.classList.remove("has-error");
    copy.querySelectorAll(".field-error").forEach((e) => e.remove());
    table.append(copy);
    renumber();
    copy.querySelector("input").focus();
  });
  table.addEventListener("click", (event) => {
    const button = event.target.closest(".remove-row");
    if (!button || table.querySelectorAll("tr.action-row").length <= MIN_ACTIONS) return;
    button.closest("tr").remove();
    renumber();
  });

  function sync() {
    const kind = checked("action_space_type");
    form.querySelectorAll(".kind-panel").forEach((p) => (p.hidden = p.dataset.kind !== kind));
    const sac = form.querySelector("[name=algorithm][value=sac]");
    const sacOption = document.getElementById("sac-option");
    sac.disabled = kind === "discrete";
    sacOption.classList.toggle("disabled", kind === "discrete");
    sacOption.title = kind === "discrete" ? "SAC needs a continuous action space" : "";
    if (sac.disabled && sac.checked) form.querySelector("[name=algorithm][value=clipped_ppo]").checked = true;
    const algorithm = checked("algorithm");
    form.querySelectorAll("[data-only]").forEach((f) => (f.hidden = f.dataset.only !== algorithm));
    const race = checked("race_type");
    form.querySelectorAll("[data-race]").forEach((f) => (f.hidden = f.dataset.race !== race));
  }
  form.addEventListener("change", sync);
  sync();
  renumber();

  // The race's layout on the chosen track, drawn by the server as the simulator places it
  // (/tracks/<id>/race.png); a setting it refuses is said in words under the picture.
  const layout = document.getElementById("race-layout");
  const layoutImg = document.getElementById("race-layout-img");
  const layoutNote = document.getElementById("race-layout-note");
  const LAYOUT_FIELDS = ["direction", "number_of_objects", "object_placement", "object_positions",
    "number_of_bots", "bot_speed", "lane_change_min_s", "lane_change_max_s"];
  let layoutTimer = null;
  let layoutUrl = "";
  function layoutSource() {
    const race = checked("race_type");
    const track = checked("track_id");
    if (!track || (race !== "OBJECT_AVOIDANCE" && race !== "HEAD_TO_BOT")) return "";
    const query = new URLSearchParams({ race_type: race });
    LAYOUT_FIELDS.forEach((name) => {
      const input = form.querySelector(`[name=${name}]`);
      if (input && input.value !== "") query.set(name, input.value);
    });
    return `/tracks/${encodeURIComponent(track)}/race.png?${query}`;
  }
  function showLayout() {
    const url = layoutSource();
    layout.hidden = !url;
    if (!url || url === layoutUrl) return;
    layoutUrl = url;
    layoutImg.hidden = false;
    layoutNote.textContent = "Where an episode starts the objects on the chosen track.";
    layoutImg.src = url;
  }
  layoutImg.addEventListener("error", () => {
    const url = layoutUrl;
    layoutImg.hidden = true;
    fetch(url).then((r) => r.text()).then((text) => {
      if (url === layoutUrl) layoutNote.textContent = `No preview: ${text.slice(0, 300)}`;
    }).catch(() => {
      if (url === layoutUrl) layoutNote.textContent = "No preview: the console did not answer.";
    });
  });
  const laterLayout = () => {
    clearTimeout(layoutTimer);
    layoutTimer = setTimeout(showLayout, 300);
  };
  form.addEventListener("change", laterLayout);
  form.addEventListener("input", laterLayout);
  showLayout();

  // The generator posts the form back; land on the action space again.
  // A refused form lands on its first error (the reward editor scrolls itself into view).
  const firstError = form.querySelector(".has-error, .form-error");
  if (form.dataset.jump) document.getElementById(form.dataset.jump).scrollIntoView();
  else if (firstError) firstError.scrollIntoView({ block: "center" });
  form.addEventListener("submit", () => {
    // Disabled inputs are not sent: enable SAC for the post so that a choice is never lost.
    form.querySelectorAll("[name=algorithm]").forEach((i) => (i.disabled = false));
  });
})();
