// sm_bt's view: the tree (py_trees_js), the modes, the run's bands and events, live from the
// server's Server-Sent Events (/events), or a recording replayed.
"use strict";

// py_trees_js reads these two by name.
var canvas_graph = py_trees.canvas.create_graph();
var canvas_paper = py_trees.canvas.create_paper({graph: canvas_graph});
window.addEventListener("resize", function () { py_trees.canvas.on_window_resize(canvas_paper); });

// The tree of one frame on the canvas (py_trees_js lays it out again only when nodes are new).
function drawTree(tree) {
  canvas_paper.freeze();
  var added = py_trees.canvas.update_graph({graph: canvas_graph, tree: tree});
  if (added.length) {
    py_trees.canvas.layout_graph({graph: canvas_graph});
    added.forEach(function (node) {
      var view = canvas_paper.findViewByModel(node);
      view.listenTo(canvas_paper, "translate", view.updateBox);
      view.listenTo(canvas_paper, "scale", view.updateBox);
    });
    canvas_paper.updateViews();
    py_trees.canvas.scale_content_to_fit(canvas_paper);
  }
  canvas_paper.unfreeze();
}

var frames = [];       // every frame received, in order
var shown = -1;        // the frame shown in the table and bands (-1: follow the latest)
var eventsShown = 0;
var scrubber = document.getElementById("scrubber");
var liveButton = document.getElementById("live");
var STATE_COLOURS = {active: "#2e7d32", inactive: "#f9a825", unconfigured: "#616161", finalized: "#424242",
                     unknown: "#37474f"};

function text(tag, content, cls) {
  var element = document.createElement(tag);
  element.textContent = content;
  if (cls) { element.className = cls; }
  return element;
}

function showModes(frame) {
  var body = document.querySelector("#modes tbody");
  body.replaceChildren();
  frame.modes.forEach(function (row) {
    var tr = document.createElement("tr");
    tr.dataset.part = row.part;
    tr.className = row.kind + (row.error ? " error" : row.cause ? " diverging" : "");
    tr.appendChild(text("td", row.part));
    tr.appendChild(text("td", row.target || "-"));
    tr.appendChild(text("td", row.actual + (row.inferred ? " (*)" : "")));
    tr.appendChild(text("td", row.cause || ""));
    body.appendChild(tr);
  });
  var status = document.getElementById("status");
  status.textContent = frame.status;
  status.className = "status " + frame.status;
  document.getElementById("clock").textContent = frame.time.toFixed(1) + " s";
  document.getElementById("tick").textContent = "#" + frame.tick;
}

function addEvents(frame) {
  var list = document.getElementById("events");
  frame.events.forEach(function (event) {
    if (event.kind === "actual" || event.kind === "target") { return; }  // the bands show those
    var item = text("li", event.time.toFixed(2) + " s  " + event.text, event.kind);
    list.appendChild(item);
    eventsShown += 1;
  });
  list.scrollTop = list.scrollHeight;
}

// One band per part: its actual state and mode over time, a tick where its target changed.
function drawBands(upTo) {
  var svg = document.getElementById("bands");
  var last = frames[upTo];
  if (!last) { return; }
  var parts = last.modes.map(function (row) { return row.part; });
  var width = svg.clientWidth || 600, label = 130, rowHeight = 18;
  var end = Math.max(last.time, 1e-6), scale = (width - label - 4) / end;
  svg.setAttribute("height", parts.length * rowHeight + 16);
  svg.replaceChildren();
  var ns = "http://www.w3.org/2000/svg";
  parts.forEach(function (part, index) {
    var y = index * rowHeight + 2;
    var name = document.createElementNS(ns, "text");
    name.setAttribute("x", 2); name.setAttribute("y", y + 12); name.textContent = part;
    svg.appendChild(name);
    var segment = null, lastTarget = null;
    for (var i = 0; i <= upTo; i++) {
      var row = frames[i].modes.find(function (r) { return r.part === part; });
      if (!row) { continue; }
      var key = row.actual + (row.error ? "!" : "");
      if (!segment || segment.key !== key) {
        if (segment) { segment.to = frames[i].time; }
        segment = {key: key, row: row, from: frames[i].time, to: last.time};
        bandRect(svg, ns, segment, y, label, scale, rowHeight);
      } else {
        svg.lastSegment.setAttribute("width", Math.max(1, (last.time - segment.from) * scale));
      }
      if (lastTarget !== null && row.target !== lastTarget) {
        var mark = document.createElementNS(ns, "rect");
        mark.setAttribute("x", label + frames[i].time * scale - 1); mark.setAttribute("y", y - 1);
        mark.setAttribute("width", 2); mark.setAttribute("height", rowHeight - 2);
        mark.setAttribute("fill", "#90caf9");
        mark.appendChild(text("title", part + " targeted at " + row.target + " at " + frames[i].time.toFixed(2) + " s"));
        svg.appendChild(mark);
      }
      lastTarget = row.target;
    }
  });
}

