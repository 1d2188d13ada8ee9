// The live leaderboard: one websocket per event page (/ws/league/events/<id>/). Every message
// carries the whole board; the submission that just finished is highlighted for a few seconds.
(function () {
  "use strict";
  const board = document.querySelector("[data-leaderboard]");
  if (!board) return;
  const eventId = board.dataset.eventId;
  const me = board.dataset.me || "";
  const tbody = board.querySelector("tbody");
  const table = board.querySelector("table");
  const empty = board.querySelector("[data-board-empty]");
  const live = document.querySelector("[data-live-status]");
  const withVideo = board.dataset.video !== "0";

  function td(text, cls) {
    const cell = document.createElement("td");
    if (cls) cell.className = cls;
    if (text !== undefined) cell.textContent = text;
    return cell;
  }

  function rowFor(r, highlight) {
    const tr = document.createElement("tr");
    tr.dataset.submissionId = r.submission_id;
    tr.dataset.racer = r.alias;
    if (String(r.racer_id) === me) tr.classList.add("lb-me");
    if (r.submission_id === highlight) tr.classList.add("lb-new");
    const rank = td();
    const badge = document.createElement("span");
    badge.className = "lb-rank" + (r.rank <= 3 ? " r" + r.rank : "");
    badge.textContent = r.rank;
    rank.appendChild(badge);
    const racer = td();
    const dot = document.createElement("span");
    dot.className = "lb-dot";
    dot.style.background = r.colour;
    const name = document.createElement("span");
    name.className = "lb-racer";
    name.textContent = r.alias;
    racer.append(dot, name);
    if (r.country) {
      const c = document.createElement("span");
      c.className = "lb-country";
      c.textContent = r.country;
      racer.appendChild(c);
    }
    tr.append(rank, racer, td(r.time, "time num"), td(r.gap, "gap num"),
      td(String(r.off_tracks), "num hide-sm"), td(String(r.collisions), "num hide-sm"));
    if (withVideo) {
      const video = td(undefined, "lb-video");
      const a = document.createElement("a");
      a.href = r.video_url || r.detail_url;
      a.textContent = r.video_url ? "Watch" : "Laps";
      video.appendChild(a);
      tr.appendChild(video);
    }
    return tr;
  }

  function render(rows, highlight) {
    tbody.replaceChildren(...rows.map((r) => rowFor(r, highlight)));
    table.hidden = rows.length === 0;
    if (empty) empty.hidden = rows.length > 0;
    if (highlight) {
      const fresh = tbody.querySelector(".lb-new");
      if (fresh) setTimeout(() => fresh.classList.remove("lb-new"), 6000);
    }
  }

  function updateMine(sub) {
    const row = document.querySelector(`[data-my-submission="${sub.id}"]`);
    if (!row) return;
    const status = row.querySelector("[data-status]");
    status.textContent = sub.status_label;
    status.className = "lb-status lb-status-" + sub.status.toLowerCase();
    row.querySelector("[data-time]").textContent = sub.time;
    const reason = row.querySelector("[data-reason]");
    if (reason) reason.textContent = sub.reason || "";
  }

  let delay = 1000;
  function connect() {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const socket = new WebSocket(`${scheme}://${location.host}/ws/league/events/${eventId}/`);
    socket.onopen = () => { delay = 1000; if (live) { live.dataset.state = "live"; live.textContent = "Live"; } };
    socket.onmessage = (e) => {
      const msg = JSON.parse(e.data);
      if (msg.type === "snapshot") render(msg.rows, null);
      if (msg.type === "result") {
        const sub = msg.submission;  // null: someone else's result that is not ranked
        render(msg.rows, sub && sub.status === "RANKED" ? sub.id : null);
        if (sub) updateMine(sub);
      }
    };
    socket.onclose = () => {
      if (live) { live.dataset.state = "off"; live.textContent = "Reconnecting…"; }
      setTimeout(connect, delay);
      delay = Math.min(delay * 2, 30000);
    };
  }
  connect();
})();

// The bracket page: the same event websocket says when a race of the bracket started or ended;
// the page fetches its rounds again.
(function () {
  "use strict";
  const bracket = document.querySelector("[data-bracket]");
  if (!bracket) return;
  const live = document.querySelector("[data-live-status]");
  let delay = 1000;
  function refresh() {
    fetch(bracket.dataset.fragmentUrl, { credentials: "same-origin" })
      .then((r) => (r.ok ? r.text() : null))
      .then((html) => { if (html !== null) bracket.innerHTML = html; })
      .catch(() => {});
  }
  function connect() {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const socket = new WebSocket(`${scheme}://${location.host}/ws/league/events/${bracket.dataset.eventId}/`);
    socket.onopen = () => { delay = 1000; if (live) { live.dataset.state = "live"; live.textContent = "Live"; } };
    socket.onmessage = (e) => { if (JSON.parse(e.data).type === "bracket") refresh(); };
    socket.onclose = () => {
      if (live) { live.dataset.state = "off"; live.textContent = "Reconnecting…"; }
      setTimeout(connect, delay);
      delay = Math.min(delay * 2, 30000);
    };
  }
  connect();
})();

// Small behaviours without inline handlers (the Content Security Policy allows no inline code).
document.addEventListener("submit", (event) => {
  const question = event.target.dataset && event.target.dataset.confirm;
  if (question && !window.confirm(question)) event.preventDefault();
});
document.addEventListener("click", (event) => {
  const target = event.target;
  if (target.matches && target.matches("[data-select-on-click]")) target.select();
  const from = target.dataset && target.dataset.copyFrom;
  if (from && navigator.clipboard) {
    navigator.clipboard.writeText(document.getElementById(from).value);
  }
});
