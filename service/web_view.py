"""A live view of a running render service in a web browser (``holo-view --web``).

One page, served by the standard library's HTTP server on loopback: the current
frame as an MJPEG stream (``/stream.mjpg``; layout ``zone``, ``strip``, ``quilt``,
``depth`` or ``autostereogram``), and ``/status.json`` (polled by the page twice a
second): whether the service is alive, refreshes/s and renders/s (plotted live by
the page), the service's ``stats``, the viewer pose (position, orientation and motion, from
an empty ``set_viewer``, which changes nothing) and the zone of the newest frame, and
the warm-up progress.  The page posts what it shows to ``/seen`` once a second (the
frame it drew, a checksum of its pixels and its status line), so the server can
count browsers watching (``viewers``) and tests can read what a real browser saw.

Pacing: frames come from a SUB socket with a high-water mark of 2 (a subscriber that
cannot keep up loses frames, the service never waits); each browser's stream sends
the newest frame when it is ready for one, at most ``max_fps`` a second, so a slow
browser gets fewer frames and slows nothing else.  Each frame is encoded once per
layout, however many browsers watch it.
"""

from __future__ import annotations

import io
import json
import os
import threading
import time
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qs, urlparse

import numpy as np

from service.autostereogram.output import SirdOutput
from service.base.errors import HoloError
from service.net import protocol
from service.net.client import FrameSubscriber, ServiceClient
from service.render.frame import default_grid, depth_grey, quilt, view_strip

#: The layouts a browser can ask for.
LAYOUTS = ("zone", "strip", "quilt", "depth", "autostereogram")
BOUNDARY = "holoframe"


@dataclass(frozen=True)
class WebSettings:
    """The web view's settings.

    Attributes
    ----------
    control, frames : str
        The service's control and frame stream addresses.
    host : str
        Where to listen (loopback by default).
    port : int
        0 picks a free port.
    max_fps : float
        Most frames a second per browser.
    quality : int
        JPEG quality, 1 to 100.
    """

    control: str = "tcp://127.0.0.1:5555"
    frames: str = "tcp://127.0.0.1:5556"
    host: str = "127.0.0.1"
    port: int = 8080
    max_fps: float = 30.0
    quality: int = 80


def encode_jpeg(rgb: np.ndarray, quality: int = 80) -> bytes:
    """An (R, C, 3) or (R, C) uint8 image as JPEG bytes (pygame's encoder)."""
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    # deferred: pygame (SDL) loads only where a window, pad or picture needs it
    import pygame

    if rgb.ndim == 2:
        rgb = np.repeat(rgb[:, :, None], 3, axis=2)
    surface = pygame.image.frombuffer(np.ascontiguousarray(rgb).tobytes(),
                                      (rgb.shape[1], rgb.shape[0]), "RGB")
    out = io.BytesIO()
    pygame.image.save(surface, out, "frame.jpg")
    del quality  # pygame-ce's save has no quality setting; kept for the API
    return out.getvalue()


def layout_image(arrays: dict[str, np.ndarray], header: dict, layout: str,
                 zone: int) -> np.ndarray | None:
    """The picture of a frame in ``layout``, (H, W, 3) or (H, W) uint8; None if it lacks it."""
    colour, depth = arrays.get("colour"), arrays.get("depth")
    z = min(max(zone, 0), colour.shape[0] - 1) if colour is not None else 0
    if layout == "zone":
        return None if colour is None else colour[z]
    if layout == "strip":
        return None if colour is None else view_strip(colour, sep=2, sep_value=40)
    if layout == "quilt":
        return None if colour is None else quilt(colour, *default_grid(colour.shape[0]))
    if layout == "depth":
        return None if depth is None else depth_grey(depth[min(z, depth.shape[0] - 1)])
    if "autostereogram" in arrays:  # the service's own (set_display encodings)
        return arrays["autostereogram"]
    if depth is None:
        return None
    rows, cols = depth.shape[1:]  # made here from the zone's depth, as the service would
    try:
        return SirdOutput(cols, rows, 2.0).frame(depth[z])
    except HoloError:  # a display too narrow for a stereogram
        return None


