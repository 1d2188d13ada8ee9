// The reward-function editor: CodeMirror (static/vendor/codemirror.bundle.js, global
// RacecraftEditor) over the form's textarea, the examples, the Validate button, and saving
// after a validation: when the server answers a save with data-pending-poll (the function is
// being validated on a worker), poll it, then post the form again once it passes (the server
// saves at once then) or mark the errors on their lines.
"use strict";
(function () {
  const root = document.querySelector(".reward-editor");
  if (!root) return;
  const textarea = root.querySelector("textarea");
  const mountPoint = root.querySelector("#reward-editor");
  const result = root.querySelector("#reward-result");
  const examples = JSON.parse(document.getElementById("reward-examples").textContent);
  const initialErrors = JSON.parse(document.getElementById("reward-errors").textContent);
  let view = null;

  if (window.RacecraftEditor) {
    view = window.RacecraftEditor.mount(mountPoint, textarea);
    textarea.hidden = true;
    root.classList.add("enhanced");
  }
  const getText = () => (view ? view.state.doc.toString() : textarea.value);
  const setText = (text) => {
    if (view) window.RacecraftEditor.setText(view, text);
    textarea.value = text;
  };

  function showErrors(errors) {
    result.replaceChildren();
    if (view) window.RacecraftEditor.markErrors(view, errors);
    if (!errors.length) return;
    const list = document.createElement("ul");
    list.className = "error-list";
    for (const e of errors) {
      const item = document.createElement("li");
      const tag = document.createElement("span");
      tag.className = "tag";
      tag.textContent = e.type || "ERROR";
      item.append(tag, (e.lineNumber ? ` Line ${e.lineNumber}: ` : " ") + e.message);
      if (e.lineNumber) item.dataset.line = e.lineNumber;
      list.append(item);
    }
    result.append(list);
  }

  function showOk(rewards) {
    result.replaceChildren();
    if (view) window.RacecraftEditor.clearErrors(view);
    const ok = document.createElement("p");
    ok.className = "ok-message";
    const runs = Object.keys(rewards || {}).length;
    ok.textContent = `Valid: the function ran on ${runs} test situations of the chosen track.`;
    result.append(ok);
  }

  if (initialErrors.length) {
    // The server refused the reward function: take the user to it, at the first marked line.
    showErrors(initialErrors);
    root.scrollIntoView({ block: "start" });
  }

  // Polls a validation until it is done (``limitMs`` at most); ``onStatus`` sees each answer.
  async function pollUntilDone(data, poll, limitMs, onStatus) {
    const stop = Date.now() + limitMs;
    while (data.status === "queued" || data.status === "running") {
      onStatus(data);
      if (Date.now() > stop) throw new Error(`no answer in ${Math.round(limitMs / 60000)} minutes`);
      await new Promise((done) => setTimeout(done, 500));
      data = await (await fetch(poll)).json();
    }
    return data;
  }

  const pending = root.dataset.pendingPoll;
  if (pending) {
    const note = root.querySelector("#pending-validation");
    const form = root.closest("form");
    const submit = form.querySelector("button[type=submit].primary");  // the save button, not "generate"
    const started = Date.now();
    if (submit) submit.disabled = true;
    const say = (state) => {
      const s = Math.floor((Date.now() - started) / 1000);
      const what = state === "running" ? "Running your function in the sandbox" : "Waiting for a free worker";
      note.textContent = `Validating before saving: ${what}… ${s} s. Nothing is saved until it passes.`;
    };
    say("queued");
    root.scrollIntoView({ block: "start" });
    pollUntilDone({ status: "queued" }, pending, 600000, (data) => say(data.status))
      .then((data) => {
        if (data.ok) {
          note.textContent = "Valid: saving…";
          delete form.dataset.sent;
          if (submit) submit.disabled = false;
          form.requestSubmit(submit || undefined);
          return;
        }
        note.remove();
        showErrors(data.errors || []);
        if (submit) submit.disabled = false;
      })
      .catch((err) => {
        note.remove();
        showErrors([{ type: "NETWORK_ERROR", message: "The validation did not finish: " + err + ". Save again to retry." }]);
        if (submit) submit.disabled = false;
      });
  }

  const useExample = root.querySelector("#use-example");
  if (useExample) {
    useExample.addEventListener("click", () => {
      const id = root.querySelector("#example-select").value;
      if (getText().trim() && !window.confirm("Replace your reward function with this example?")) return;
      setText(examples[id]);
      showErrors([]);
    });
  }

  const validate = root.querySelector("#validate-reward");
  if (validate) {
    validate.addEventListener("click", async () => {
      const form = root.closest("form");
      const track = form.querySelector("[name=track_id]:checked, select[name=track_id], input[type=hidden][name=track_id]");
      const direction = form.querySelector("[name=direction]");
      validate.disabled = true;
      validate.textContent = "Validating…";
      result.replaceChildren();
      // Progress while the sandbox runs the function (a few seconds; an endless loop is
      // stopped after one call of the per-call limit).
      const progress = document.createElement("p");
      progress.className = "muted small validate-progress";
      result.append(progress);
      const perCall = Number(root.dataset.perCall || 5);
      const started = Date.now();
      const tick = () => {
        const s = Math.floor((Date.now() - started) / 1000);
        progress.textContent = `Running your function in the sandbox on the test situations… ${s} s (each call may take at most ${perCall} s).`;
      };
      tick();
      const timer = window.setInterval(tick, 500);
      try {
        const response = await fetch(root.dataset.validateUrl, {
          method: "POST",
          headers: {
            "Content-Type": "application/json",
            "X-CSRFToken": form.querySelector("[name=csrfmiddlewaretoken]").value,
          },
          body: JSON.stringify({
            source: getText(),
            track: track ? track.value : "",
            direction: direction ? direction.value : "native",
          }),
        });
        // The validation runs in a worker: poll until it is done (two minutes at most).
        const first = await response.json();
        const data = await pollUntilDone(first, first.poll, 120000, (d) => {
          validate.textContent = d.status === "running" ? "Running…" : "Queued…";
        });
        if (data.ok) showOk(data.rewards);
        else showErrors(data.errors);
      } catch (err) {
        showErrors([{ type: "NETWORK_ERROR", message: "Could not reach the server: " + err }]);
      } finally {
        window.clearInterval(timer);
        progress.remove();
        validate.disabled = false;
        validate.textContent = "Validate";
      }
    });
  }
})();
