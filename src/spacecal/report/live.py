"""A live view of an acquisition in the web browser: the marker in the tracker's volume, the
sweeps recorded so far, and the samples counted, while ``spacecal acquire --live-view`` runs.

Why a local web page, and not the Rerun viewer or RViz: every robotics workstation already has
a browser open, the page needs no extra package (the standard library's ``http.server`` and the
plotly.js that the report already embeds), it works offline and behind a hospital firewall,
any machine on the same host can look, and it is tested headless with the same Chromium that
tests the report. Rerun (``rerun-sdk``) would add a large binary wheel whose viewer must match
the SDK's version, and RViz needs a ROS installation; both can be fed later from the same
observer if a site wants them.

How it stays out of the robot's way:

* :meth:`LiveView.observe` is the acquisition's frame observer (see
  :data:`spacecal.workflows.acquisition.FrameObserver`). It takes no lock and does no I/O: it
  counts, keeps the marker position and appends one tuple to a ``collections.deque`` with a
  fixed length, so a full buffer drops its oldest frame and the acquisition never waits on
  the view.
* The page is served by a ``ThreadingHTTPServer`` on 127.0.0.1 in a daemon thread; the
  browser polls ``/data?since=N`` for the frames after the N-th, twice a second.
* Nothing another program does with its connections can stop the view answering: each
  connection serves one request (HTTP/1.0, no keep-alive), has :data:`READ_TIMEOUT_S` to send
  it whole (however slowly it trickles in) and each read and write of it that long; at most
  :data:`MAX_CONNECTIONS` are open at once, and a new one beyond them closes the one that has
  waited longest for its request (a browser sends its request at once, so only idle or
  half-open connections are ever closed so), and the listening queue holds
  :data:`LISTEN_BACKLOG` connections not yet taken (the standard library's 5 let a burst of
  connections make a browser's wait seconds long).
* A view that cannot start (the port is taken) warns once on stderr and the run goes on
  without it; an exception inside the observer is caught by the acquisition loop, which
  warns once and detaches it.
"""

from __future__ import annotations

import collections
import contextlib
import json
import socket
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, cast
from urllib.parse import parse_qs, urlparse

import numpy as np

from spacecal.models.tracker import PyramidVolume

#: The port ``--live-view`` uses when none is given.
DEFAULT_PORT = 8765
#: Frames kept for the page; an acquisition at 20 Hz fills it in about 17 minutes.
DEFAULT_CAPACITY = 20_000
#: Frames sent in one reply at most (a page that fell behind catches up over a few polls).
MAX_FRAMES_PER_REPLY = 5_000
#: How long a connection may take to send its whole request, and each read or write of it, s
#: (a browser sends its request at once and reads the reply as it comes).
READ_TIMEOUT_S = 10.0
#: Connections served at once (a page polls over one at a time; a few tabs, a few more).
MAX_CONNECTIONS = 64
#: Connections the listening socket queues before they are taken.
LISTEN_BACKLOG = 128


