// The model page's readiness check, while it is queued or running: asks the server how far
// it got every few seconds (GET <section data-progress-url>, the owner's JSON) and moves the
// status badge, the "n of m conditions driven" line and the bar; when the check has ended
// the page reloads once, to show the table, the verdict and the videos. Without this script
// the page says to reload it.
"use strict";
(function () {
  const section = document.querySelector("#readiness[data-progress-url]");
  if (!section) return;
  const POLL_MS = 3000;
  const status = document.getElementById("readiness-status");
  const progress = document.getElementById("readiness-progress");
  const ahead = document.getElementById("readiness-ahead");
  const bar = document.getElementById("readiness-bar");
  const note = document.getElementById("readiness-live-note");
  if (note) note.textContent = "This updates by itself every few seconds.";
  const show = (data) => {
    if (status) {
      status.textContent = data.status_display;
      status.className = `status status-${data.badge}`;
    }
    if (progress) progress.textContent = `${data.cells_done} of ${data.cells_total} conditions driven`;
    if (bar) bar.style.width = `${data.percent}%`;
    if (ahead) {
      ahead.hidden = data.ahead === null;
      if (data.ahead !== null) {
        ahead.textContent = data.ahead ? `${data.ahead} job${data.ahead === 1 ? "" : "s"} ahead` : "next to start";
      }
    }
  };
  let failures = 0;
  const poll = async () => {
    try {
      const answer = await fetch(section.dataset.progressUrl, {
        credentials: "same-origin", headers: { Accept: "application/json" },
      });
      if (!answer.ok) throw new Error(`HTTP ${answer.status}`);
      const data = await answer.json();
      failures = 0;
      show(data);
      if (!data.active) {
        window.location.reload();
        return;
      }
    } catch (exc) {
      failures += 1;
      if (note && failures >= 3) note.textContent = "Cannot reach the server: reload the page to see how far it got.";
    }
    window.setTimeout(poll, POLL_MS * Math.min(failures + 1, 5));
  };
  window.setTimeout(poll, POLL_MS);
})();