function bandRect(svg, ns, segment, y, label, scale, rowHeight) {
  if (svg.lastSegment && svg.lastSegment.dataset.y === String(y)) {
    svg.lastSegment.setAttribute("width", Math.max(1, (segment.from - Number(svg.lastSegment.dataset.from)) * scale));
  }
  var rect = document.createElementNS(ns, "rect");
  var state = segment.row.actual.split(".")[0];
  rect.setAttribute("x", label + segment.from * scale); rect.setAttribute("y", y);
  rect.setAttribute("width", Math.max(1, (segment.to - segment.from) * scale));
  rect.setAttribute("height", rowHeight - 4);
  rect.setAttribute("fill", segment.row.error ? "#b71c1c" : (STATE_COLOURS[state] || "#455a64"));
  rect.dataset.y = String(y); rect.dataset.from = String(segment.from);
  rect.appendChild(text("title", segment.row.actual + " from " + segment.from.toFixed(2) + " s"));
  svg.appendChild(rect);
  svg.lastSegment = rect;
  var mode = segment.row.actual.split(".")[1];
  if (mode) {
    var label_ = document.createElementNS(ns, "text");
    label_.setAttribute("x", label + segment.from * scale + 2); label_.setAttribute("y", y + 11);
    label_.textContent = mode;
    svg.appendChild(label_);
  }
}

function show(index) {
  var frame = frames[index];
  drawTree(frame.tree);
  showModes(frame);
  drawBands(index);
}

function receive(frame) {
  frames.push(frame);
  addEvents(frame);
  scrubber.max = String(frames.length - 1);
  scrubber.disabled = false;
  if (shown < 0) {
    scrubber.value = scrubber.max;
    if (caughtUp) { showLatest(false); }
  }
}

// The tree, table and bands are redrawn at most every 100 ms (no timers: a page in the
// background gets them throttled to a minute); the run so far is drawn once it has all come.
var caughtUp = false, drawnAt = 0;
function showLatest(force) {
  var now = Date.now();
  if (!frames.length || (!force && now - drawnAt < 100)) { return; }
  drawnAt = now;
  show(frames.length - 1);
}

scrubber.addEventListener("input", function () {
  var index = Number(scrubber.value);
  shown = index === frames.length - 1 ? -1 : index;
  liveButton.disabled = shown < 0;
  show(index);
});
liveButton.addEventListener("click", function () {
  shown = -1;
  liveButton.disabled = true;
  scrubber.value = scrubber.max;
  show(frames.length - 1);
});

var source = new EventSource("/events");
source.onmessage = function (message) { receive(JSON.parse(message.data)); };
// /?once: the run so far, then no more updates (a page to save, or a headless browser's look).
var once = new URLSearchParams(window.location.search).has("once");
source.addEventListener("caught-up", function () {
  caughtUp = true;
  if (shown < 0) { showLatest(true); }
  if (once) {
    source.close();
    document.body.dataset.once = "true";
  }
});
source.addEventListener("end", function () {
  caughtUp = true;
  if (shown < 0) { showLatest(true); }
  source.close();
  document.body.dataset.ended = "true";
  var status = document.getElementById("status");
  status.textContent = (frames.length ? frames[frames.length - 1].status : "no frames") + " (run over)";
});
source.onerror = function () {
  if (document.body.dataset.ended !== "true") {
    document.getElementById("status").textContent = "disconnected: retrying";
  }
};
