// The racer's live speed page: each button posts its value without reloading the page (the
// form works without this script too), then shows the speed the server set and moves the
// -0.1/+0.1 buttons' values on from it. A refusal (not your turn, a bad value) is shown as
// the server's sentence.
"use strict";
(function () {
  const form = document.querySelector("form[data-speed-form]");
  if (!form) return;
  const shown = document.querySelector("[data-testid=speed-value]");
  const error = document.querySelector("[data-testid=speed-error]");
  const driving = document.querySelector("[data-testid=speed-driving]");
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
  form.addEventListener("submit", async (event) => {
    const button = event.submitter;
    if (!button) return;
    event.preventDefault();
    const body = new FormData(form);
    body.set("speed", button.value);
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
      form.querySelectorAll("button").forEach((b) => { b.disabled = false; });
    }
  });
})();
