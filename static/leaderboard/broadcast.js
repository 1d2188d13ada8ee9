// The broadcast stage (templates/leaderboard/_broadcast_stage.html) of two pages: the race-day
// broadcast (templates/leaderboard/broadcast.html, /ws/league/events/<id>/broadcast/[?watch=])
// and a racer's race watched live (templates/races/watch.html, /ws/races/<id>/). One
// websocket, its URL in the body's data-socket-url. Each frame is a binary message in the one frame
// format (racing/framecodec.py): a 4-byte big-endian length, that much JSON ({"timing", "shot",
// "layout", "title", "t"}), then the JPEG: the TV camera with the track map and each racer's
// camera drawn in. The tower, clock, lap, PiP names and winner are drawn here, in HTML, from
// the frame's timing (racing/timing.py). A "status" text message says a race went on track
// ("started") or ended ("over", with its winner; a race page's also its job "status" and
// "outcome"); the event's leaderboard is fetched again then. data-final: a page of one race,
// whose socket is not reopened once the race is over.
(function () {
  const body = document.querySelector("[data-broadcast]");
  if (!body) return;
  const MAX_HEADER = 64 * 1024;
  const socketUrl = body.dataset.socketUrl;
  const final = body.dataset.final !== undefined;
  const video = document.querySelector("[data-video]");
  const clock = document.querySelector("[data-clock]");
  const lap = document.querySelector("[data-lap]");
  const title = document.querySelector("[data-race-title]");
  const timing = document.querySelector("[data-timing] tbody");
  const overlay = document.querySelector("[data-winner]");
  const live = document.querySelector("[data-live-status]");
  const board = document.querySelector("[data-board]");
  const pipLabels = document.querySelector("[data-pip-labels]");
  const raceStatus = document.querySelector("[data-race-status]");
  const stopForm = document.querySelector("[data-stop-form]");
  let over = false;
  let layout = null;
  let lastTiming = null;
  let quiet = null;  // after a while without frames the page goes back to idle

  function raceClock(seconds) {
    if (seconds === null || seconds === undefined) return "–";
    const m = Math.floor(seconds / 60);
    const s = (seconds - m * 60).toFixed(1).padStart(4, "0");
    return `${m}:${s}`;
  }

  function el(tag, className, text) {
    const node = document.createElement(tag);
    if (className) node.className = className;
    if (text !== undefined) node.textContent = text;
    return node;
  }

  function speedBadge(car) {
    const m = car.speed_multiplier;
    if (typeof m !== "number" || Math.abs(m - 1) < 0.005) return null;
    return el("span", m < 1 ? "tv-badge slow" : "tv-badge", `${m.toFixed(2).replace(/0$/, "")}×`);
  }

  function gapText(car) {
    if (car.status === "finished") return raceClock(car.finish_s);
    if (car.status === "retired") return "OUT";
    if (car.position === 1) return "Leader";
    if (typeof car.gap_s === "number") return `+${car.gap_s.toFixed(1)}`;
    return "–";
  }

  function renderTiming(t) {
    clock.textContent = raceClock(t.clock_s);
    if (t.lap) lap.textContent = `${t.lap}/${t.laps}`;
    timing.replaceChildren(...t.cars.map((car) => {
      const tr = el("tr", car.status === "retired" ? "tv-out" : "");
      tr.dataset.car = car.index;
      tr.dataset.name = car.name;
      tr.appendChild(el("td", "bc-rank", String(car.position)));
      const name = el("td");
      const line = el("span", "tv-name");
      const swatch = el("span", "bc-swatch");
      swatch.style.background = car.colour;
      line.append(swatch, car.name);
      const badge = speedBadge(car);
      if (badge) line.appendChild(badge);
      if (car.penalty_s > 0) {  // penalties that cost time (0 s ones are only resets)
        const pen = el("span", "tv-badge pen", `${car.penalties} pen`);
        pen.title = `${car.penalty_s.toFixed(0)} s of penalties`;
        line.appendChild(pen);
      }
      name.appendChild(line);
      if (car.status === "retired") name.appendChild(el("span", "tv-sub", `out: ${car.reason}`));
      tr.appendChild(name);
      tr.appendChild(el("td", "", car.status === "finished" ? "FIN" : `${car.lap}/${t.laps}`));
      const gap = el("td", "tv-gap", gapText(car));
      if (typeof car.interval_s === "number" && car.position > 2) gap.title = `interval +${car.interval_s.toFixed(1)}`;
      tr.appendChild(gap);
      for (let i = 0; i < 3; i++) {
        const td = el("td");
        if (typeof car.sectors[i] === "number") {
          const s = el("span", `bc-s ${car.sector_colours[i] || "yellow"}`, car.sectors[i].toFixed(2));
          s.dataset.sector = i + 1;
          td.appendChild(s);
        }
        tr.appendChild(td);
      }
      tr.appendChild(el("td", "bc-num", raceClock(car.last_lap_s)));
      return tr;
    }));
    if (t.over && t.winner) showWinner({ over: true, winner: t.winner.name, winner_time_s: t.winner.time_s });
  }

  // The PiP names sit on top of each racer's camera in the video: where the frame's layout says
  // it lies, mapped through the video's object-fit: cover.
  function placePips(t) {
    if (!layout || !layout.pips) return;
    const box = video.getBoundingClientRect();
    const scale = Math.max(box.width / layout.width, box.height / layout.height);
    const dx = (box.width - layout.width * scale) / 2;
    const dy = (box.height - layout.height * scale) / 2;
    const cars = new Map(((t && t.cars) || []).map((c) => [c.index, c]));
    pipLabels.replaceChildren(...layout.pips.map((pip) => {
      const [x, y, w] = pip.rect;
      const car = cars.get(pip.car) || {};
      const label = el("div", "tv-pip-label", pip.name);
      label.dataset.pip = pip.car;
      label.style.left = `${dx + x * scale}px`;
      label.style.top = `${dy + y * scale - 2}px`;
      label.style.width = `${w * scale}px`;
      if (car.colour) label.style.setProperty("--pip", car.colour);
      const badge = speedBadge(car);
      if (badge) label.append(" ", badge);
      return label;
    }));
  }

  function paintBoard() {
    if (!board) return;
    board.querySelectorAll(".bc-dot[data-colour]").forEach((dot) => { dot.style.background = dot.dataset.colour; });
  }

  function refreshBoard() {
    if (!board) return;
    fetch(board.dataset.boardUrl, { credentials: "same-origin" })
      .then((r) => (r.ok ? r.text() : null))
      .then((html) => { if (html) { board.innerHTML = html; paintBoard(); } })
      .catch(() => {});
  }

  function showWinner(msg) {
    const kicker = document.querySelector("[data-winner-kicker]");
    if (kicker) kicker.textContent = msg.winner ? "Winner" : msg.outcome || "Race over";
    document.querySelector("[data-winner-name]").textContent = msg.winner || "No winner";
    document.querySelector("[data-winner-time]").textContent =
      typeof msg.winner_time_s === "number" ? raceClock(msg.winner_time_s) : "";
    overlay.hidden = false;
    body.dataset.state = "over";
    if (msg.over) over = true;
  }

  function showStatus(msg) {  // a race page's job status: its text, and no Stop once over
    if (!raceStatus || !msg.status) return;
    raceStatus.dataset.status = msg.status;
    raceStatus.textContent = msg.outcome || (msg.started ? "On track" : raceStatus.textContent);
    if (msg.over && stopForm) stopForm.remove();
  }

  function readFrame(buffer) {  // racing/framecodec.py's decode_frame, bounded the same way
    if (buffer.byteLength < 4) return null;
    const length = new DataView(buffer).getUint32(0);
    if (length > MAX_HEADER || 4 + length > buffer.byteLength) return null;
    try {
      const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length)));
      return header && typeof header === "object" ? { header, jpeg: new Uint8Array(buffer, 4 + length) } : null;
    } catch (e) {
      return null;
    }
  }

  let shown = null;  // the object URL on screen, released when the next frame replaces it
  function showFrame(buffer) {
    const frame = readFrame(buffer);
    if (!frame) return;
    const url = URL.createObjectURL(new Blob([frame.jpeg], { type: "image/jpeg" }));
    video.src = url;
    if (shown) URL.revokeObjectURL(shown);
    shown = url;
    const t = frame.header.timing;
    if (frame.header.layout) layout = frame.header.layout;
    if (typeof frame.header.title === "string" && frame.header.title) title.textContent = frame.header.title;
    if (t && Array.isArray(t.cars)) {
      lastTiming = t;
      if (!t.over) {
        overlay.hidden = true;
        body.dataset.state = "racing";
        if (raceStatus && !over) raceStatus.textContent = "On track";
      }
      renderTiming(t);
      placePips(t);
    }
    clearTimeout(quiet);
    quiet = setTimeout(() => { if (body.dataset.state === "racing") body.dataset.state = "idle"; }, 15000);
  }

  let delay = 1000;
  let pinger = null;
  function connect() {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const socket = new WebSocket(`${scheme}://${location.host}${socketUrl}`);
    socket.binaryType = "arraybuffer";
    socket.onopen = () => {
      delay = 1000;
      live.dataset.state = "live";
      live.textContent = "Live";
      pinger = setInterval(() => socket.send("{}"), 10000);  // keeps the worker sending frames
    };
    socket.onmessage = (e) => {
      if (typeof e.data !== "string") { showFrame(e.data); return; }
      const msg = JSON.parse(e.data);
      if (msg.type === "status") {
        if (msg.started) {
          overlay.hidden = true;
          if (msg.title) title.textContent = msg.title;
          body.dataset.state = "racing";
        }
        if (msg.over) { showWinner(msg); refreshBoard(); }
        showStatus(msg);
      }
    };
    socket.onclose = (e) => {
      if (pinger) clearInterval(pinger);
      live.dataset.state = "off";
      if (e.code === 4403 || e.code === 4404) {  // the link was turned off: no retry
        live.textContent = "Broadcast closed";
        return;
      }
      if (final && over) {  // one race's page: nothing more will come
        live.textContent = "Race over";
        return;
      }
      live.textContent = "Reconnecting…";
      setTimeout(connect, delay);
      delay = Math.min(delay * 2, 30000);
    };
  }
  window.addEventListener("resize", () => placePips(lastTiming));
  paintBoard();
  connect();
})();
