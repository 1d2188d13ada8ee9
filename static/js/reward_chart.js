// DeepRacer's reward graph on the model page, drawn with Chart.js (window.RacecraftCharts):
// x = iteration; left axis average reward (training); right axis 0-100 % completion
// (training and evaluation); the best model marked.
"use strict";
(function () {
  const COLORS = { reward: "#ff9f1c", train: "#4cc9f0", eval: "#72e06a", best: "#ffd166", grid: "#2a3242", text: "#98a2b3" };

  class RewardChart {
    constructor(canvas, points) {
      this.canvas = canvas;
      this.points = [];
      this.chart = null;
      if (!window.RacecraftCharts) {
        // The bundle is built with npm (manage.py build_assets); the page works without it.
        canvas.insertAdjacentText("afterend", "The chart needs the charts bundle: run manage.py build_assets.");
        (points || []).forEach((p) => this.add(p, false));
        return;
      }
      const Chart = window.RacecraftCharts.Chart;
      const series = (label, color, axis, extra) => ({ label, data: [], borderColor: color, backgroundColor: color, yAxisID: axis, pointRadius: 2, ...extra });
      this.chart = new Chart(canvas, {
        type: "line",
        data: {
          labels: [],
          datasets: [
            series("Average reward (training)", COLORS.reward, "reward"),
            series("Average completion % (training)", COLORS.train, "pct"),
            series("Average completion % (evaluation)", COLORS.eval, "pct"),
            series("Best model", COLORS.best, "pct", { showLine: false, pointRadius: 6, pointStyle: "star" }),
          ],
        },
        options: {
          animation: false, aspectRatio: 2,
          plugins: { legend: { display: false } },
          scales: {
            x: { title: { display: true, text: "Iteration", color: COLORS.text }, ticks: { color: COLORS.text }, grid: { color: COLORS.grid } },
            reward: { position: "left", ticks: { color: COLORS.reward }, grid: { color: COLORS.grid } },
            pct: { position: "right", min: 0, max: 100, ticks: { color: COLORS.text }, grid: { display: false } },
          },
        },
      });
      (points || []).forEach((p) => this.add(p, false));
      this.draw();
    }

    add(point, redraw = true) {
      if (!point || typeof point.iteration !== "number") return;
      const i = this.points.findIndex((p) => p.iteration === point.iteration);
      if (i >= 0) this.points[i] = point;
      else this.points.push(point);
      this.points.sort((a, b) => a.iteration - b.iteration);
      this.canvas.dataset.points = this.points.length;
      if (redraw) this.draw();
    }

    draw() {
      if (!this.chart) return;
      const pts = this.points, sets = this.chart.data.datasets;
      this.chart.data.labels = pts.map((p) => p.iteration);
      sets[0].data = pts.map((p) => p.train_reward);
      sets[1].data = pts.map((p) => p.train_progress);
      sets[2].data = pts.map((p) => p.eval_progress);
      sets[3].data = pts.map((p) => (p.is_best ? p.eval_progress : null));
      this.chart.update("none");
    }
  }

  window.RewardChart = RewardChart;
})();
