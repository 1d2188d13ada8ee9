// A small canvas chart of DeepRacer's reward graph: x = iteration; left axis average reward
// (training); right axis 0-100 % completion (training and evaluation); best model marked.
"use strict";
(function () {
  const COLORS = { reward: "#ff9f1c", train: "#4cc9f0", eval: "#72e06a", best: "#ffd166", grid: "#2a3242", text: "#98a2b3" };

  class RewardChart {
    constructor(canvas, points) {
      this.canvas = canvas;
      this.points = [];
      (points || []).forEach((p) => this.add(p, false));
      new ResizeObserver(() => this.draw()).observe(canvas);
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
      const canvas = this.canvas;
      const dpr = window.devicePixelRatio || 1;
      const width = canvas.clientWidth || 600;
      const height = canvas.clientHeight || 300;
      canvas.width = Math.round(width * dpr);
      canvas.height = Math.round(height * dpr);
      const ctx = canvas.getContext("2d");
      ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
      ctx.clearRect(0, 0, width, height);
      const pad = { left: 52, right: 44, top: 14, bottom: 34 };
      const w = width - pad.left - pad.right;
      const h = height - pad.top - pad.bottom;
      const pts = this.points;
      ctx.font = "12px system-ui, sans-serif";
      ctx.fillStyle = COLORS.text;
      if (!pts.length) {
        ctx.textAlign = "center";
        ctx.fillText("The graph grows after each training iteration.", width / 2, height / 2);
        return;
      }
      const maxIt = Math.max(2, pts[pts.length - 1].iteration);
      const minIt = Math.min(1, pts[0].iteration);
      let rMin = Math.min(0, ...pts.map((p) => p.train_reward));
      let rMax = Math.max(...pts.map((p) => p.train_reward));
      if (rMax - rMin < 1e-6) rMax = rMin + 1;
      rMax += (rMax - rMin) * 0.08;
      const x = (it) => pad.left + ((it - minIt) / (maxIt - minIt)) * w;
      const yR = (r) => pad.top + h - ((r - rMin) / (rMax - rMin)) * h;
      const yP = (p) => pad.top + h - (p / 100) * h;

      // grid and axes
      ctx.strokeStyle = COLORS.grid;
      ctx.lineWidth = 1;
      for (let k = 0; k <= 4; k++) {
        const y = pad.top + (h * k) / 4;
        ctx.beginPath();
        ctx.moveTo(pad.left, y);
        ctx.lineTo(pad.left + w, y);
        ctx.stroke();
        ctx.textAlign = "right";
        ctx.fillText(formatNumber(rMax - ((rMax - rMin) * k) / 4), pad.left - 6, y + 4);
        ctx.textAlign = "left";
        ctx.fillText(`${100 - 25 * k}%`, pad.left + w + 6, y + 4);
      }
      ctx.textAlign = "center";
      const step = Math.max(1, Math.ceil((maxIt - minIt) / 8));
      for (let it = minIt; it <= maxIt; it += step) ctx.fillText(String(it), x(it), pad.top + h + 16);
      ctx.fillText("Iteration", pad.left + w / 2, height - 4);

      // best model
      for (const p of pts.filter((q) => q.is_best)) {
        ctx.strokeStyle = COLORS.best;
        ctx.setLineDash([4, 4]);
        ctx.beginPath();
        ctx.moveTo(x(p.iteration), pad.top);
        ctx.lineTo(x(p.iteration), pad.top + h);
        ctx.stroke();
        ctx.setLineDash([]);
      }
      const best = pts.filter((q) => q.is_best).pop();

      this.line(ctx, pts, (p) => [x(p.iteration), yR(p.train_reward)], COLORS.reward);
      this.line(ctx, pts, (p) => [x(p.iteration), yP(p.train_progress)], COLORS.train);
      this.line(ctx, pts, (p) => [x(p.iteration), yP(p.eval_progress)], COLORS.eval);
      if (best) {
        const [bx, by] = [x(best.iteration), yP(best.eval_progress)];
        ctx.fillStyle = COLORS.best;
        star(ctx, bx, by, 7);
        ctx.fillStyle = COLORS.text;
        ctx.textAlign = bx > pad.left + w - 80 ? "right" : "left";
        ctx.fillText("Best model", bx + (ctx.textAlign === "left" ? 10 : -10), Math.max(pad.top + 10, by - 8));
      }
    }

    line(ctx, pts, xy, color) {
      ctx.strokeStyle = color;
      ctx.fillStyle = color;
      ctx.lineWidth = 2;
      ctx.beginPath();
      pts.forEach((p, i) => {
        const [px, py] = xy(p);
        if (i === 0) ctx.moveTo(px, py);
        else ctx.lineTo(px, py);
      });
      ctx.stroke();
      for (const p of pts) {
        const [px, py] = xy(p);
        ctx.beginPath();
        ctx.arc(px, py, 2.5, 0, Math.PI * 2);
        ctx.fill();
      }
    }
  }

  function star(ctx, cx, cy, r) {
    ctx.beginPath();
    for (let i = 0; i < 10; i++) {
      const radius = i % 2 ? r / 2.2 : r;
      const a = (Math.PI / 5) * i - Math.PI / 2;
      ctx.lineTo(cx + radius * Math.cos(a), cy + radius * Math.sin(a));
    }
    ctx.closePath();
    ctx.fill();
  }

  function formatNumber(v) {
    const a = Math.abs(v);
    if (a >= 1000) return v.toFixed(0);
    if (a >= 10) return v.toFixed(1);
    return v.toFixed(2);
  }

  window.RewardChart = RewardChart;
})();