class Watcher:
    """The newest frame and the service's status, kept by two threads.

    Parameters
    ----------
    settings : WebSettings
    """

    def __init__(self, settings: WebSettings) -> None:
        self.settings = settings
        self.lock = threading.Condition()
        self.header: dict[str, Any] | None = None
        self.arrays: dict[str, np.ndarray] = {}
        self.frames = 0
        self.stats: dict[str, Any] | None = None
        self.stats_error = ""
        self.viewer: dict[str, Any] | None = None
        self.alive = False
        #: the frame stream's newest (status, warmup): heartbeats say so while warming up
        self.heartbeat: tuple[str | None, dict | None] = (None, None)
        self.seen: dict[str, Any] = {}
        self.viewers: dict[str, float] = {}
        self._cache: dict[tuple, bytes] = {}
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._frames, daemon=True),
                         threading.Thread(target=self._stats, daemon=True)]

    def start(self) -> None:
        """Start the frame and stats threads."""
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        """Stop both threads (they close their sockets)."""
        self._stop.set()
        with self.lock:
            self.lock.notify_all()
        for t in self._threads:
            t.join(5)

    def _frames(self) -> None:
        limit = protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS
        with FrameSubscriber(self.settings.frames) as sub:
            heard = -limit  # a message's arrival (a reconnect also resets last_heard)
            while not self._stop.is_set():
                before = (sub.last_heard, sub.reconnects)
                got = sub.latest(0.5)
                if sub.reconnects == before[1] and sub.last_heard != before[0]:
                    heard = sub.last_heard
                with self.lock:
                    self.alive = time.monotonic() - heard < limit
                    self.heartbeat = (sub.status, sub.warmup)
                    if got is not None:
                        self.header, self.arrays = got
                        self.frames += 1
                        self._cache.clear()
                        self.lock.notify_all()

    def _stats(self) -> None:
        client = ServiceClient(self.settings.control, timeout_s=1.0)
        try:
            while not self._stop.is_set():
                stats, error = self._ask(client.stats)
                viewer = None
                if stats is not None and stats.get("status") != "warming_up":
                    # set_viewer without a pose or devices changes nothing, and answers
                    # with the pose in use (docs/protocol.md 1.5)
                    viewer = (self._ask(client.set_viewer)[0] or {}).get("viewer")
                with self.lock:
                    self.stats, self.stats_error, self.viewer = stats, error, viewer
                self._stop.wait(1.0)
        finally:
            client.close()

    @staticmethod
    def _ask(request: Any) -> tuple[dict | None, str]:
        """A request's reply and "", or None (a warming-up service: its progress) and why."""
        try:
            return request(), ""
        except Exception as exc:  # noqa: BLE001 - any failure is "no reply"
            error = str(exc).splitlines()[0] if str(exc) else repr(exc)
            if getattr(exc, "warmup", None):  # warming up: no stats yet, but progress
                return {"status": "warming_up", "warmup": exc.warmup}, error
            return None, error

    def jpeg(self, layout: str, zone: int) -> tuple[int, bytes | None]:
        """The newest frame's number and its JPEG in ``layout`` (encoded once per frame)."""
        with self.lock:
            n, header, arrays = self.frames, self.header, self.arrays
            key = (n, layout, zone)
            if key in self._cache:
                return n, self._cache[key]
        if header is None:
            return n, None
        image = layout_image(arrays, header, layout, zone)
        data = None if image is None else encode_jpeg(image, self.settings.quality)
        with self.lock:
            if self.frames == n and data is not None:
                self._cache[key] = data
        return n, data

    def wait_newer(self, n: int, timeout_s: float) -> int:
        """Wait until a frame newer than ``n`` came (or the timeout); the newest number."""
        with self.lock:
            self.lock.wait_for(lambda: self.frames > n or self._stop.is_set(), timeout_s)
            return self.frames

    def status(self) -> dict[str, Any]:
        """What ``/status.json`` serves."""
        with self.lock:
            h, stats = self.header or {}, self.stats
            now = time.monotonic()
            viewers = sum(1 for t in self.viewers.values() if now - t < 3.0)
            beat_status, beat_warmup = self.heartbeat
            warming = beat_status == "warming_up" or (stats or {}).get("status") == "warming_up"
            return {
                # frames or heartbeats heard, or requests answered (a warming-up service
                # answers stats with its progress; its heartbeats may lag on a busy host)
                "alive": self.alive or stats is not None,
                "frames": self.frames, "seq": h.get("seq"), "zone": h.get("zone"),
                "zones": int(self.arrays["colour"].shape[0]) if "colour" in self.arrays else None,
                "held": h.get("held") is True, "viewer": self.viewer,
                "pose": {k: h.get(k) for k in ("pose_n", "pose_seq", "pose_t_ns")},
                "refreshes_per_s": (stats or {}).get("refreshes_per_s"),
                "updates_per_s": (stats or {}).get("updates_per_s"),
                "status": "warming_up" if warming else (stats or {}).get("status"),
                "warmup": (stats or {}).get("warmup") or beat_warmup,
                "stats": stats, "error": self.stats_error, "viewers": viewers,
                "layouts": list(LAYOUTS), "seen": self.seen,
            }