class LiveView:
    """A local web page showing an acquisition as it runs.

    Parameters
    ----------
    port : int
        TCP port on 127.0.0.1; 0 picks a free one.
    capacity : int
        Frames kept; when full, the oldest are dropped.
    volume : PyramidVolume
        The tracker's measurement volume to draw (default: Polaris Vicra).

    Examples
    --------
    >>> with LiveView(0) as view:  # doctest: +SKIP
    ...     print(view.url)
    ...     app.acquire(settings, observer=view.observe)
    """

    def __init__(
        self, port: int = DEFAULT_PORT, capacity: int = DEFAULT_CAPACITY, volume: PyramidVolume | None = None
    ):
        self.port = port
        self.volume = volume or PyramidVolume()
        self._frames: collections.deque = collections.deque(maxlen=capacity)
        self._sequence = 0
        self._samples = 0
        self._visible = 0
        self._per_segment: dict[str, int] = {}
        self._latest: (
            tuple[float, str, tuple[float, float, float] | None, tuple[float, float, float]] | None
        ) = None
        self._status = "waiting for the first frame"
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None
        self._page: bytes | None = None
        #: Requests that ended in an error (a browser that closed the tab mid-reply): counted,
        #: never printed on the terminal the acquisition's progress line owns.
        self.failed_requests = 0

    # -- the acquisition's side: no lock, no I/O ---------------------------------------------

    def observe(
        self,
        time_s: float,
        segment: str,
        tracker_from_marker: np.ndarray | None,
        base_from_tcp: np.ndarray,
        recorded: bool,
    ) -> None:
        """The frame observer: keep the frame for the page and return at once."""
        position = None
        if tracker_from_marker is not None:
            position = (
                float(tracker_from_marker[0, 3]),
                float(tracker_from_marker[1, 3]),
                float(tracker_from_marker[2, 3]),
            )
        # the TCP in the robot base frame: drawn with the plan before any calibration exists
        tcp = (float(base_from_tcp[0, 3]), float(base_from_tcp[1, 3]), float(base_from_tcp[2, 3]))
        self._sequence += 1
        if recorded:
            self._samples += 1
            self._visible += position is not None
            self._per_segment[segment] = self._per_segment.get(segment, 0) + 1
        self._latest = (float(time_s), segment, position, tcp)
        self._status = "running"
        self._frames.append((self._sequence, float(time_s), segment, position, bool(recorded), tcp))

    def finish(self, status: str = "finished") -> None:
        """Say on the page that the run is over (or why it stopped)."""
        self._status = status

    # -- the page's side --------------------------------------------------------------------

    def snapshot(self, since: int = 0) -> dict[str, Any]:
        """What ``/data?since=N`` returns: the frames after the N-th and the counts."""
        for _ in range(10):
            try:
                frames = list(self._frames)  # the acquisition may append meanwhile: retry
                break
            except RuntimeError:
                continue
        else:
            frames = []
        new = [f for f in frames if f[0] > since][:MAX_FRAMES_PER_REPLY]
        oldest = frames[0][0] if frames else self._sequence + 1
        return {
            "sequence": new[-1][0] if new else max(since, 0),
            "latest_sequence": self._sequence,
            "dropped": max(0, oldest - since - 1),  # frames the ring buffer let go unseen
            "frames": [
                {"n": n, "t": t, "segment": s, "marker_mm": p, "recorded": r, "tcp_mm": q}
                for n, t, s, p, r, q in new
            ],
            "samples": self._samples,
            "visible": self._visible,
            "per_segment": dict(self._per_segment),
            "latest": None
            if self._latest is None
            else {
                "t": self._latest[0],
                "segment": self._latest[1],
                "marker_mm": self._latest[2],
                "tcp_mm": self._latest[3],
            },
            "status": self._status,
        }

    def page(self) -> bytes:
        """The self-contained page (plotly.js embedded)."""
        if self._page is None:
            from plotly.offline import get_plotlyjs

            volume = json.dumps(volume_edges(self.volume))
            self._page = (
                PAGE.replace("/*PLOTLY*/", get_plotlyjs()).replace("/*VOLUME*/null", volume).encode("utf-8")
            )
        return self._page

    # -- server -----------------------------------------------------------------------------

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/"

    @property
    def running(self) -> bool:
        return self._server is not None

    def start(self) -> bool:
        """Serve the page; False (with one warning on stderr) when it cannot."""
        view = self

        class Handler(BaseHTTPRequestHandler):
            timeout = READ_TIMEOUT_S  # each read and write of the connection (StreamRequestHandler)

            def parse_request(self) -> bool:
                parsed = super().parse_request()
                # its request is in: the connection is no longer idle
                cast(_BoundedThreadingServer, self.server).request_read(self.connection)
                return parsed

            def do_GET(self) -> None:
                if not _local_host(self.headers.get("Host"), view.port):
                    # a page served under another name (DNS rebinding) gets nothing
                    self.send_error(421, "Misdirected Request")
                    return
                address = urlparse(self.path)
                if address.path == "/":
                    self._send(view.page(), "text/html; charset=utf-8")
                elif address.path == "/data":
                    try:
                        since = int(parse_qs(address.query).get("since", ["0"])[0])
                    except ValueError:
                        since = 0
                    self._send(json.dumps(view.snapshot(since)).encode(), "application/json")
                else:
                    self.send_error(404)

            def _send(self, body: bytes, kind: str) -> None:
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: Any) -> None:
                pass  # the acquisition's progress line owns the terminal

        class Server(_BoundedThreadingServer):
            def handle_error(self, request: Any, client_address: Any) -> None:
                # a browser that closes the tab mid-reply is not an error worth a traceback on the
                # terminal the acquisition's progress line owns
                view.failed_requests += 1

        try:
            server = Server(("127.0.0.1", self.port), Handler)
        except OSError as exc:
            print(
                f"warning: live view not started: port {self.port} on 127.0.0.1 ({exc.strerror or exc}); "
                "the acquisition runs without it",
                file=sys.stderr,
                flush=True,
            )
            return False
        server.daemon_threads = True
        self.port = server.server_address[1]
        self._server = server
        self._thread = threading.Thread(
            target=server.serve_forever,
            kwargs={"poll_interval": 0.25},
            name="spacecal-live-view",
            daemon=True,
        )
        self._thread.start()
        return True

    def close(self) -> None:
        """Stop serving."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def __enter__(self) -> LiveView:
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class _BoundedThreadingServer(ThreadingHTTPServer):
    """A ``ThreadingHTTPServer`` that no number of idle, slow or half-open connections fills.

    Each accepted connection is waiting for its request until its handler has read it
    (:meth:`request_read`); one waiting longer than :data:`READ_TIMEOUT_S` is shut down at the
    next poll of the serving loop (:meth:`service_actions`), and a connection beyond
    :data:`MAX_CONNECTIONS` shuts down the one waiting longest (or, when every one is busy
    with a reply, is itself closed at once). Shutting a socket down wakes its handler's
    blocked read, which then ends and closes it.
    """

    daemon_threads = True
    request_queue_size = LISTEN_BACKLOG

    def __init__(self, *args: Any, **kwargs: Any):
        self._lock = threading.Lock()
        self._open: set[socket.socket] = set()
        self._waiting: dict[socket.socket, float] = {}  # accepted at (monotonic s)
        #: Connections closed unserved: idle past the deadline or pushed out by newer ones.
        self.dropped_connections = 0
        super().__init__(*args, **kwargs)

    def process_request(self, request: Any, client_address: Any) -> None:
        with self._lock:
            if len(self._open) >= MAX_CONNECTIONS:
                if not self._waiting:  # all busy with replies: this one waits for none
                    self.dropped_connections += 1
                    self.shutdown_request(request)
                    return
                self._drop(min(self._waiting, key=self._waiting.__getitem__))
            self._open.add(request)
            self._waiting[request] = time.monotonic()
        super().process_request(request, client_address)

    def request_read(self, connection: socket.socket) -> None:
        """A handler has read its connection's request: the connection is no longer idle."""
        with self._lock:
            self._waiting.pop(connection, None)

    def service_actions(self) -> None:
        # run by serve_forever between polls: close the connections past their deadline
        now = time.monotonic()
        with self._lock:
            for connection in [c for c, since in self._waiting.items() if now - since > READ_TIMEOUT_S]:
                self._drop(connection)

    def _drop(self, connection: socket.socket) -> None:
        """Shut a waiting connection down (its handler's read ends and closes it); under the lock."""
        self._waiting.pop(connection, None)
        self._open.discard(connection)
        self.dropped_connections += 1
        with contextlib.suppress(OSError):
            connection.shutdown(socket.SHUT_RDWR)

    def shutdown_request(self, request: Any) -> None:
        with self._lock:
            self._open.discard(request)
            self._waiting.pop(request, None)
        super().shutdown_request(request)


