// The tree pane: py_trees_js draws the part of the tree that matters now, readable.
//
// A whole mission tree scaled to fit a laptop's pane has labels a few pixels high, so py_trees_js
// gets a pruned tree instead:
// - the root's and the running behaviours' children are drawn; every other subtree is closed into
//   its top behaviour (py_trees_js's brown dot under it); double-click a behaviour to open or
//   close it, "all" opens everything;
// - of an open behaviour with more than MANY children, the running ones are drawn and the others
//   between them as one narrow "N more" placeholder (double-click it to draw them all);
// - when the running branch is deeper than the pane holds, its top becomes a breadcrumb line
//   above the tree (click an ancestor there to draw the tree from it).
// The camera follows the running behaviours at a scale that keeps names >= 11 px (py_trees_js
// draws them 14 px at scale 1). The wheel zooms around the pointer and a drag pans; either stops
// the following, "follow" (or a double-click on the background) starts it again.
"use strict";

var treePane = (function () {
  var MIN_SCALE = 0.8, MAX_SCALE = 1.0, PAD = 12, MANY = 3, NODE = {width: 170, height: 52}, MORE = 96;
  var RANK_SEP = 24;
  // py_trees_js reads these two globals by name.
  window.canvas_graph = py_trees.canvas.create_graph();
  window.canvas_paper = py_trees.canvas.create_paper({graph: canvas_graph});
  var graph = canvas_graph, paper = canvas_paper;
  var pane = document.getElementById("canvas"), crumbBar = document.getElementById("crumbs");
  var opened = {};      // behaviour id -> true/false: opened or closed by hand
  var wholly = {};      // behaviour id -> true: all its children drawn (its placeholder was opened)
  var showAll = false;  // "all": every subtree open, from the root
  var pinned = null;    // the behaviour the tree is drawn from, chosen in the breadcrumb
  var follow = true;    // the camera follows the running behaviours
  var last = null, shownKey = "", focusedOn = "";

  // py_trees_js's own handlers zoom around the origin, fit the whole tree on a double click and
  // collapse without a new layout: ours instead.
  paper.off("blank:mousewheel");
  paper.off("blank:pointerdblclick");
  paper.off("element:pointerdblclick");
  paper.on("blank:mousewheel", function (event, x, y, delta) { zoom(x, y, delta); });
  paper.on("cell:mousewheel", function (view, event, x, y, delta) { zoom(x, y, delta); });
  paper.on("blank:pointerdown", function () { setFollow(false); });
  paper.on("blank:pointerdblclick", function () { pinned = null; setFollow(true); });
  paper.on("element:pointerdblclick", function (view) {
    if (!last) { return; }
    var id = view.model.get("behaviour_id"), hidden = (view.model.get("data") || {}).Hidden;
    if (hidden) { wholly[id.split("/")[0]] = true; } else { opened[id] = !isOpen(last.behaviours[id], last); }
    draw(last, true);
  });

  function zoom(x, y, delta) {
    setFollow(false);
    var scale = paper.scale().sx, offset = paper.translate();
    var next = Math.min(3, Math.max(0.1, scale * (delta > 0 ? 1.15 : 1 / 1.15)));
    paper.translate(offset.tx + x * (scale - next), offset.ty + y * (scale - next));
    paper.scale(next, next);
  }

  function setFollow(on) {
    follow = on;
    document.getElementById("follow").classList.toggle("on", on);
    if (on && last) { draw(last, true); }
  }

  function isOpen(behaviour, state) {
    if (!behaviour || !behaviour.children) { return false; }
    if (behaviour.id in opened) { return opened[behaviour.id]; }
    return showAll || behaviour.status === "RUNNING" || behaviour.id === state.root;
  }

  // The behaviours to draw from ``top``, their children pruned as said above.
  function prune(state, top) {
    var behaviours = state.behaviours, shown = {}, collapsed = [], placeholders = [];
    (function visit(id) {
      var behaviour = behaviours[id];
      if (!behaviour) { return; }
      if (!isOpen(behaviour, state)) {
        shown[id] = behaviour.children ? withChildren(behaviour, undefined) : behaviour;
        if (behaviour.children) { collapsed.push(id); }
        return;
      }
      var children = behaviour.children, kept = children;
      var running = children.filter(function (child) { return (behaviours[child] || {}).status === "RUNNING"; });
      if (children.length > MANY && !showAll && !wholly[id] && running.length) {
        kept = [];
        var hidden = [];
        children.concat([null]).forEach(function (child) {
          if (child !== null && running.indexOf(child) < 0) { hidden.push(child); return; }
          if (hidden.length) {
            var more = placeholder(id, hidden, behaviours);
            shown[more.id] = more;
            placeholders.push(more.id);
            kept.push(more.id);
            hidden = [];
          }
          if (child !== null) { kept.push(child); }
        });
      }
      shown[id] = kept === children ? behaviour : withChildren(behaviour, kept);
      kept.forEach(function (child) { if (!shown[child]) { visit(child); } });
    })(top);
    return {behaviours: shown, collapsed: collapsed, placeholders: placeholders};
  }

  function withChildren(behaviour, children) {
    var copy = Object.assign({}, behaviour);
    if (children) { copy.children = children; } else { delete copy.children; }
    return copy;
  }

  function placeholder(parent, hidden, behaviours) {
    return {id: parent + "/" + hidden[0], name: hidden.length + " more", status: "INVALID", colour: "#333333",
            details: "double-click: all", data: {Hidden: hidden.map(function (child) {
              return (behaviours[child] || {}).name;
            })}};
  }

  // Ranks under ``id`` in a pruned tree (1: a leaf).
  function depth(shown, id) {
    var children = (shown[id] || {}).children || [];
    return 1 + children.reduce(function (most, child) { return Math.max(most, depth(shown, child)); }, 0);
  }

  // Where to draw from: the root, or down the running branch as far as it takes to fit the
  // pane's height at the smallest readable scale.
  function top(state) {
    if (showAll) { return state.root; }
    if (pinned && state.behaviours[pinned]) { return pinned; }
    var fits = Math.max(2, Math.floor((pane.clientHeight - 2 * PAD + RANK_SEP * MIN_SCALE) /
                                      ((NODE.height + RANK_SEP) * MIN_SCALE)));
    var shown = prune(state, state.root).behaviours, id = state.root;
    while (depth(shown, id) > fits) {
      var deepest = null, most = 0;
      (shown[id].children || []).forEach(function (child) {
        var d = depth(shown, child);
        if (shown[child].status === "RUNNING" && d > most) { deepest = child; most = d; }
      });
      if (deepest === null) { break; }
      id = deepest;
    }
    return id;
  }

  function ancestors(state, id) {
    var parents = {};
    Object.keys(state.behaviours).forEach(function (parent) {
      (state.behaviours[parent].children || []).forEach(function (child) { parents[child] = parent; });
    });
    var path = [];
    for (var at = parents[id]; at !== undefined; at = parents[at]) { path.unshift(at); }
    return path;
  }

  function showCrumbs(state, from) {
    crumbBar.replaceChildren();
    ancestors(state, from).forEach(function (id) {
      var behaviour = state.behaviours[id], crumb = document.createElement("button");
      crumb.type = "button";
      crumb.className = "crumb " + behaviour.status;
      crumb.textContent = behaviour.name;
      crumb.title = "draw the tree from " + behaviour.name;
      crumb.dataset.id = id;
      crumb.addEventListener("click", function () { pinned = id; setFollow(true); });
      crumbBar.appendChild(crumb);
    });
  }

  // Draw ``state`` (view.js: behaviours, visited, root, time); ``refocus``: move the camera even
  // if the running behaviours did not change.
  function draw(state, refocus) {
    last = state;
    var from = top(state), pruned = prune(state, from);
    showCrumbs(state, from);
    var key = Object.keys(pruned.behaviours).join(",") + "|" + pruned.collapsed.join(",");
    paper.freeze();
    var added = py_trees.canvas.update_graph({graph: graph, tree: {
      changed: "true", timestamp: state.time, visited_path: state.visited, behaviours: pruned.behaviours}});
    if (added && added.length) {
      graph.getElements().forEach(function (element) {
        var more = pruned.placeholders.indexOf(element.get("behaviour_id")) >= 0;
        element.resize(more ? MORE : width(element.get("name")), NODE.height);
      });
      layout();
      added.forEach(function (cell) {
        if (cell.isLink()) { return; }
        var view = paper.findViewByModel(cell);
        view.listenTo(paper, "translate", view.updateBox);
        view.listenTo(paper, "scale", view.updateBox);
      });
      paper.updateViews();
    }
    graph.getElements().forEach(function (element) {
      var dot = pruned.collapsed.indexOf(element.get("behaviour_id")) >= 0 ? "visible" : "hidden";
      if (element.attr("collapse/visibility") !== dot) { element.attr("collapse/visibility", dot); }
    });
    paper.unfreeze();
    var running = runningKey();
    if (follow && (refocus || key !== shownKey || running !== focusedOn)) { focus(); }
    shownKey = key;
    focusedOn = running;
  }

  // Wide enough for the name on two lines (py_trees_js gives it 80 % of the box, 14 px at scale 1:
  // about a tenth of the box's width in characters per line).
  function width(name) {
    var longest = name.split(/\s+/).reduce(function (most, word) { return Math.max(most, word.length); }, 0);
    return Math.round(Math.min(260, Math.max(NODE.width, 10.5 * longest + 10, 6 * name.length + 10)));
  }

  // A tighter layout than py_trees_js's, and org-chart links (down from the parent's bottom,
  // across, down into the child's top) instead of its obstacle-avoiding router, which costs more
  // than the rest of a redraw and crosses the tree.
  function layout() {
    joint.layout.DirectedGraph.layout(graph, {rankDir: "TB", nodeSep: 12, rankSep: RANK_SEP, edgeSep: 10,
                                              marginX: 10, marginY: 10});
    graph.getLinks().forEach(function (link) {
      var from = link.getSourceElement().getBBox(), to = link.getTargetElement().getBBox();
      var middle = (from.y + from.height + to.y) / 2;
      link.router("normal");
      link.connector("normal");
      link.source(link.getSourceElement(), {anchor: {name: "bottom"}});
      link.target(link.getTargetElement(), {anchor: {name: "top"}});
      link.vertices([{x: from.x + from.width / 2, y: middle}, {x: to.x + to.width / 2, y: middle}]);
    });
  }

  function runningElements() {
    return graph.getElements().filter(function (element) { return element.get("status") === "RUNNING"; });
  }

  function runningKey() {
    return runningElements().map(function (element) { return element.get("behaviour_id"); }).join(",");
  }

  // As much of the tree as fits at a readable scale (all of it with "all"), the running
  // behaviours in the middle, or the deepest of them when they do not all fit.
  function focus() {
    var width = pane.clientWidth, height = pane.clientHeight, elements = graph.getElements();
    if (!elements.length || !width || !height) { return; }
    var all = graph.getBBox(elements), running = runningElements();
    var target = running.length && !showAll ? graph.getBBox(running) : all;
    var fits = Math.min((width - 2 * PAD) / all.width, (height - 2 * PAD) / all.height);
    var scale = Math.min(MAX_SCALE, Math.max(showAll ? 0.05 : MIN_SCALE, fits));
    var room = (height - 2 * PAD) / scale;
    if (target.height > room) { target = {x: target.x, width: target.width, y: target.y + target.height - room, height: room}; }
    paper.scale(scale, scale);
    paper.translate(axis(all.x, all.width, target.x, target.width, width, scale),
                    axis(all.y, all.height, target.y, target.height, height, scale));
  }

  // The translation along one axis: the target centred, with no empty margin where the tree
  // could fill the pane.
  function axis(start, size, targetStart, targetSize, room, scale) {
    if (size * scale <= room - 2 * PAD) { return (room - size * scale) / 2 - start * scale; }
    var centred = room / 2 - (targetStart + targetSize / 2) * scale;
    var most = PAD - start * scale, least = room - PAD - (start + size) * scale;
    return Math.min(most, Math.max(least, centred));
  }

  document.getElementById("follow").addEventListener("click", function () { pinned = null; setFollow(true); });
  document.getElementById("expand").addEventListener("click", function (event) {
    showAll = !showAll;
    opened = {};
    wholly = {};
    event.target.classList.toggle("on", showAll);
    if (last) { draw(last, true); }
  });
  window.addEventListener("resize", function () { if (follow && last) { draw(last, true); } });

  // What shows the running behaviours, for the page's layout check (check.js): their names in
  // the tree, and the breadcrumb's.
  function runningNames() {
    var names = runningElements().map(function (element) {
      return {name: element.get("name"), element: paper.findViewByModel(element).$name[0]};
    });
    crumbBar.querySelectorAll(".crumb.RUNNING").forEach(function (crumb) {
      names.push({name: crumb.textContent, element: crumb});
    });
    return names;
  }

  return {draw: draw, runningNames: runningNames};
})();
