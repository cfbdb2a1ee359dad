// ?check: the boxes of what a person must see without scrolling, written into the page as JSON
// (<script id="layout-report">) for tests that read the DOM a headless browser built
// (tests/view/test_view_browser.py): the viewport and the document's size, the running
// behaviours' names (and their font size), every cell of the mode table, the time axis and its
// ticks, and the newest events up to the tick shown, each with the box of what clips it.
"use strict";

var layoutCheck = (function () {
  function box(element) {
    var r = element.getBoundingClientRect();
    return [Math.round(r.left), Math.round(r.top), Math.round(r.right), Math.round(r.bottom)];
  }

  // The box an element is clipped to: its nearest ancestor that hides or scrolls overflow.
  function clip(element) {
    for (var parent = element.parentElement; parent; parent = parent.parentElement) {
      var style = getComputedStyle(parent);
      if (style.overflowX !== "visible" || style.overflowY !== "visible") { return box(parent); }
    }
    return box(document.documentElement);
  }

  function item(element, name) {
    return {name: name || element.textContent.trim().slice(0, 60), box: box(element), clip: clip(element),
            font: parseFloat(getComputedStyle(element).fontSize),
            elided: element.scrollWidth > element.clientWidth + 1 || element.scrollHeight > element.clientHeight + 1};
  }

  function report() {
    var now = Array.prototype.slice.call(document.querySelectorAll("#events li.now"));
    var data = {
      viewport: [window.innerWidth, window.innerHeight],
      document: [document.documentElement.scrollWidth, document.documentElement.scrollHeight],
      running: treePane.runningNames().map(function (name) { return item(name.element, name.name); }),
      cells: Array.prototype.map.call(document.querySelectorAll("#modes th, #modes td"), function (cell) {
        return item(cell);
      }),
      axis: Array.prototype.map.call(document.querySelectorAll("#axis text"), function (tick) { return item(tick); }),
      current: now.map(function (event) { return item(event); }),
      shown: Number(scrubber.value),
      frames: frames.length,
    };
    var script = document.getElementById("layout-report") || document.createElement("script");
    script.id = "layout-report";
    script.type = "application/json";
    script.textContent = JSON.stringify(data);
    document.body.appendChild(script);
  }

  return {report: report};
})();