#: The names the page may be asked for under: the loopback address and ``localhost``.
LOCAL_HOSTS = ("127.0.0.1", "localhost")


def _local_host(header: str | None, port: int) -> bool:
    """True when a request's ``Host`` header names this server on loopback (``127.0.0.1:PORT``
    or ``localhost:PORT``): a page of another site that rebinds its name to 127.0.0.1 sends its
    own name and is refused."""
    if not header:
        return False
    host, _, given_port = header.strip().rpartition(":")
    return host.lower() in LOCAL_HOSTS and given_port == str(port)


def volume_edges(volume: PyramidVolume) -> list[list[float] | None]:
    """The frustum's 12 edges as a polyline with None between edges (tracker frame, mm)."""
    corners = []
    for depth in (volume.near_mm, volume.far_mm):
        half_x = 0.5 * volume.far_width_mm * depth / volume.far_mm
        half_y = 0.5 * volume.far_height_mm * depth / volume.far_mm
        corners.append(
            [[sx * half_x, sy * half_y, -depth] for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        )
    points: list[list[float] | None] = []
    for face in corners:
        points += [*face, face[0], None]
    for near, far in zip(*corners):
        points += [near, far, None]
    return points


PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>spacecal acquisition: live view</title>
<style>
body { font-family: system-ui, sans-serif; margin: 0; padding: 10px 16px; color: #1d1d1f; }
h1 { font-size: 1.3em; margin: 0 0 4px; }
#status { font-size: 1.05em; margin: 4px 0; }
#status b { font-size: 1.3em; }
#segments { font-size: 0.9em; color: #444; }
#connection { font-size: 0.85em; color: #8a5a00; }
#view { width: 100%; height: calc(100vh - 120px); min-height: 420px; }
</style></head><body>
<div id="script-errors" style="display:none;background:#fdd;border:1px solid #c00;padding:8px"></div>
<script>
window.addEventListener("error", function (event) {
  var banner = document.getElementById("script-errors");
  banner.style.display = "block";
  banner.textContent += "script error: " + event.message + "\\n";
});
</script>
<h1>Calibration motion: live view</h1>
<div id="status">samples <b id="samples">0</b> (marker seen <span id="visible">0</span>);
  segment <span id="segment">-</span>; t = <span id="time">-</span> s;
  <span id="run-status">connecting</span></div>
<div id="segments"></div>
<div id="connection"></div>
<div id="view"></div>
<script>/*PLOTLY*/</script>
<script>
var VOLUME = /*VOLUME*/null;
var sequence = 0, bySegment = {}, order = [], latest = null;
var colours = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#17becf"];
function column(points, k) { return points.map(function (p) { return p === null ? null : p[k]; }); }
function traces() {
  var data = [{type: "scatter3d", mode: "lines", name: "tracker volume (nominal)", hoverinfo: "skip",
               x: column(VOLUME, 0), y: column(VOLUME, 1), z: column(VOLUME, 2),
               line: {color: "#999", width: 2}}];
  order.forEach(function (label, k) {
    var p = bySegment[label];
    data.push({type: "scatter3d", mode: "markers", name: label + " (" + p.length + " seen)",
               x: column(p, 0), y: column(p, 1), z: column(p, 2),
               marker: {size: 2, color: colours[k % colours.length]}});
  });
  var now = latest && latest.marker_mm ? [latest.marker_mm] : [];
  data.push({type: "scatter3d", mode: "markers", name: "marker now",
             x: column(now, 0), y: column(now, 1), z: column(now, 2),
             marker: {size: 7, color: "#c8102e", symbol: "diamond"}});
  return data;
}
var layout = {margin: {l: 0, r: 0, t: 10, b: 0}, uirevision: "keep", legend: {itemsizing: "constant"},
              scene: {aspectmode: "data", xaxis: {title: {text: "x (mm)"}}, yaxis: {title: {text: "y (mm)"}},
                      zaxis: {title: {text: "z (mm)"}}}};
Plotly.newPlot("view", traces(), layout, {displaylogo: false, responsive: true});
function show(data) {
  data.frames.forEach(function (f) {
    if (!f.recorded || f.marker_mm === null) { return; }
    if (!(f.segment in bySegment)) { bySegment[f.segment] = []; order.push(f.segment); }
    bySegment[f.segment].push(f.marker_mm);
  });
  sequence = data.sequence;
  latest = data.latest;
  document.getElementById("samples").textContent = data.samples;
  document.getElementById("visible").textContent = data.visible;
  document.getElementById("run-status").textContent = data.status;
  if (latest) {
    document.getElementById("segment").textContent = latest.segment;
    document.getElementById("time").textContent = latest.t.toFixed(1);
  }
  document.getElementById("segments").textContent = Object.keys(data.per_segment).map(function (k) {
    return k + ": " + data.per_segment[k];
  }).join(", ");
  document.getElementById("connection").textContent =
    data.dropped ? data.dropped + " frames were dropped before this page saw them" : "";
  Plotly.react("view", traces(), layout);
}
var status = null;
function poll() {
  fetch("/data?since=" + sequence, {cache: "no-store"}).then(function (r) { return r.json(); })
    .then(function (data) {
      // redraw only what changed: a 3-D redraw is most of the page's work
      if (data.sequence !== sequence || data.status !== status) { show(data); }
      status = data.status;
      // once the run has ended and every frame is shown there is nothing more to fetch
      var ended = data.status !== "running" && data.status.indexOf("waiting") !== 0;
      if (!ended || data.sequence < data.latest_sequence) {
        setTimeout(poll, data.sequence < data.latest_sequence ? 50 : 500);
      }
    })
    .catch(function () {
      document.getElementById("run-status").textContent = "view disconnected (the acquisition has ended)";
      setTimeout(poll, 2000);
    });
}
poll();
</script>
</body></html>
"""
