// A task a worker runs for this page (a model import, a car-model export): poll its status
// (data-background-poll) and say where it is; when it is done, open the imported model
// ("next") or offer the car archive ("download"), or show the error.
"use strict";
(function () {
  const root = document.querySelector("[data-background-poll]");
  if (!root) return;
  const progress = root.querySelector(".task-progress");
  const error = root.querySelector(".task-error");
  const done = root.querySelector(".task-done");
  const started = Date.now();
  const LIMIT_MS = 15 * 60 * 1000;

  function say(status) {
    const s = Math.floor((Date.now() - started) / 1000);
    progress.textContent = status === "running" ? `Working… ${s} s` : `Waiting for a free worker… ${s} s`;
  }

  function fail(message) {
    progress.hidden = true;
    error.textContent = message;
    error.hidden = false;
  }

  async function poll() {
    let data;
    try {
      const response = await fetch(root.dataset.backgroundPoll, { headers: { Accept: "application/json" } });
      data = await response.json();
      if (!response.ok) return fail(data.error || `The server answered ${response.status}.`);
    } catch (err) {
      return fail("Could not reach the server: " + err);
    }
    if (data.status !== "done") {
      say(data.status);
      if (Date.now() - started > LIMIT_MS) return fail("No answer in 15 minutes; try again later.");
      window.setTimeout(poll, 700);
      return;
    }
    if (!data.ok) return fail(data.error || "The task failed.");
    if (data.next) {
      window.location.assign(data.next);
      return;
    }
    progress.textContent = "Ready.";
    if (done) done.hidden = false;
  }
  say("queued");
  poll();
})();
