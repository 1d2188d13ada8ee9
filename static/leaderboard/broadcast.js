// The race-day broadcast page: one websocket (/ws/league/events/<id>/broadcast/[?watch=]).
// Each frame is a binary message (built once by the worker at 15 frames a second, paced at
// real time): a 4-byte big-endian length, that much JSON ({"timing": ..., "t": ...}), then the
// JPEG. A "status" text message says a race went on track or ended (with its winner), and the
// leaderboard beside the video is fetched again.
(function () {
  const body = document.querySelector("[data-broadcast]");
  if (!body) return;
  const eventId = body.dataset.eventId;
  const watch = body.dataset.watch;
  const video = document.querySelector("[data-video]");
  const clock = document.querySelector("[data-clock]");
  const lap = document.querySelector("[data-lap]");
  const title = document.querySelector("[data-race-title]");
  const timing = document.querySelector("[data-timing] tbody");
  const overlay = document.querySelector("[data-winner]");
  const live = document.querySelector("[data-live-status]");
  const board = document.querySelector("[data-board]");

  function raceClock(seconds) {
    if (seconds === null || seconds === undefined) return "–";
    const m = Math.floor(seconds / 60);
    const s = (seconds - m * 60).toFixed(1).padStart(4, "0");
    return `${m}:${s}`;
  }

  function cell(text, className) {
    const td = document.createElement("td");
    if (className) td.className = className;
    td.textContent = text;
    return td;
  }

  function renderTiming(t) {
    clock.textContent = raceClock(t.clock_s);
    const leader = t.cars[0];
    if (leader) lap.textContent = `${leader.lap}/${t.laps}`;
    timing.replaceChildren(...t.cars.map((car) => {
      const tr = document.createElement("tr");
      tr.dataset.car = car.index;
      tr.appendChild(cell(String(car.position), "bc-rank"));
      const name = cell("");
      const swatch = document.createElement("span");
      swatch.className = "bc-swatch";
      swatch.style.background = car.colour;
      name.append(swatch, car.name);
      if (car.state === "out") {
        const out = document.createElement("div");
        out.className = "bc-out";
        out.textContent = `out: ${car.reason}`;
        name.appendChild(out);
      }
      tr.appendChild(name);
      tr.appendChild(cell(car.state === "finished" ? "FIN" : `${car.lap}/${t.laps}`));
      for (let i = 0; i < 3; i++) {
        const td = document.createElement("td");
        if (car.sectors[i] !== undefined) {
          const s = document.createElement("span");
          s.className = `bc-s ${car.sector_colours[i] || "yellow"}`;
          s.dataset.sector = i + 1;
          s.textContent = car.sectors[i].toFixed(2);
          td.appendChild(s);
        }
        tr.appendChild(td);
      }
      tr.appendChild(cell(car.finish_s !== null ? raceClock(car.finish_s) : raceClock(car.last_lap_s), "bc-num"));
      return tr;
    }));
  }

  function refreshBoard() {
    fetch(board.dataset.boardUrl, { credentials: "same-origin" })
      .then((r) => (r.ok ? r.text() : null))
      .then((html) => { if (html) board.innerHTML = html; })
      .catch(() => {});
  }

  function showWinner(msg) {
    const name = document.querySelector("[data-winner-name]");
    const time = document.querySelector("[data-winner-time]");
    name.textContent = msg.winner || "No winner";
    time.textContent = typeof msg.winner_time_s === "number" ? raceClock(msg.winner_time_s) : "";
    overlay.hidden = false;
  }

  let shown = null;  // the object URL on screen, released when the next frame replaces it
  function showFrame(buffer) {
    const length = new DataView(buffer).getUint32(0);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length)));
    const url = URL.createObjectURL(new Blob([new Uint8Array(buffer, 4 + length)], { type: "image/jpeg" }));
    video.src = url;
    if (shown) URL.revokeObjectURL(shown);
    shown = url;
    renderTiming(header.timing);
    if (!header.timing.over) overlay.hidden = true;
  }

  let delay = 1000;
  let pinger = null;
  function connect() {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const query = watch ? `?watch=${encodeURIComponent(watch)}` : "";
    const socket = new WebSocket(`${scheme}://${location.host}/ws/league/events/${eventId}/broadcast/${query}`);
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
        if (msg.started) { overlay.hidden = true; title.textContent = msg.title || "On track"; }
        if (msg.over) { showWinner(msg); refreshBoard(); }
      }
    };
    socket.onclose = (e) => {
      if (pinger) clearInterval(pinger);
      live.dataset.state = "off";
      if (e.code === 4403 || e.code === 4404) {  // the link was turned off: no retry
        live.textContent = "Broadcast closed";
        return;
      }
      live.textContent = "Reconnecting…";
      setTimeout(connect, delay);
      delay = Math.min(delay * 2, 30000);
    };
  }
  connect();
})();
