// sm_bt's view: the tree (tree.js, py_trees_js), the mode table, the run's timeline
// (timeline.js) and its events, live from the server's Server-Sent Events (/events) or a
// recording replayed. Frames carry what changed since the one before (sm_bt/view/frames.py);
// the page keeps them all, with the whole state every CHECKPOINT frames, so that the scrubber
// can show any tick.
//
// URL options: ?once (the run so far, then no more updates: a page to save, or a headless
// browser's look), ?at=SECONDS (show that moment of the run), ?span=FROM,TO (the timeline's
// window, in seconds), ?check (write the boxes of what must be in view into #layout-report, for
// the tests).
"use strict";

var CHECKPOINT = 32;
var frames = [];      // every frame received, in order
var checkpoints = []; // the whole state of frames 0, CHECKPOINT, 2 * CHECKPOINT, ...
var latest = null;    // the whole state of the newest frame
var shown = -1;       // the frame shown (-1: follow the newest)
var listed = [];      // the events' list items, in order ({index, item})
var later = 0;        // listed[later:] are after the frame shown
var scrubber = document.getElementById("scrubber");
var liveButton = document.getElementById("live");
var eventList = document.getElementById("events");
var options = new URLSearchParams(window.location.search);

// The whole state after ``frame``: behaviours (py_trees_js's format), visited, blackboard, modes.
function advance(state, frame) {
  var next = {tick: frame.tick, time: frame.time, status: frame.status};
  if (frame.key) {
    next.behaviours = frame.behaviours;
    next.root = rootOf(frame.behaviours);
    next.visited = frame.visited;
    next.blackboard = frame.blackboard || {};
    next.modes = frame.modes;
    next.modesSummary = frame.modes_summary;
    return next;
  }
  next.root = state.root;
  next.behaviours = state.behaviours;
  if (frame.changes) {
    next.behaviours = Object.assign({}, state.behaviours);
    for (var id in frame.changes) { next.behaviours[id] = changed(state.behaviours[id], frame.changes[id]); }
  }
  next.visited = frame.visited || state.visited;
  next.blackboard = frame.blackboard ? Object.assign({}, state.blackboard, frame.blackboard) : state.blackboard;
  next.modes = frame.modes || state.modes;
  next.modesSummary = frame.modes ? frame.modes_summary : state.modesSummary;  // it travels with its table
  return next;
}

function changed(behaviour, change) {
  var next = Object.assign({}, behaviour);
  next.data = Object.assign({}, behaviour.data);
  if ("status" in change) { next.status = change.status; }
  if ("feedback" in change) { next.data.Feedback = change.feedback; }
  if ("details" in change) {
    next.details = change.details;
    if (change.details === "...") { delete next.data.Detail; } else { next.data.Detail = change.details; }
  }
  return next;
}

function rootOf(behaviours) {
  var children = {};
  Object.keys(behaviours).forEach(function (id) {
    (behaviours[id].children || []).forEach(function (child) { children[child] = true; });
  });
  return Object.keys(behaviours).find(function (id) { return !children[id]; });
}

function stateAt(index) {
  if (index === frames.length - 1) { return latest; }
  var base = Math.floor(index / CHECKPOINT), state = checkpoints[base];
  for (var i = base * CHECKPOINT + 1; i <= index; i++) { state = advance(state, frames[i]); }
  return state;
}

function text(tag, content, cls) {
  var element = document.createElement(tag);
  element.textContent = content;
  if (cls) { element.className = cls; }
  return element;
}

// A table cell whose long names may wrap after a dot or an underscore (only if they must).
function breakable(content) {
  var cell = document.createElement("td");
  content.split(/(?<=[._])/).forEach(function (piece, index) {
    if (index) { cell.appendChild(document.createElement("wbr")); }
    cell.appendChild(document.createTextNode(piece));
  });
  return cell;
}

function showModes(state) {
  var body = document.querySelector("#modes tbody");
  body.replaceChildren();
  state.modes.forEach(function (row) {
    var tr = document.createElement("tr");
    tr.dataset.part = row.part;
    tr.className = row.kind + (row.error ? " error" : row.cause ? " diverging" : "");
    tr.appendChild(breakable(row.part));
    tr.appendChild(breakable(row.target || "-"));
    tr.appendChild(breakable(row.actual + (row.inferred ? " (*)" : "")));
    tr.appendChild(text("td", row.cause || ""));
    var held = text("td", row.held_by || "");  // who holds the part (a column shown only while one does)
    held.className = "held";
    tr.appendChild(held);
    body.appendChild(tr);
  });
  document.getElementById("modes").classList.toggle("holding", state.modes.some(function (row) {
    return Boolean(row.held_by);
  }));
  var summary = document.getElementById("modes-summary");  // how many parts there are, when some are left out
  summary.textContent = state.modesSummary || "";
  summary.hidden = !state.modesSummary;
  var status = document.getElementById("status");
  status.textContent = state.status;
  status.className = "status " + state.status;
  document.getElementById("clock").textContent = state.time.toFixed(1) + " s";
  document.getElementById("tick").textContent = "#" + state.tick;
}

