// A track drawn to scale on a canvas (metres → pixels, y up), with heatmap cells and paths
// coloured by a value. window.TrackCanvas(canvas, outline) — outline from track_outline().
"use strict";
(function () {
  const ROAD = "#3a4150", BG = "#11151d", CENTRE = "#6b7488";
  const PALETTE = ["#4cc9f0", "#f72585", "#72e06a", "#ffd166", "#b5179e", "#ff9f1c", "#4361ee",
    "#06d6a0", "#ef476f", "#8d99ae", "#ffbe0b", "#3a86ff", "#8338ec", "#fb5607", "#80ed99"];

  // A cold-to-hot ramp: t in 0..1 → CSS colour.
  function ramp(t) {
    const x = Math.max(0, Math.min(1, t));
    const h = 240 - 240 * x;
    return `hsl(${h}, 90%, ${45 + 10 * x}%)`;
  }

  class TrackCanvas {
    constructor(canvas, outline) {
      this.canvas = canvas;
      this.outline = outline;
      const [x0, y0, x1, y1] = outline.bounds;
      const m = 0.4;
      this.box = [x0 - m, y0 - m, x1 + m, y1 + m];
      this.ctx = canvas.getContext("2d");
      const w = canvas.width, h = canvas.height;
      this.scale = Math.min(w / (this.box[2] - this.box[0]), h / (this.box[3] - this.box[1]));
    }

    px(x, y) {
      return [(x - this.box[0]) * this.scale, this.canvas.height - (y - this.box[1]) * this.scale];
    }

    poly(points, close) {
      const c = this.ctx;
      c.beginPath();
      points.forEach(([x, y], i) => { const [u, v] = this.px(x, y); i ? c.lineTo(u, v) : c.moveTo(u, v); });
      if (close) c.closePath();
    }

    drawTrack() {
      const c = this.ctx, o = this.outline;
      c.fillStyle = BG;
      c.fillRect(0, 0, this.canvas.width, this.canvas.height);
      c.fillStyle = ROAD;
      this.poly(o.outer, o.closed);
      if (o.closed) { c.fill(); c.fillStyle = BG; this.poly(o.inner, true); c.fill(); }
      else { c.strokeStyle = ROAD; c.lineWidth = 2; c.stroke(); }
      c.strokeStyle = CENTRE; c.setLineDash([4, 6]); c.lineWidth = 1;
      this.poly(o.centre, o.closed); c.stroke(); c.setLineDash([]);
    }

    // Heatmap cells: data from /data/heatmap.json. Returns a legend string.
    drawHeatmap(data) {
      const c = this.ctx, vals = data.values.filter((v) => v !== null);
      if (!vals.length) return "No steps logged yet.";
      const lo = Math.min(...vals), hi = Math.max(...vals), span = hi - lo || 1;
      const size = data.cell * this.scale + 0.5;
      data.values.forEach((v, i) => {
        if (v === null) return;
        const [u, w] = this.px(data.x0 + (i % data.nx) * data.cell, data.y0 + (Math.floor(i / data.nx) + 1) * data.cell);
        c.fillStyle = data.kind === "action" ? PALETTE[v % PALETTE.length] : ramp((v - lo) / span);
        c.globalAlpha = 0.85;
        c.fillRect(u, w, size, size);
      });
      c.globalAlpha = 1;
      if (data.kind === "action") {
        return "Most chosen action: " + (data.actions || []).map((a, i) => `■ ${i}: ${a}`).join("  ");
      }
      const unit = data.kind === "speed" ? " m/s" : "";
      return `${data.kind} per step: blue ${lo.toFixed(2)}${unit} → red ${hi.toFixed(2)}${unit} (${data.steps} steps)`;
    }

    // A path coloured by `values` over `range` ([min, max], default the values' own) or in
    // one colour; returns the range used.
    drawPath(xs, ys, values, colour, range) {
      const c = this.ctx;
      const vals = (values || []).filter((v) => v !== null);
      const [lo, hi] = range || (vals.length ? [Math.min(...vals), Math.max(...vals)] : [0, 1]);
      c.lineWidth = 3;
      for (let i = 1; i < xs.length; i++) {
        const v = values ? values[i] : null;
        c.strokeStyle = colour || (v === null ? "#888" : ramp((v - lo) / (hi - lo || 1)));
        c.beginPath();
        c.moveTo(...this.px(xs[i - 1], ys[i - 1]));
        c.lineTo(...this.px(xs[i], ys[i]));
        c.stroke();
      }
      return [lo, hi];
    }
  }

  window.TrackCanvas = TrackCanvas;
  window.TrackPalette = PALETTE;
})();
