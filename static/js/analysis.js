// The analysis page: fetches each chart's data (the server aggregates) and draws it with
// Chart.js (window.RacecraftCharts) and TrackCanvas; reward replays go to a Celery task.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const config = JSON.parse($("analysis-config").textContent);
  const outline = JSON.parse($("track-outline").textContent);
  const Chart = window.RacecraftCharts.Chart;
  const TEXT = "#98a2b3", GRID = "#2a3242";
  Chart.defaults.color = TEXT;
  Chart.defaults.borderColor = GRID;
  const charts = {};
  const state = { kind: "reward", episode: null, best: [], heatmap: null, episodes: null };

  async function getJSON(url) {
    const response = await fetch(url, { credentials: "same-origin" });
    const body = await response.json();
    if (!response.ok) throw new Error(body.error || response.statusText);
    return body;
  }

  function fail(err) {
    const box = $("analysis-error");
    box.textContent = String(err.message || err);
    box.hidden = false;
  }

  function chart(id, type, data, options) {
    if (charts[id]) { charts[id].data = data; charts[id].update("none"); return; }
    charts[id] = new Chart($(id), { type, data, options: { animation: false, aspectRatio: 2, ...options } });
  }

  const line = (label, data, colour, extra) => ({ label, data, borderColor: colour, backgroundColor: colour, pointRadius: 0, spanGaps: true, ...extra });

  async function loadProgress() {
    const d = await getJSON("data/progress.json");
    chart("progress-chart", "line", {
      labels: d.iteration,
      datasets: [
        line("Mean reward", d.reward, "#ff9f1c", { yAxisID: "reward" }),
        line("Progress % (training)", d.progress, "#4cc9f0", { yAxisID: "pct" }),
        line("Completion rate %", d.completion_rate, "#b5179e", { yAxisID: "pct" }),
        line("Progress % (evaluation)", d.eval_progress, "#72e06a", { yAxisID: "pct", pointRadius: 3, showLine: false }),
      ],
    }, { scales: { reward: { position: "left" }, pct: { position: "right", min: 0, max: 100 } } });
    const upper = d.lap_time.map((m, i) => (m === null || d.lap_time_std[i] === null ? m : m + d.lap_time_std[i]));
    const lower = d.lap_time.map((m, i) => (m === null || d.lap_time_std[i] === null ? m : m - d.lap_time_std[i]));
    chart("laptime-chart", "line", {
      labels: d.iteration,
      datasets: [
        line("+1 sd", upper, "rgba(76,201,240,0.25)", { fill: "+1" }),
        line("Mean lap time (s)", d.lap_time, "#4cc9f0", { pointRadius: 2 }),
        line("-1 sd", lower, "rgba(76,201,240,0.25)", { fill: "-1" }),
      ],
    }, {});
  }

  async function loadHeatmap() {
    const data = await getJSON(`data/heatmap.json?kind=${state.kind}`);
    if (data.kind !== state.kind) return; // a newer choice is on its way
    state.heatmap = data;
    $("heatmap-csv").href = `data/heatmap.csv?kind=${state.kind}`;
    drawTrack();
  }

  function drawTrack() {
    const canvas = $("track-canvas");
    const t = new window.TrackCanvas(canvas, outline);
    t.drawTrack();
    $("track-legend").textContent = state.heatmap ? t.drawHeatmap(state.heatmap) : "";
    if ($("show-best").checked) state.best.forEach((p, i) => t.drawPath(p.x, p.y, null, window.TrackPalette[i]));
    if (state.episode && state.episode.path) {
      const [lo, hi] = t.drawPath(state.episode.path.x, state.episode.path.y, state.episode.path.speed);
      $("track-legend").textContent += ` · episode ${state.episode.episode} (iteration ${state.episode.iteration}) by speed ${lo.toFixed(1)}–${hi.toFixed(1)} m/s`;
    }
    canvas.dataset.kind = state.heatmap ? state.heatmap.kind : "";
    canvas.dataset.episode = state.episode ? `${state.episode.iteration}/${state.episode.episode}` : "";
  }

  const episodeUrl = (it, ep) => config.episode.replace(/\/0\/0\/$/, `/${it}/${ep}/`);

  function row(cells, onClick) {
    const tr = document.createElement("tr");
    cells.forEach((c) => { const td = document.createElement("td"); td.textContent = c === null ? "—" : c; tr.appendChild(td); });
    tr.tabIndex = 0;
    tr.className = "pickable";
    tr.addEventListener("click", onClick);
    return tr;
  }

  async function pick(iteration, episode) {
    const path = await getJSON(episodeUrl(iteration, episode));
    state.episode = { iteration, episode, path };
    $("replay-target").textContent = `episode ${episode} of iteration ${iteration}`;
    $("replay-run").disabled = false;
    drawTrack();
  }

  async function loadLaps() {
    const f = await getJSON("data/fastest.json");
    const body = $("fastest-table").tBodies[0];
    body.replaceChildren(...f.episode.map((ep, i) => row(
      [f.iteration[i], ep, f.time_s[i], f.steps[i], f.reward[i], f.speed[i]], () => pick(f.iteration[i], ep))));
    state.best = await Promise.all(f.episode.slice(0, 3).map((ep, i) => getJSON(episodeUrl(f.iteration[i], ep))));
    drawTrack();
  }

  async function loadEpisodes() {
    state.episodes = await getJSON("data/episodes.json");
    const select = $("episode-iteration");
    const its = [...new Set(state.episodes.iteration)];
    const keep = select.value;
    select.replaceChildren(...its.map((it) => new Option(String(it), String(it))));
    select.value = its.includes(Number(keep)) ? keep : String(its[its.length - 1] ?? "");
    showEpisodes();
  }

  function showEpisodes() {
    const e = state.episodes, it = Number($("episode-iteration").value);
    const rows = [];
    e.episode.forEach((ep, i) => {
      if (e.iteration[i] === it) rows.push(row([it, ep, e.steps[i], e.time_s[i], e.progress[i], e.reward[i]], () => pick(it, ep)));
    });
    $("episode-table").tBodies[0].replaceChildren(...rows);
  }

  async function loadActions() {
    const a = await getJSON("data/actions.json");
    const names = a.actions.length ? a.actions : ["no actions: the action space could not be read"];
    $("actions-note").textContent = a.continuous
      ? "Continuous action space: each step counts in a bin of steering (5 bins) × speed (3 bins) over the space's ranges, by what the car executed; the action heatmap shows the most used bin."
      : "";
    const stacked = { scales: { x: { stacked: true }, y: { stacked: true, max: 100 } } };
    const sets = (rows) => names.map((n, k) => ({ label: `${k}: ${n}`, data: rows.map((r) => r[k] ?? 0), backgroundColor: window.TrackPalette[k % 15] }));
    chart("actions-chart", "bar", { labels: a.iterations, datasets: sets(a.per_iteration) }, stacked);
    chart("sections-chart", "bar", { labels: a.per_section.map((_, i) => `${i * 10}-${i * 10 + 10}%`), datasets: sets(a.per_section) }, stacked);
  }

  async function loadEvaluations() {
    const d = await getJSON("data/evaluations.json");
    const select = $("evaluation-pick");
    select.replaceChildren(...d.evaluations.map((e) => new Option(`evaluation #${e.id}`, String(e.id))));
    const draw = () => {
      const t = new window.TrackCanvas($("evaluation-canvas"), outline);
      t.drawTrack();
      const ev = d.evaluations.find((e) => String(e.id) === select.value);
      if (!ev) { $("evaluation-legend").textContent = "No evaluation yet."; return; }
      const speeds = ev.laps.flatMap((l) => l.speed);
      const range = [Math.min(...speeds), Math.max(...speeds)];
      ev.laps.forEach((l) => t.drawPath(l.x, l.y, l.speed, null, range));
      $("evaluation-legend").textContent = ev.laps.map((l) => `lap ${l.lap[0]}: ${l.time_s[0]} s`).join(" · ") + ` · speed ${range[0]}–${range[1]} m/s (blue → red)`;
    };
    select.onchange = draw;
    draw();
  }

  async function replay() {
    const button = $("replay-run");
    button.disabled = true;
    $("replay-state").textContent = "running in the sandbox…";
    try {
      const response = await fetch(config.replay, {
        method: "POST", credentials: "same-origin",
        headers: { "Content-Type": "application/json", "X-CSRFToken": document.querySelector("[name=csrfmiddlewaretoken]").value },
        body: JSON.stringify({ iteration: state.episode.iteration, episode: state.episode.episode, reward_function: $("replay-source").value }),
      });
      const started = await response.json();
      if (!response.ok) throw new Error(started.error);
      let result = { state: "PENDING" };
      while (result.state === "PENDING") {
        await new Promise((r) => setTimeout(r, 700));
        result = await getJSON(`${config.replay}${started.task}/`);
      }
      if (result.state !== "DONE" || result.error) throw new Error(result.error || "the replay failed");
      showReplay(result);
    } catch (err) {
      $("replay-state").textContent = String(err.message || err);
    } finally {
      button.disabled = false;
    }
  }

  function showReplay(r) {
    $("replay-state").textContent = r.errors.length ? `errors: ${r.errors.join("; ")}` : "done";
    $("replay-totals").textContent = `Total reward: recorded ${r.old_total}, new ${r.new_total} over ${r.steps.length} steps` + (r.failed_steps ? ` (${r.failed_steps} steps failed)` : "");
    $("replay-totals").dataset.newTotal = r.new_total;
    chart("replay-chart", "line", { labels: r.steps, datasets: [line("Recorded reward", r.old_reward, "#ff9f1c"), line("New reward", r.new_reward, "#72e06a")] }, {});
    const t = new window.TrackCanvas($("replay-canvas"), outline);
    t.drawTrack();
    t.drawPath(r.x, r.y, r.new_reward);
  }

  document.querySelectorAll("[data-png]").forEach((b) => b.addEventListener("click", () => {
    const a = document.createElement("a");
    a.href = $(b.dataset.png).toDataURL("image/png");
    a.download = `${b.dataset.png}.png`;
    a.click();
  }));
  $("heatmap-kind").addEventListener("change", (e) => { state.kind = e.target.value; loadHeatmap().catch(fail); });
  $("show-best").addEventListener("change", drawTrack);
  $("episode-iteration").addEventListener("change", showEpisodes);
  $("replay-run").addEventListener("click", replay);

  const refresh = () => Promise.all([loadProgress(), loadHeatmap(), loadLaps(), loadEpisodes(), loadActions()]).catch(fail);
  refresh().then(() => loadEvaluations().catch(fail));
  if (config.live) setInterval(refresh, 20000);
})();
