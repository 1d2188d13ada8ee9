// The model page's reward function, highlighted read-only with the bundled CodeMirror.
"use strict";
(function () {
  const source = document.getElementById("reward-source");
  const mount = document.getElementById("reward-readonly");
  if (!source || !mount || !window.RacecraftEditor) return;
  const holder = document.createElement("textarea");
  holder.value = source.textContent;
  window.RacecraftEditor.mount(mount, holder, { readOnly: true });
  source.hidden = true;
})();
