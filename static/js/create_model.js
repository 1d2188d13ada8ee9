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
