// Track search and filters, as you type: the Tracks page's form (which also works without
// this script, sent as GET) and the model wizard's pickers. Each element with
// data-track-filter="<selector>" holds the controls (named <prefix>-q, -season, -direction,
// -source, -min_length, -max_length, -min_width, -max_width); the items under the selector
// carry data-track (name and id, lower case), data-season, data-direction, data-source,
// data-length and data-width (metres). A chosen radio or checkbox is never hidden.
"use strict";
(function () {
  const KEYS = ["q", "season", "direction", "source", "min_length", "max_length", "min_width", "max_width"];

  function controls(bar) {
    const found = {};
    bar.querySelectorAll("input, select").forEach((el) => {
      const key = (el.name || "").split("-").pop();
      if (KEYS.includes(key)) found[key] = el;
    });
    return found;
  }

  function number(el) {
    if (!el || el.value.trim() === "") return null;
    const value = Number(el.value);
    return Number.isFinite(value) ? value : null;
  }

  function matcher(found) {
    const words = found.q ? found.q.value.toLowerCase().split(/\s+/).filter(Boolean) : [];
    const pick = (key) => (found[key] ? found[key].value : "");
    const lo = { length: number(found.min_length), width: number(found.min_width) };
    const hi = { length: number(found.max_length), width: number(found.max_width) };
    return (item) => {
      const d = item.dataset;
      if (!words.every((w) => (d.track || "").includes(w))) return false;
      for (const key of ["season", "direction", "source"]) {
        if (pick(key) && d[key] !== pick(key)) return false;
      }
      for (const key of ["length", "width"]) {
        const value = Number(d[key]);
        if (lo[key] !== null && value < lo[key]) return false;
        if (hi[key] !== null && value > hi[key]) return false;
      }
      return true;
    };
  }

  function fillSeasons(select, items) {
    const seasons = new Set(items.map((item) => item.dataset.season).filter(Boolean));
    const known = [...seasons].filter((s) => s !== "other").sort().reverse();
    for (const season of known) select.add(new Option(season, season));
    if (seasons.has("other")) select.add(new Option("Other", "other"));
  }

  document.querySelectorAll("[data-track-filter]").forEach((bar) => {
    const lists = [...document.querySelectorAll(bar.dataset.trackFilter)];
    const items = lists.flatMap((list) => [...list.querySelectorAll("[data-track]")]);
    if (!items.length) return;
    const found = controls(bar);
    const count = bar.querySelector("[aria-live]");
    const season = bar.querySelector("select[data-fill-seasons]");
    if (season) fillSeasons(season, items);
    bar.hidden = false;

    function apply() {
      const matches = matcher(found);
      let shown = 0;
      // the gallery may be filtered by the server already: its count says of how many
      const total = Number(count && count.dataset.total) || lists[0].querySelectorAll("[data-track]").length;
      for (const item of items) {
        const chosen = item.querySelector("input:checked") !== null;
        const visible = chosen || matches(item);
        item.hidden = !visible;
        if (visible && lists[0].contains(item)) shown += 1;
      }
      if (count) count.textContent = shown === total ? "" : `Showing ${shown} of ${total} tracks.`;
    }

    bar.addEventListener("input", apply);
    bar.addEventListener("change", apply);
    // Enter in the search box filters; it never sends the wizard's form.
    bar.addEventListener("keydown", (event) => {
      if (event.key === "Enter" && event.target.matches("input") && !bar.matches("form")) {
        event.preventDefault();
      }
    });
    apply();
  });
})();
