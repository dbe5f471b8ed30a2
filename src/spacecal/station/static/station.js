// A run's page: the live 3-D view of the set-up over a websocket, progress, time left, and STOP.
(function () {
  var view = document.getElementById("view");
  var stopUrl = view.dataset.stop;
  // the set-up the station drew from the files (spacecal.station.scene): the plan, the site and,
  // through a calibration, the tracker and its volume; the samples are added as they come
  var source = document.getElementById("scene-figure");
  var figure = source ? JSON.parse(source.textContent) : null;
  var sceneFromBase = figure ? figure.scene_from_base : [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]];
  var frameName = figure ? figure.frame : "robot base";
  view.dataset.frame = frameName;
  var seen = [], unseen = [], latest = null, ended = false;
  function column(points, k) { return points.map(function (p) { return p === null ? null : p[k]; }); }
  function inScene(p) {  // a robot base point (mm) in the scene's frame
    var m = sceneFromBase;
    return [0, 1, 2].map(function (r) { return m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3]; });
  }
  function points(p, name, colour, size, symbol) {
    return {type: "scatter3d", mode: "markers", name: name, x: column(p, 0), y: column(p, 1), z: column(p, 2),
            marker: {size: size, color: colour, symbol: symbol || "circle"}};
  }
  function traces() {
    var data = figure ? figure.data.slice() : [];
    data.push(points(seen, "TCP, marker seen (" + seen.length + ")", "#2ca02c", 2));
    data.push(points(unseen, "TCP, marker not seen (" + unseen.length + ")", "#d62728", 2));
    var now = latest && latest.tcp_mm ? [inScene(latest.tcp_mm)] : [];
    data.push(points(now, "TCP now", "#222222", 7, "diamond"));
    return data;
  }
  var axes = {};
  ["x", "y", "z"].forEach(function (k) { axes[k + "axis"] = {title: {text: frameName + " " + k + " (mm)"}}; });
  var layout = {margin: {l: 0, r: 0, t: 30, b: 0}, uirevision: "keep", legend: {itemsizing: "constant"},
                title: {text: figure ? figure.layout.title.text : "in the robot base frame", font: {size: 13}},
                scene: {aspectmode: "data", xaxis: axes.xaxis, yaxis: axes.yaxis, zaxis: axes.zaxis}};
  // the view is a help, never a condition: without WebGL the numbers and STOP still work
  var drawing = true;
  // drawing shares the page's one thread with STOP's click: a draw that took d ms waits
  // QUIET_FACTOR * d before the next, so drawing never takes more than a sixth of the thread
  // (software WebGL on a busy machine took seconds per draw, and delayed a click as long)
  var QUIET_FACTOR = 5, MIN_PERIOD_MS = 500, nextDrawAt = 0;
  function draw(first) {
    if (!drawing) { return; }
    var started = Date.now();
    try {
      if (first) { Plotly.newPlot("view", traces(), layout, {displaylogo: false, responsive: true}); }
      else { Plotly.react("view", traces(), layout); }
    } catch (error) {
      drawing = false;
      view.textContent = "the live view cannot be drawn in this browser (" + error + ")";
    }
    var took = Date.now() - started;
    nextDrawAt = Date.now() + Math.max(MIN_PERIOD_MS, QUIET_FACTOR * took);
  }
  function text(id, value) { document.getElementById(id).textContent = value; }
  var scheme = location.protocol === "https:" ? "wss://" : "ws://";
  var address = scheme + location.host + "/runs/" + view.dataset.run + "/ws";
  // a connection lost mid-run stops the robot at the station's end (nobody could press STOP);
  // the page keeps trying, and once the station answers it shows what the run became
  var RECONNECT_AFTER_MS = 2000;
  var socket = null, drawn = 0;
  draw(true);
  function show(data) {
    data.frames.forEach(function (f) {
      if (!f.recorded || !f.tcp_mm) { return; }
      (f.marker_mm === null ? unseen : seen).push(inScene(f.tcp_mm));
    });
    latest = data.latest;
    text("run-state", data.run_state);
    text("move", data.move);
    text("moves", data.moves_total);
    text("samples", data.samples);
    text("visible", data.visible);
    text("message", data.message);
    text("time-left", typeof data.remaining_s === "number" ? "; about " + Math.round(data.remaining_s) + " s left" : "");
    // a guidance in one session waits at the standoff for the insertion's confirmation
    var awaiting = document.getElementById("awaiting");
    if (awaiting) { awaiting.hidden = data.awaiting !== "insert"; }
    var bar = document.getElementById("progress");
    bar.max = Math.max(1, data.moves_total);
    bar.value = data.move;
    if (Date.now() >= nextDrawAt && (data.frames.length || Date.now() - drawn > 2000)) {
      draw(false);
      drawn = Date.now();
    }
    if (data.run_state !== "starting" && data.run_state !== "running") {
      ended = true;
      var stop = document.getElementById("stop");
      stop.disabled = true;
      stop.classList.add("idle");  // STOP is live only while something moves
      // the heading says what the run became, not what it was doing
      text("run-title", view.dataset.title + ": " + data.run_state);
      if (data.run_state === "done") {  // every move made: the counters and the bar agree
        text("move", data.moves_total);
        bar.value = bar.max;
      }
      draw(false);  // the whole run, however the last draws were spaced
      socket.close();
    }
  }
  function connect() {
    // each connection is sent the run's frames from its first: the view starts over
    seen = []; unseen = [];
    socket = new WebSocket(address);
    socket.onmessage = function (event) { show(JSON.parse(event.data)); };
    socket.onclose = function () {
      if (ended) { return; }
      text("message", "connection to the station lost: the station stops the robot; reconnecting to show the run");
      setTimeout(connect, RECONNECT_AFTER_MS);
    };
  }
  connect();
  // leaving (reload, Back, closing the tab) stops the robot: the browser asks first while it moves
  window.addEventListener("beforeunload", function (event) {
    if (ended) { return; }
    event.preventDefault();
    event.returnValue = "The robot stops if you leave this page.";
  });
  document.getElementById("stop").addEventListener("click", function () {
    text("message", "stopping…");
    if (socket.readyState === WebSocket.OPEN) { socket.send("stop"); }
    fetch(stopUrl, {method: "POST"});
  });
})();
