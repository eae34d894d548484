// mebm dashboard: refresh [data-poll] regions from their HTML fragment every few seconds
// (no full reload), and submit [data-autosubmit] selects on change. No dependencies.
(function () {
  "use strict";
  // widths from data attributes: the CSP allows no inline style
  function sizeBars(root) {
    root.querySelectorAll("[data-width-pct]").forEach(function (e) { e.style.width = e.getAttribute("data-width-pct") + "%"; });
    root.querySelectorAll("[data-left-pct]").forEach(function (e) { e.style.left = e.getAttribute("data-left-pct") + "%"; });
  }
  function poll(el) {
    var url = el.getAttribute("data-poll");
    var every = 1000 * (parseFloat(el.getAttribute("data-poll-s")) || 5);
    var busy = false;
    // a poll that fails keeps what the region shows and says so (the next tick retries):
    // the region never falls back to an older state without a word
    function trouble(why) {
      var note = el.querySelector(".poll-trouble");
      if (!note) {
        note = document.createElement("p");
        note.className = "warn-text poll-trouble";
        el.appendChild(note);
      }
      note.textContent = "This part of the page could not be refreshed (" + why + " at " +
        new Date().toLocaleTimeString() + "); it tries again every " + every / 1000 + " s. " +
        "If this lasts, reload the page.";
    }
    function tick() {
      if (busy || document.hidden) { return; }
      busy = true;
      fetch(url, { credentials: "same-origin", headers: { "Accept": "text/html" } })
        .then(function (r) {
          if (r.status === 401) { window.location.href = "/ui/sign-in"; return null; }
          if (!r.ok) { trouble("the service answered HTTP " + r.status); return null; }
          return r.text();
        })
        .then(function (html) {
          if (html === null || html === undefined) { return; }
          el.innerHTML = html;
          sizeBars(el);
          el.setAttribute("data-refreshed", new Date().toISOString());
          if (el.querySelector("[data-poll-stop]")) { clearInterval(timer); }
        })
        .catch(function () { trouble("the service does not answer"); })
        .finally(function () { busy = false; });
    }
    var timer = setInterval(tick, every);
  }
  document.addEventListener("DOMContentLoaded", function () {
    sizeBars(document);
    document.querySelectorAll("[data-poll]").forEach(poll);
    document.querySelectorAll("select[data-autosubmit]").forEach(function (s) {
      s.addEventListener("change", function () { s.form.submit(); });
    });
  });
})();
