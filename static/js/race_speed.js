// The racer's live speed page: each button posts its value without reloading the page (the
// form works without this script too), then shows the speed the server set and moves the
// -0.1/+0.1 buttons' values on from it. A refusal (not your turn, a bad value) is shown as
// the server's sentence.
//
// Every few seconds the page also asks whose turn it is (GET <.sp-page data-turn-url>): a
// racer waiting for their turn gets the buttons as soon as their car is on track, a racer
// whose turn ended gets the sentence, and "On track now at ..." follows what the car drives
// at, all without a reload (without this script: the page's "Try again" link, a reload).
"use strict";
(function () {
  const box = document.querySelector(".sp-page[data-turn-url]");
  const form = document.querySelector("form[data-speed-form]");
  const shown = document.querySelector("[data-testid=speed-value]");
  const error = document.querySelector("[data-testid=speed-error]");
  const driving = document.querySelector("[data-testid=speed-driving]");
  const POLL_MS = 3000;
  let busy = false; // a POST in flight
  let version = 0; // POSTs answered: a poll that began before one does not overwrite it

  if (form) {
    const min = parseFloat(form.dataset.min);
    const max = parseFloat(form.dataset.max);
    const clamp = (value) => Math.min(max, Math.max(min, Math.round(value * 100) / 100));
    const show = (speed) => {
      form.dataset.speed = speed.toFixed(2);
      shown.textContent = speed.toFixed(2);
      form.querySelectorAll("button[data-nudge]").forEach((button) => {
        button.value = clamp(speed + parseFloat(button.dataset.nudge)).toFixed(2);
      });
    };
    form.showSpeed = show;
    form.addEventListener("submit", async (event) => {
      const button = event.submitter;
      if (!button) return;
      event.preventDefault();
      const body = new FormData(form);
      body.set("speed", button.value);
      busy = true;
      form.querySelectorAll("button").forEach((b) => { b.disabled = true; });
      try {
        const answer = await fetch(window.location.href, {
          method: "POST", body, credentials: "same-origin",
          headers: { Accept: "application/json", "X-CSRFToken": body.get("csrfmiddlewaretoken") },
        });
        const data = await answer.json();
        if (answer.ok) {
          error.hidden = true;
          show(data.speed);
          if (driving) driving.textContent = `Sent: your car drives at ${data.speed.toFixed(2)}× from its next steps.`;
        } else {
          error.textContent = data.error || "The speed could not be changed.";
          error.hidden = false;
        }
      } catch (exc) {
        error.textContent = "The speed could not be sent: check your connection and try again.";
        error.hidden = false;
      } finally {
        version += 1;
        busy = false;
        form.querySelectorAll("button").forEach((b) => { b.disabled = false; });
      }
    });
  }

  if (!box) return;
  const onTurn = (data) => {
    if (!form) { // the car is on track now: the page with the buttons
      window.location.reload();
      return false;
    }
    if (driving && data.driving !== null) {
      driving.dataset.driving = data.driving.toFixed(2);
      driving.textContent = `On track now at ${data.driving.toFixed(2)}×.`;
    }
    form.showSpeed(data.speed);
    return true;
  };
  const refused = (data) => {
    if (form) { // the turn is over: the page says so, without the buttons
      window.location.reload();
      return false;
    }
    if (error && data.error) {
      error.textContent = data.error;
      error.hidden = false;
    }
    return true;
  };
  let failures = 0;
  const poll = async () => {
    const before = version;
    let goOn = true;
    try {
      const answer = await fetch(box.dataset.turnUrl, {
        credentials: "same-origin", headers: { Accept: "application/json" },
      });
      if (answer.status !== 200 && answer.status !== 403) throw new Error(`HTTP ${answer.status}`);
      const data = await answer.json();
      failures = 0;
      if (!busy && before === version) goOn = data.turn ? onTurn(data) : refused(data);
    } catch (exc) {
      failures += 1;
    }
    if (goOn) window.setTimeout(poll, POLL_MS * Math.min(failures + 1, 5));
  };
  window.setTimeout(poll, POLL_MS);
})();
