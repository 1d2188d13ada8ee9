// A form that takes a while on the server (create: saving the model files; import: the
// checkpoint is read and checked) says so while the browser waits: the submit button turns
// into "<data-busy> 12 s", once per page, so the user neither waits blind nor submits twice.
"use strict";
(function () {
  document.querySelectorAll("form[data-busy]").forEach((form) => {
    form.addEventListener("submit", (event) => {
      const button = event.submitter || form.querySelector("button[type=submit], button:not([type])");
      if (!button || form.dataset.sent) return;
      form.dataset.sent = "1";
      const label = button.dataset.busy || form.dataset.busy;
      const started = Date.now();
      const tick = () => {
        button.textContent = `${label} ${Math.floor((Date.now() - started) / 1000)} s`;
      };
      // Disable after the browser has read the button's name/value for the post.
      window.setTimeout(() => {
        button.disabled = true;
        tick();
        window.setInterval(tick, 1000);
      }, 0);
    });
  });
})();
