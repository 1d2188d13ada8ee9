// A model page's live parts: websockets to the training and evaluation jobs, the chart,
// the video frames (latest only: stale frames are dropped), timers and lap progress.
"use strict";
(function () {
  const config = JSON.parse(document.getElementById("live-config").textContent);
  const canvas = document.getElementById("reward-chart");
  const chart = canvas ? new window.RewardChart(canvas, JSON.parse(document.getElementById("chart-points").textContent)) : null;
  const FINISHED = ["COMPLETED", "FAILED", "CANCELED"];
  const LABELS = { QUEUED: "Queued", INITIALIZING: "Initializing", IN_PROGRESS: "In progress", STOPPING: "Stopping", COMPLETED: "Completed", FAILED: "Failed", CANCELED: "Canceled" };
  const BADGES = { COMPLETED: "ok", IN_PROGRESS: "busy", INITIALIZING: "busy", QUEUED: "wait", STOPPING: "wait", FAILED: "bad", CANCELED: "off" };

  function setStatus(el, status) {
    if (!el) return;
    el.textContent = LABELS[status] || status;
    el.className = `status status-${BADGES[status] || "off"}`;
  }

  function duration(s) {
    s = Math.max(0, Math.floor(s));
    const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
    const pad = (n) => String(n).padStart(2, "0");
    return h ? `${h}:${pad(m)}:${pad(sec)}` : `${m}:${pad(sec)}`;
  }

  function openSocket(path, handlers, isActive) {
    let delay = 1000;
    const connect = () => {
      const scheme = location.protocol === "https:" ? "wss" : "ws";
      const socket = new WebSocket(`${scheme}://${location.host}${path}`);
      socket.onmessage = (event) => {
        const message = JSON.parse(event.data);
        (handlers[message.type] || (() => {}))(message);
      };
      socket.onopen = () => (delay = 1000);
      socket.onclose = (event) => {
        if (event.code === 4404 || !isActive()) return;
        setTimeout(connect, delay);
        delay = Math.min(delay * 2, 15000);
      };
    };
    connect();
  }

  // ---- training
  // "live · evaluation lap 2 · iteration 7 · policy v6": what the streamed workers say the
  // frame shows (older workers send only the pictures).
  const frameCaption = (frame) => {
    const parts = ["live"];
    if (frame.phase === "evaluation") parts.push(frame.lap ? `evaluation lap ${frame.lap}` : "evaluation lap");
    else if (frame.phase === "training") parts.push("training episode");
    if (frame.iteration !== undefined) parts.push(`iteration ${frame.iteration}`);
    if (frame.version !== undefined) parts.push(`policy v${frame.version}`);
    return parts.join(" · ");
  };

  const training = config.training;
  if (training) {
    const elapsedEl = document.getElementById("elapsed");
    const remainingEl = document.getElementById("remaining");
    const timeBar = document.getElementById("time-bar");
    const videoCard = document.getElementById("training-video");
    const videoState = document.getElementById("video-state");
    const camera = document.getElementById("frame-camera");
    const chase = document.getElementById("frame-chase");
    let clock = { elapsed: training.elapsed, at: performance.now(), running: training.status === "IN_PROGRESS" || training.status === "INITIALIZING" || training.status === "STOPPING" };
    let latestFrame = null;
    let drawing = false;

    const tick = () => {
      const elapsed = clock.elapsed + (clock.running ? (performance.now() - clock.at) / 1000 : 0);
      const total = training.max_minutes * 60;
      elapsedEl.textContent = duration(elapsed);
      if (training.active) remainingEl.textContent = duration(total - elapsed);
      timeBar.style.width = `${Math.min(100, (elapsed / total) * 100)}%`;
    };
    tick();
    setInterval(tick, 1000);

    const drawFrame = () => {
      drawing = false;
      if (!latestFrame) return;
      const frame = latestFrame;
      latestFrame = null;
      if (frame.camera) camera.src = `data:image/jpeg;base64,${frame.camera}`;
      if (frame.chase) chase.src = `data:image/jpeg;base64,${frame.chase}`;
      videoCard.dataset.frames = Number(videoCard.dataset.frames) + 1;
      videoState.textContent = frameCaption(frame);
      videoCard.classList.add("live");
    };

    // "Stop when ready": evaluations in a row at 100 % (every lap complete), as the loop counts.
    const streakCell = document.getElementById("ready-streak");
    const counted = new Set();
    const countStreak = (p) => {
      if (!streakCell || !p || counted.has(p.iteration)) return;
      if (counted.size === 0) streakCell.dataset.streak = "0";  // the snapshot recounts from its first point
      counted.add(p.iteration);
      const streak = p.eval_progress >= 100 ? Number(streakCell.dataset.streak) + 1 : 0;
      streakCell.dataset.streak = String(streak);
      streakCell.textContent = `${streak} of ${streakCell.dataset.needed}`;
    };

    if (training.active) {
      openSocket(`/ws/training/${training.id}/`, {
        snapshot: (m) => {
          (m.points || []).forEach((p) => chart && chart.add(p));
          (m.points || []).forEach(countStreak);
          document.getElementById("iterations").textContent = chart ? chart.points.length : 0;
          clock = { elapsed: m.elapsed_s, at: performance.now(), running: !FINISHED.includes(m.status) && m.status !== "QUEUED" };
          setStatus(document.getElementById("job-status"), m.status);
          if (FINISHED.includes(m.status) && training.active) location.reload();
        },
        metrics: (m) => {
          if (chart) chart.add(m.point);
          countStreak(m.point);
          document.getElementById("iterations").textContent = chart ? chart.points.length : 0;
        },
        frame: (m) => {
          // Keep only the newest frame; the browser paints at most once per animation frame.
          latestFrame = m;
          if (!drawing) {
            drawing = true;
            requestAnimationFrame(drawFrame);
          }
        },
        status: (m) => {
          setStatus(document.getElementById("job-status"), m.status);
          if (m.status === "IN_PROGRESS" && !clock.running) clock = { elapsed: 0, at: performance.now(), running: true };
          if (FINISHED.includes(m.status)) {
            training.active = false;
            setTimeout(() => location.reload(), 800);
          }
        },
      }, () => training.active);
    }
  }

  // ---- evaluation
  const evaluation = config.evaluation;
  if (evaluation && evaluation.active) {
    const progress = document.getElementById("laps-progress");
    const bar = document.getElementById("laps-bar");
    const showLaps = (done) => {
      progress.textContent = `${done} of ${evaluation.laps} laps completed`;
      if (bar) bar.style.width = `${(100 * done) / evaluation.laps}%`;
    };
    const evalCard = document.getElementById("evaluation-live");
    let evalFrame = null;
    let evalDrawing = false;
    const drawEvalFrame = () => {
      evalDrawing = false;
      if (!evalFrame || !evalCard) return;
      const frame = evalFrame;
      evalFrame = null;
      if (frame.chase) document.getElementById("eval-frame-chase").src = `data:image/jpeg;base64,${frame.chase}`;
      if (frame.camera) document.getElementById("eval-frame-camera").src = `data:image/jpeg;base64,${frame.camera}`;
      evalCard.dataset.frames = Number(evalCard.dataset.frames) + 1;
      document.getElementById("eval-video-state").textContent = "live";
    };
    openSocket(`/ws/evaluation/${evaluation.id}/`, {
      snapshot: (m) => {
        setStatus(document.getElementById("evaluation-status"), m.status);
        showLaps(m.laps_done);
        if (FINISHED.includes(m.status)) location.reload();
      },
      progress: (m) => showLaps(m.laps_done),
      frame: (m) => {
        // The newest frame wins; stale ones are dropped (at most one paint per animation frame).
        evalFrame = m;
        if (!evalDrawing) {
          evalDrawing = true;
          requestAnimationFrame(drawEvalFrame);
        }
      },
      status: (m) => {
        setStatus(document.getElementById("evaluation-status"), m.status);
        if (FINISHED.includes(m.status)) {
          evaluation.active = false;
          setTimeout(() => location.reload(), 500);
        }
      },
    }, () => evaluation.active);
  }
})();
