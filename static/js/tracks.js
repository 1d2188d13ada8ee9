// The Tracks page: after a preview or a refused upload, land on the import form.
"use strict";
(function () {
  const head = document.getElementById("tracks-head");
  const target = head && head.dataset.jump ? document.getElementById(head.dataset.jump) : null;
  if (target) target.scrollIntoView({ block: "start" });
})();
