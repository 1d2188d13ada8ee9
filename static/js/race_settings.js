// The evaluation form shows the settings of the race type chosen: boxes for object avoidance,
// bot cars for head-to-bot, none for a time trial or the model's own race.
(() => {
  document.querySelectorAll("form").forEach((form) => {
    const select = form.querySelector("select[name=race_type]");
    const panels = form.querySelectorAll("[data-race]");
    if (!select || !panels.length) return;
    const sync = () => panels.forEach((p) => (p.hidden = p.dataset.race !== select.value));
    select.addEventListener("change", sync);
    sync();
  });
})();
