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
    function tick() {
      if (busy || document.hidden) { return; }
      busy = true;
      fetch(url, { credentials: "same-origin", headers: { "Accept": "text/html" } })
        .then(function (r) {
          if (r.status === 401) { window.location.href = "/ui/sign-in"; return null; }
          return r.ok ? r.text() : null;
        })
        .then(function (html) {
          if (html === null || html === undefined) { return; }
          el.innerHTML = html;
          sizeBars(el);
          el.setAttribute("data-refreshed", new Date().toISOString());
          if (el.querySelector("[data-poll-stop]")) { clearInterval(timer); }
        })
        .catch(function () { /* the next tick retries */ })
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