function addEvents(frame, index) {
  (frame.events || []).forEach(function (event) {
    var item = text("li", event.time.toFixed(2) + " s  " + event.text, event.kind);
    if (event.plan) {  // a request's plan: its first line in the list, all of it on hover
      item.textContent += "  (" + event.plan[0].split(": ").pop() + ")";
      item.title = event.plan.join("\n");
    }
    item.dataset.index = String(index);
    eventList.appendChild(item);
    listed.push({index: index, item: item});
    if (shown >= 0) { item.classList.add("later"); } else { later = listed.length; }
  });
}

// The events up to the frame shown, the newest at the bottom of the list and those of its own
// tick marked; later ones dimmed below it.
function followEvents(index) {
  var boundary = listed.length;
  while (boundary > 0 && listed[boundary - 1].index > index) { boundary--; }
  if (boundary < later) {
    for (var i = boundary; i < later; i++) { listed[i].item.classList.add("later"); }
  } else {
    for (var j = later; j < boundary; j++) { listed[j].item.classList.remove("later"); }
  }
  later = boundary;
  eventList.querySelectorAll("li.now").forEach(function (item) { item.classList.remove("now"); });
  for (var k = boundary - 1; k >= 0 && listed[k].index === listed[boundary - 1].index; k--) {
    listed[k].item.classList.add("now");  // the newest events up to the tick shown
  }
  if (boundary > 0) {  // the newest of them in view, a few later ones below if there is room
    var first = listed[k + 1].item, current = listed[boundary - 1].item;
    var bottom = current.offsetTop + current.offsetHeight, height = eventList.clientHeight;
    var room = boundary < listed.length ? Math.max(height * 0.75, bottom - first.offsetTop) : height;
    eventList.scrollTop = Math.max(0, Math.min(first.offsetTop, bottom - Math.min(room, height)));
  }
}

function show(index) {
  var state = stateAt(index);
  treePane.draw(state);
  showModes(state);
  followEvents(index);
  timeline.draw(state.time);
}

function receive(frame) {
  if (!frames.length && !frame.key) { return; }  // a delta means nothing without its key frame
  latest = advance(latest, frame);
  frames.push(frame);
  if ((frames.length - 1) % CHECKPOINT === 0) { checkpoints.push(latest); }
  timeline.add(frame, latest.modes);
  addEvents(frame, frames.length - 1);
  scrubber.max = String(frames.length - 1);
  scrubber.disabled = false;
  if (shown < 0) {
    scrubber.value = scrubber.max;
    if (caughtUp) { scheduleDraw(); }
  }
}

// Live frames are drawn at most every 100 ms: a tree ticking at 100 Hz must not keep the
// browser busy. The run so far is drawn once it has all come.
var caughtUp = false, drawPending = false;
function scheduleDraw() {
  if (drawPending) { return; }
  drawPending = true;
  setTimeout(function () {
    drawPending = false;
    if (shown < 0 && frames.length) { show(frames.length - 1); }
  }, 100);
}

function select(index) {
  shown = index >= frames.length - 1 ? -1 : index;
  liveButton.disabled = shown < 0;
  scrubber.value = String(index);
  show(index);
}

function frameAt(time) {
  var index = 0;
  while (index + 1 < frames.length && frames[index + 1].time <= time) { index++; }
  return index;
}

scrubber.addEventListener("input", function () { select(Number(scrubber.value)); });
liveButton.addEventListener("click", function () { select(frames.length - 1); });
timeline.seek(function (time) { if (frames.length) { select(frameAt(time)); } });

function reset() {
  frames = []; checkpoints = []; latest = null; listed = []; later = 0; caughtUp = false;
  eventList.replaceChildren();
  timeline.reset();
}

function caughtUpNow() {
  caughtUp = true;
  if (options.has("span")) { timeline.zoom.apply(null, options.get("span").split(",").map(Number)); }
  if (!frames.length) { return; }
  if (options.has("at") && shown < 0) {
    select(frameAt(Number(options.get("at"))));
  } else {
    select(shown < 0 ? frames.length - 1 : shown);
  }
}

var source = new EventSource("/events");
source.onmessage = function (message) { receive(JSON.parse(message.data)); };
source.addEventListener("reset", reset);  // the server dropped frames this page had not read
source.addEventListener("caught-up", function () {
  caughtUpNow();
  if (options.has("once")) {
    source.close();
    settled(function () { document.body.dataset.once = "true"; });
  }
});
source.addEventListener("end", function () {
  if (!caughtUp) { caughtUpNow(); } else if (shown < 0) { select(frames.length - 1); }
  source.close();
  document.getElementById("ended").hidden = false;
  settled(function () { document.body.dataset.ended = "true"; });
});
source.onerror = function () {
  if (document.body.dataset.ended !== "true") {
    document.getElementById("status").textContent = "disconnected: retrying";
  }
};

// After the tree's views are drawn (jointjs renders asynchronously): ``then``, and the layout
// report when asked for.
function settled(then) {
  setTimeout(function () {
    if (options.has("check")) { layoutCheck.report(); }
    then();
  }, 300);
}
