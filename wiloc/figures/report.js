/* The frame browser: pick a run and a filter, step with the arrow keys or the buttons. */
(function () {
  "use strict";
  var data = JSON.parse(document.getElementById("report-data").textContent);
  var byId = function (id) { return document.getElementById(id); };
  var run = 0, shown = [], at = 0;

  function filter() { return document.querySelector("input[name=filter]:checked").value; }

  function keeps(r, k, how, cut) {
    var decided = r.match[k] !== null;
    if (how === "wrong") { return decided && !r.correct[k]; }
    if (how === "confident-wrong") { return decided && !r.correct[k] && r.confidence[k] !== null && r.confidence[k] >= cut; }
    if (how === "leaving") { return !r.has_match[k]; }
    return true;
  }

  function picture(img, caption, index, text) {
    var uri = index >= 0 ? data.images[index] : "";
    if (uri) { img.src = uri; } else { img.removeAttribute("src"); }  /* src="" would be a failed load */
    img.style.visibility = uri ? "visible" : "hidden";
    caption.textContent = text;
  }

  function show() {
    var r = data.runs[run];
    var info = byId("frame-info");
    byId("position").max = String(Math.max(shown.length - 1, 0));
    byId("position").value = String(at);
    byId("counter").textContent = shown.length ? (at + 1) + " / " + shown.length : "0 / 0";
    if (!shown.length) {
      info.textContent = "No frame of this run passes the filter.";
      info.className = "frame-info";
      ["query", "match", "truth"].forEach(function (cell) { picture(byId(cell + "-img"), byId(cell + "-caption"), -1, ""); });
      return;
    }
    var k = shown[at];
    var decided = r.match[k] !== null;
    var verdict = !decided ? "undecided" : (r.correct[k] ? "right" : "wrong");
    var parts = ["frame " + (r.first + k) + " (0-" + (r.run_frames - 1) + ")", verdict];  /* numbered as in the run and its timeline, from 0 */
    if (r.confidence[k] !== null) { parts.push("confidence " + r.confidence[k].toFixed(3)); }
    if (r.new_place && r.new_place[k] !== null) { parts.push("P(new place) " + r.new_place[k].toFixed(3)); }
    if (!r.has_match[k]) { parts.push("no true match in the map"); }
    info.textContent = parts.join(" \u00b7 ");
    info.className = "frame-info " + (verdict === "undecided" ? "" : verdict);
    picture(byId("query-img"), byId("query-caption"), r.query_image[k], "query " + r.frames[k]);
    picture(byId("match-img"), byId("match-caption"), decided ? r.match_image[k] : -1,
            decided ? "decided match " + r.match[k] : "no match decided");
    picture(byId("truth-img"), byId("truth-caption"), r.truth_image[k],
            r.truth[k] !== null ? "true place " + r.truth[k] : "no true place in the map");
  }

  function refresh() {
    var r = data.runs[run], how = filter(), cut = parseFloat(byId("confident-cut").value);
    var current = shown.length ? shown[at] : 0;
    shown = [];
    for (var k = 0; k < r.frames.length; k++) { if (keeps(r, k, how, isNaN(cut) ? data.confident : cut)) { shown.push(k); } }
    at = 0;
    for (var i = 0; i < shown.length; i++) { if (shown[i] <= current) { at = i; } }
    show();
  }

  function step(by) {
    if (!shown.length) { return; }
    at = Math.min(Math.max(at + by, 0), shown.length - 1);
    show();
  }

  byId("run-select").addEventListener("change", function (event) { run = Number(event.target.value); shown = []; refresh(); });
  Array.prototype.forEach.call(document.querySelectorAll("input[name=filter]"), function (input) {
    input.addEventListener("change", refresh);
  });
  byId("confident-cut").addEventListener("input", refresh);
  byId("position").addEventListener("input", function (event) { at = Number(event.target.value); show(); });
  byId("prev").addEventListener("click", function () { step(-1); });
  byId("next").addEventListener("click", function () { step(1); });
  document.addEventListener("keydown", function (event) {
    var typing = event.target.tagName === "INPUT" && event.target.type === "number";
    if (typing || event.altKey || event.ctrlKey || event.metaKey) { return; }
    if (event.key === "ArrowRight") { step(1); event.preventDefault(); }
    if (event.key === "ArrowLeft") { step(-1); event.preventDefault(); }
  });
  refresh();
  document.body.setAttribute("data-ready", "yes");
}());
