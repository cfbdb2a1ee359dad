// The run's timeline: per part, a band of its actual state and mode over time and under it its
// requests (from asked to answered), a time axis, and a cursor at the tick shown. Click or drag
// on it to show that moment; the wheel zooms into the time around the pointer, a double-click
// shows the whole run again. Built as frames come (segments per part), drawn whole each time:
// a few hundred SVG elements. The bands are those of the parts in the table now; a part that left
// the table (a large model's table shows a few of its parts) has a gap in its band while it was out.
"use strict";

var timeline = (function () {
  var NS = "http://www.w3.org/2000/svg";
  var STATE_COLOURS = {active: "#2e7d32", inactive: "#f9a825", unconfigured: "#616161", finalized: "#424242",
                       unknown: "#37474f"};
  var ROW = 22, BAND = 13, AXIS = 22;
  var svg = document.getElementById("bands");
  var parts = [];        // the table's, in its order: the bands drawn
  var segments = {};     // part -> [{from, actual, error}]
  var requests = {};     // request number -> {part, from, to, ok, text}
  var marks = [];        // failed expectations of a scenario: {time, text}
  var end = 0;           // the latest time seen
  var windowed = null;   // {from, to} zoomed into, or null: the whole run
  var lastNow;
  var onSeek = null;

  // What a frame adds: a new segment where a part's actual (or its error) changed, requests.
  function add(frame, modes) {
    end = Math.max(end, frame.time);
    if (frame.modes) {
      var shown = {};
      modes.forEach(function (row) {
        shown[row.part] = true;
        var list = segments[row.part] = segments[row.part] || [], key = row.actual + (row.error ? "!" : "");
        if (!list.length || list[list.length - 1].key !== key) {
          list.push({from: frame.time, key: key, actual: row.actual, error: row.error});
        }
      });
      parts.forEach(function (part) {  // out of the table: what it does from now on is not known here
        var list = segments[part];
        if (!shown[part] && list.length && list[list.length - 1].actual !== null) {
          list.push({from: frame.time, key: "", actual: null, error: false});
        }
      });
      parts = modes.map(function (row) { return row.part; });
    }
    (frame.events || []).forEach(function (event) {
      if (event.kind === "expectation") { marks.push({time: event.time, text: event.text}); }
      if (event.kind !== "request" || event.request === undefined) { return; }
      var request = requests[event.request];
      if (!request) {
        request = requests[event.request] = {part: event.part, from: event.time, to: null, ok: null,
                                             text: event.text + (event.plan ? "\n" + event.plan.join("\n") : "")};
      }
      if (event.done) { request.to = event.time; request.ok = event.ok; request.text += "; " + event.text; }
    });
  }

  function el(tag, attributes, title) {
    var element = document.createElementNS(NS, tag);
    for (var name in attributes) { element.setAttribute(name, attributes[name]); }
    if (title) {
      var tip = document.createElementNS(NS, "title");
      tip.textContent = title;
      element.appendChild(tip);
    }
    return element;
  }

  // A step of 1, 2 or 5 times a power of ten giving about ``count`` ticks over ``span``.
  function step(span, count) {
    var raw = span / Math.max(1, count), power = Math.pow(10, Math.floor(Math.log10(raw)));
    var best = [1, 2, 5, 10].find(function (m) { return m * power >= raw; });
    return best * power;
  }

  // The whole run, or the window zoomed into (wheel: around the pointer; double-click: all).
  function range() {
    return windowed ? windowed : {from: 0, to: Math.max(end, 1)};
  }

  function draw(now) {
    lastNow = now;
    var width = svg.clientWidth || 600;
    var label = 14 + 6.5 * parts.reduce(function (longest, part) { return Math.max(longest, part.length); }, 4);
    var shown = range(), plot = width - label - 24, scale = plot / (shown.to - shown.from);
    var x = function (time) { return label + (time - shown.from) * scale; };
    // A span of time as a rectangle's x and width, cut to the plot (null: outside it).
    var span = function (from, to, least) {
      var left = Math.max(x(from), label), right = Math.min(x(to), label + plot);
      return right < label || left > label + plot ? null : {x: left, width: Math.max(least, right - left)};
    };
    var height = parts.length * ROW + AXIS;
    svg.setAttribute("height", height);
    svg.setAttribute("viewBox", "0 0 " + width + " " + height);
    svg.replaceChildren();
    parts.forEach(function (part, index) {
      var y = index * ROW;
      var name = el("text", {x: 2, y: y + BAND - 2, "class": "part"});
      name.textContent = part;
      svg.appendChild(name);
      var list = segments[part];
      list.forEach(function (segment, i) {
        var box = segment.actual === null ? null : span(segment.from, i + 1 < list.length ? list[i + 1].from : end, 1);
        if (!box) { return; }
        var state = segment.actual.split(".")[0], mode = segment.actual.split(".")[1];
        svg.appendChild(el("rect", {x: box.x, y: y, width: box.width, height: BAND,
                                    fill: segment.error ? "#b71c1c" : (STATE_COLOURS[state] || "#455a64")},
                           segment.actual + " from " + segment.from.toFixed(2) + " s"));
        if (mode && box.width > 7 * mode.length) {
          var text = el("text", {x: box.x + 2, y: y + BAND - 3, "class": "mode"});
          text.textContent = mode;
          svg.appendChild(text);
        }
      });
    });
    Object.keys(requests).forEach(function (id) {
      var request = requests[id], row = parts.indexOf(request.part);
      var box = span(request.from, request.to === null ? end : request.to, 3);
      if (row < 0 || !box) { return; }
      svg.appendChild(el("rect", {x: box.x, y: row * ROW + BAND + 2, width: box.width, height: 4,
                                  "class": "request " + (request.ok === null ? "open" : request.ok ? "ok" : "failed")},
                         request.text));
    });
    var axis = el("g", {id: "axis", transform: "translate(0," + (parts.length * ROW + 2) + ")"});
    axis.appendChild(el("line", {x1: label, x2: label + plot, y1: 0, y2: 0, "class": "axis"}));
    var every = step(shown.to - shown.from, Math.max(2, Math.floor(plot / 70)));
    for (var t = Math.ceil(shown.from / every - 1e-9) * every; t <= shown.to + 1e-9; t += every) {
      axis.appendChild(el("line", {x1: x(t), x2: x(t), y1: 0, y2: 4, "class": "axis"}));
      var tick = el("text", {x: x(t), y: 15, "class": "tick"});
      tick.textContent = (every < 1 ? t.toFixed(1) : String(Math.round(t))) + " s";
      axis.appendChild(tick);
    }
    svg.appendChild(axis);
    if (now !== undefined && now >= shown.from && now <= shown.to) {
      svg.appendChild(el("line", {x1: x(now), x2: x(now), y1: 0, y2: parts.length * ROW, "class": "cursor"}));
    }
    // Over the cursor: a failure stays visible at the moment it is shown.
    marks.forEach(function (mark) {
      if (mark.time < shown.from || mark.time > shown.to) { return; }
      svg.appendChild(el("line", {x1: x(mark.time), x2: x(mark.time), y1: 0, y2: parts.length * ROW,
                                  "class": "expectation"}, mark.text));
    });
    svg.dataset.label = String(label);
    svg.dataset.scale = String(scale);
    svg.dataset.from = String(shown.from);
  }

  // Click or drag: the time under the pointer.
  var dragging = false;
  function timeAt(event) {
    var box = svg.getBoundingClientRect();
    return Number(svg.dataset.from) + (event.clientX - box.left - Number(svg.dataset.label)) / Number(svg.dataset.scale);
  }
  function seek(event) {
    if (onSeek && Number(svg.dataset.scale) > 0) { onSeek(Math.max(0, timeAt(event))); }
  }
  svg.addEventListener("pointerdown", function (event) { dragging = true; seek(event); });
  svg.addEventListener("pointermove", function (event) { if (dragging) { seek(event); } });
  window.addEventListener("pointerup", function () { dragging = false; });
  svg.addEventListener("wheel", function (event) {
    event.preventDefault();
    var shown = range(), at = Math.min(shown.to, Math.max(shown.from, timeAt(event)));
    var span = Math.max(0.5, (shown.to - shown.from) * (event.deltaY > 0 ? 1.25 : 0.8));
    if (span >= end) { windowed = null; } else {
      var from = Math.max(0, at - (at - shown.from) * span / (shown.to - shown.from));
      windowed = {from: Math.min(from, end - span), to: Math.min(from, end - span) + span};
    }
    draw(lastNow);
  }, {passive: false});
  svg.addEventListener("dblclick", function () { windowed = null; draw(lastNow); });

  function reset() { parts = []; segments = {}; requests = {}; marks = []; end = 0; windowed = null; }

  return {add: add, draw: draw, reset: reset, seek: function (callback) { onSeek = callback; },
          zoom: function (from, to) { windowed = to > from ? {from: from, to: to} : null; }};
})();