class _Handler(BaseHTTPRequestHandler):
    server: _Server

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - quiet
        pass

    def do_GET(self) -> None:  # noqa: N802 - the standard library's name
        url = urlparse(self.path)
        query = {k: v[-1] for k, v in parse_qs(url.query).items()}
        route = {"/": self._page, "/status.json": self._status, "/stream.mjpg": self._stream,
                 "/frame.jpg": self._frame}.get(url.path)
        if route is None:
            self.send_error(404, "no such page")
        else:
            route(query)

    def do_POST(self) -> None:  # noqa: N802
        if urlparse(self.path).path != "/seen":
            self.send_error(404, "no such page")
            return
        length = min(int(self.headers.get("Content-Length") or 0), 65536)
        try:
            seen = json.loads(self.rfile.read(length) or b"{}")
        except ValueError:
            self.send_error(400, "not JSON")
            return
        watcher = self.server.watcher
        with watcher.lock:
            watcher.seen = seen if isinstance(seen, dict) else {}
            watcher.viewers[str(watcher.seen.get("id", ""))] = time.monotonic()
        self._send(204, "text/plain", b"")

    def _send(self, code: int, kind: str, body: bytes) -> None:
        self.send_response(code)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _page(self, query: dict) -> None:
        self._send(200, "text/html; charset=utf-8", PAGE.encode())

    def _status(self, query: dict) -> None:
        self._send(200, "application/json", json.dumps(self.server.watcher.status()).encode())

    def _choice(self, query: dict) -> tuple[str, int]:
        layout = query.get("layout", "zone")
        try:
            zone = int(query.get("zone", "-1"))
        except ValueError:
            zone = -1
        if zone < 0:
            zone = int(self.server.watcher.status()["zone"] or 0)
        return (layout if layout in LAYOUTS else "zone"), zone

    def _frame(self, query: dict) -> None:
        _, data = self.server.watcher.jpeg(*self._choice(query))
        if data is None:
            self.send_error(503, "no frame yet")
        else:
            self._send(200, "image/jpeg", data)

    def _stream(self, query: dict) -> None:
        layout, zone = self._choice(query)
        watcher, gap = self.server.watcher, 1.0 / self.server.settings.max_fps
        self.send_response(200)
        self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY}")
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        shown = -1
        try:
            while not self.server.stopping.is_set():
                n = watcher.wait_newer(shown, 1.0)
                if n == shown:
                    continue
                shown, data = watcher.jpeg(layout, zone)
                if data is None:
                    continue
                self.wfile.write(f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
                                 f"Content-Length: {len(data)}\r\n\r\n".encode() + data + b"\r\n")
                self.wfile.flush()
                time.sleep(gap)  # the most frames a second a browser gets
        except (BrokenPipeError, ConnectionResetError):
            pass  # the browser went away


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, settings: WebSettings, watcher: Watcher) -> None:
        self.settings = settings
        self.watcher = watcher
        self.stopping = threading.Event()
        super().__init__((settings.host, settings.port), _Handler)


def serve(settings: WebSettings) -> tuple[_Server, Watcher]:
    """Start watching the service and serving the page (in threads); returns both.

    Call ``server.serve_forever()`` (or run it in a thread) and, to stop,
    ``server.stopping.set(); server.shutdown(); watcher.stop()``.

    Raises
    ------
    OSError
        When the port cannot be listened on.
    """
    watcher = Watcher(settings)
    server = _Server(settings, watcher)
    watcher.start()
    return server, watcher


PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><title>holo-view</title>
<style>
body{font-family:sans-serif;background:#111;color:#ddd;margin:12px}
#frame{max-width:100%;image-rendering:pixelated;border:1px solid #444;background:#000}
.row{display:flex;gap:16px;flex-wrap:wrap}
canvas.plot{background:#1b1b1b;border:1px solid #333}
#status.down{color:#f66;font-weight:bold}#status.up{color:#6f6}
pre{font-size:11px;max-height:300px;overflow:auto;background:#1b1b1b;padding:6px}
</style></head><body>
<h3>holo-view: <span id="status">connecting...</span></h3>
<div>layout <select id="layout"><option>zone</option><option>strip</option>
<option>quilt</option><option>depth</option><option>autostereogram</option></select>
zone <input id="zone" type="number" value="-1" min="-1" max="63" style="width:4em">
(-1: the viewer's) <span id="pose"></span></div>
<div class="row"><div><img id="frame" alt="frame"></div>
<div><div>refreshes/s <span id="rhz"></span></div>
<canvas class="plot" id="rplot" width="320" height="90"></canvas>
<div>renders/s <span id="uhz"></span></div>
<canvas class="plot" id="uplot" width="320" height="90"></canvas>
<div id="warm"></div></div></div>
<pre id="stats"></pre>
<script>
const id = Math.random().toString(36).slice(2);
const hist = {r: [], u: []};
let status = 'connecting', shown = -1;
function stream() {
  const l = document.getElementById('layout').value;
  const z = document.getElementById('zone').value;
  document.getElementById('frame').src = '/stream.mjpg?layout=' + l + '&zone=' + z +
    '&n=' + Date.now();
}
document.getElementById('layout').onchange = stream;
document.getElementById('zone').onchange = stream;
function plot(name, values) {
  const c = document.getElementById(name), g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height);
  const top = Math.max(1, ...values) * 1.1;
  g.strokeStyle = '#6cf'; g.beginPath();
  values.forEach((v, i) => {
    const x = i * c.width / 120, y = c.height - v / top * c.height;
    i ? g.lineTo(x, y) : g.moveTo(x, y);
  });
  g.stroke(); g.fillStyle = '#888'; g.fillText(top.toFixed(0), 2, 10);
}
function checksum() {
  const img = document.getElementById('frame');
  if (!img.naturalWidth) return null;
  const c = document.createElement('canvas');
  c.width = Math.min(img.naturalWidth, 256); c.height = Math.min(img.naturalHeight, 256);
  const g = c.getContext('2d'); g.drawImage(img, 0, 0, c.width, c.height);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let s = 0; for (let i = 0; i < d.length; i += 7) s = (s * 31 + d[i]) >>> 0;
  return s;
}
async function poll() {
  try {
    const s = await (await fetch('/status.json', {cache: 'no-store'})).json();
    const el = document.getElementById('status');
    if (!s.alive) { status = 'service stopped (no frames or replies)'; el.className = 'down'; }
    else if (s.status === 'warming_up') {
      const w = s.warmup || {};
      status = 'warming up ' + (w.done ?? '?') + '/' + (w.total ?? '?'); el.className = 'up';
    } else { status = 'live' + (s.held ? ' (held: renders late)' : ''); el.className = 'up'; }
    el.textContent = status;
    hist.r.push(s.refreshes_per_s || 0); hist.u.push(s.updates_per_s || 0);
    hist.r = hist.r.slice(-120); hist.u = hist.u.slice(-120);
    plot('rplot', hist.r); plot('uplot', hist.u);
    document.getElementById('rhz').textContent = (s.refreshes_per_s || 0).toFixed(1);
    document.getElementById('uhz').textContent = (s.updates_per_s || 0).toFixed(1);
    document.getElementById('pose').textContent = 'frame ' + s.seq + ', zone ' + s.zone +
      ' of ' + s.zones + (s.viewer && s.viewer.position ? ', viewer at ' +
      JSON.stringify(s.viewer.position) + ' facing ' + JSON.stringify(s.viewer.orientation)
      : ', no viewer pose (straight on)');
    document.getElementById('warm').textContent = s.warmup ?
      'warm-up: ' + JSON.stringify(s.warmup) : '';
    document.getElementById('stats').textContent = JSON.stringify(s.stats, null, 1);
    shown = s.frames;
  } catch (e) {
    status = 'web view unreachable'; document.getElementById('status').textContent = status;
    document.getElementById('status').className = 'down';
  }
}
async function report() {
  try {
    await fetch('/seen', {method: 'POST', body: JSON.stringify(
      {id: id, status: status, frames: shown, checksum: checksum(),
       width: document.getElementById('frame').naturalWidth})});
  } catch (e) {}
}
stream(); poll(); setInterval(poll, 500); setInterval(report, 1000);
</script></body></html>
"""
