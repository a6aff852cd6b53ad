"""Where the game's frames come from: the render service, or an in-process renderer.

Both backends take the same calls, so the game loop does not know which it has:

==================  ===================================================================
call                what it does
==================  ===================================================================
``start(scene)``    load the game's scene (inline) and the display settings
``update(records)`` per-object states (:func:`game.scene.object_states`)
``explode(seed)``   game over: the player's mesh in pieces that fly apart
                    (:func:`game.gameover.explosion_scene`)
``resume()``        a new game: renders follow the updates again
``frame(timeout)``  the newest frame not yet taken (a :class:`FrameView`) or None
``connected``       False while the service is unreachable (the loop shows
                    "reconnecting" and keeps trying)
``warming``         None, or the service's warm-up progress while it compiles
                    its kernels (the loop shows "waiting for the render service")
``background()``    the service's background compile once ready (``stats``'
                    ``compile``), or None
``compiling()``     why a measurement of renders/s should wait for it, or None
``close()``         stop threads / close sockets
==================  ===================================================================

:class:`ServiceBackend` talks to ``holo-service`` through :mod:`service.net.client`
(``docs/protocol.md``); :class:`LocalRenderer` runs the service's engine
(:class:`service.engine.engine.Engine`: the render and refresh threads, without
sockets) in this process, so the game also runs with no service (``--local``) and
shows the same frames for the same inputs.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from game.gameover import burst_records, explosion_scene
from game.scene import apply_states
from service.autostereogram.output import SirdOutput, warm_up_sird
from service.base.errors import ServiceError, SettingsError
from service.display import DisplaySettings
from service.engine.engine import Engine
from service.frame_settings import FrameSettings
from service.galilean import GalileanStage
from service.net.client import FrameSubscriber, PendingRequest, ServiceClient, WarmingUpError
from service.net.settings_wire import display_to_wire, render_to_wire
from service.render.scene import Scene

#: Seconds between the service backend's ``stats`` requests for level-of-detail notes.
LOD_POLL_S = 2.0
#: Seconds the service backend waits (across ticks, never within one) for a ``stats``
#: reply before it drops it.
LOD_REPLY_S = 5.0


@dataclass
class FrameView:
    """One displayed frame, whatever its source.

    Attributes
    ----------
    colour : ndarray, shape (Z, R, C, 3), uint8
    seq : int
        Frame counter of the source (gaps: frames dropped).
    render_id : int
        The render last grafted (-1 before the first).
    since_render : int
        Refreshes since that render.
    zone : int or None
        The zone the source's tracked viewer is in, if it knows.
    latency_ms : float or None
        From the input the shown render was made from (object states or head pose)
        to this frame.
    sird : ndarray, shape (R, C), uint8, or None
        The frame's autostereogram (of the viewer's zone, or the centre one).
    scene : int or None
        The version of the scene the frame was rendered from (the service's
        ``load_scene`` count; the local renderer's game count); None from a
        service older than the ``scene`` key.
    held : bool
        The frame holds the last render as it was: none came within its use-by
        date (the Galilean stage's rating), so nothing is extrapolated further.
    """

    colour: np.ndarray
    seq: int
    render_id: int
    since_render: int
    zone: int | None = None
    latency_ms: float | None = None
    sird: np.ndarray | None = None
    scene: int | None = None
    held: bool = False


def _lod_on(settings: FrameSettings) -> bool:
    """Level of detail is on (its notes are worth asking the service for)."""
    return settings.render.lod is not None and settings.render.lod.enabled


class LocalRenderer:
    """The render service's engine in this process: the game with no service (``--local``).

    An :class:`~service.engine.engine.Engine` renders (aimed at rendezvous, as the
    service's render thread does) and refreshes (the Galilean stage at the refresh
    rate, held frames, the scene-version guard) on two threads; this class gives
    the game's calls to it, as :class:`ServiceBackend` gives them to the service.

    Parameters
    ----------
    settings : FrameSettings
    max_update_hz : float
        At most this many renders a second (0: as fast as they go), as
        ``holo-service --max-update-hz``.
    """

    def __init__(self, settings: FrameSettings | None = None, max_update_hz: float = 0.0) -> None:
        self.settings = s = settings or FrameSettings()
        self.connected = True
        self.warming: dict | None = None
        self._cv = threading.Condition()
        self._latest: FrameView | None = None
        self._taken = -1
        self._scene: Scene | None = None
        self._records: list[dict] = []
        self._frozen = False
        self._reload = False
        #: the version of the scene loaded last: frames of older versions are not shown
        self.scene_version = 0
        #: frames not shown because they came from an older scene
        self.stale_frames = 0
        self._sird = _sird_output(s.display)
        #: set by the game while it shows the autostereogram: only then is one made
        self.sird_wanted = False
        self._lod_new: list[str] = []
        # the autostereogram is made here, only while it is shown: not an encoding
        engine_settings = replace(s, encodings=("colour",))
        self.engine = Engine.local(engine_settings, self._on_frame, max_update_hz=max_update_hz,
                                   log=self._on_note)

    @property
    def stage(self) -> GalileanStage | None:
        """The engine's Galilean stage (None before its first refresh)."""
        return self.engine.stage

    def start(self, scene: Scene) -> None:
        """Load the scene and start rendering and refreshing."""
        self._scene = scene
        self.load_scene(scene)
        if self._sird is not None:  # load the SIRD kernels now, not in the refresh thread
            warm_up_sird(self._sird.settings.method)
        self.engine.start()

    def load_scene(self, scene: Scene) -> None:
        """Load a scene; frames of the scenes before it are not shown from now on."""
        self.scene_version = self.engine.load_scene(scene)

    def update(self, records: list[dict]) -> None:
        """New object states as of now; the renders follow them."""
        if self._frozen:
            return
        self._records = records
        scene = apply_states(self._scene, records)
        if self._reload:  # a new game: its scene loaded with its objects in place
            self._reload = False
            self.load_scene(scene)
        else:
            self.engine.move(scene)

    def explode(self, seed: int = 0) -> None:
        """Game over: the player's mesh in pieces that fly apart (as the service shows it).

        :func:`game.gameover.explosion_scene` is loaded as a new scene; the renders
        follow its pieces until :meth:`resume`.
        """
        self._frozen = True
        self.load_scene(explosion_scene(self._scene, self._records, seed))

    def resume(self) -> None:
        """A new game: its scene is loaded with its first :meth:`update` (a new version)."""
        self._reload = self._reload or self._frozen
        self._frozen = False

    def compiling(self) -> str | None:
        """Always None: in process, kernels compile inside the first render that needs them."""
        return None

    def background(self) -> dict | None:
        """Always None: no background compile in process."""
        return None

    def lod_notes(self) -> list[str]:
        """Level-of-detail notes (a chain not built, a damaged cache) new since the last call.

        Each note is returned once, however many renders report it.
        """
        with self._cv:
            new, self._lod_new = self._lod_new, []
        return new

    def frame(self, timeout_s: float = 0.0) -> FrameView | None:
        """The newest refresh not yet taken, waiting up to ``timeout_s``."""
        with self._cv:
            self._cv.wait_for(
                lambda: self._latest is not None and self._latest.seq != self._taken, timeout_s
            )
            got = self._latest
            if got is None or got.seq == self._taken:
                return None
            self._taken = got.seq
        if got.scene < self.scene_version:
            self.stale_frames += 1  # the game before's (the explosion), or the scene before
            return None
        return got

    def close(self) -> None:
        """Stop both threads, and a level-of-detail build still running in its child."""
        self.engine.stop()

    def _on_note(self, note: str) -> None:
        """A level-of-detail note, new (the engine's scheduler says each once)."""
        with self._cv:
            self._lod_new.append(note)

    def _on_frame(self, r: Any, made: dict[str, Any], settings: Any) -> None:
        """The engine's refresh thread hands a frame: keep it as the newest."""
        sird = None
        if self._sird is not None and self.sird_wanted:
            sird = self._sird.frame(r.depth[r.depth.shape[0] // 2])
        view = FrameView(
            colour=r.colour.copy(),
            seq=r.index,
            render_id=made["render_id"],
            since_render=made["since_render"],
            zone=self.engine.st.state.viewer.zone,
            latency_ms=(time.monotonic_ns() - made["t_render_ns"]) / 1e6,
            sird=sird,
            scene=made["scene"],
            held=bool(r.flags["held"]),
        )
        with self._cv:
            self._latest = view
            self._cv.notify_all()


class ServiceBackend:
    """``holo-service`` through :mod:`service.net.client` (``docs/protocol.md``).

    Parameters
    ----------
    control : str
        The service's control address.
    frames : str or None
        Its frame stream address (None: the one ``hello`` names).
    devices : str or None
        A ``holo-devices`` PUB address the service should take the viewer's pose
        from.
    settings : FrameSettings
    timeout_s : float
        Reply deadline; short, so a dead service never stalls the game for long.
    shatter : bool
        Game over loads the player in flying pieces (a scene with another vertex
        count); False flings the whole objects through ``update_objects``.
    """

    def __init__(
        self,
        control: str,
        frames: str | None = None,
        devices: str | None = None,
        settings: FrameSettings | None = None,
        timeout_s: float = 0.5,
        shatter: bool = True,
    ) -> None:
        self.settings = settings or FrameSettings()
        self.devices = devices
        self.shatter = shatter
        self.client = ServiceClient(control, timeout_s=timeout_s, retries=0)
        self._frames_addr = frames
        self._make_sub = FrameSubscriber
        self.sub: Any = None
        self.connected = False
        #: the service's warm-up progress while it says "warming up", else None.
        self.warming: dict | None = None
        self._scene: Scene | None = None
        self._records: list[dict] = []
        self._frozen = False
        self._reload = False  # load the scene with the next update (a new game)
        self._next_try = 0.0
        self._idle = threading.Event()  # never set: paces frame() while unconnected
        self.session: str | None = None
        self.reconnects = 0
        #: the version of the scene loaded last (its ``load_scene`` reply's ``scene``;
        #: None from a service without it): frames of older versions are not shown
        self.scene_version: int | None = None
        #: frames not shown because they carried no (Z, R, C, 3) uint8 ``colour`` array:
        #: another client's ``set_display`` left ``colour`` out of the encodings
        self.unusable_frames = 0
        #: frames not shown because they came from an older scene
        self.stale_frames = 0
        self._lod_seen: set[str] = set()
        self._lod_next = 0.0
        #: seconds between ``stats`` requests for level-of-detail notes
        self.lod_poll_s = LOD_POLL_S
        #: seconds a ``stats`` reply may take before it is dropped
        self.lod_reply_s = LOD_REPLY_S
        self._stats: Any = None  # a service.net.client.PendingRequest once asked

    def start(self, scene: Scene) -> None:
        """Load the scene and settings (raises if the service is not there).

        A service that is warming up is not an error: ``warming`` says how far it is
        and the loop keeps trying.
        """
        self._scene = scene
        try:
            self._connect()
        except WarmingUpError as exc:
            self.warming, self.connected = exc.warmup, False

    def _connect(self) -> None:
        """Hello, then the display, scene and devices; not while the service warms up."""
        info = self.client.hello("holo-game")
        self.session = info["session"]
        if info.get("status", "ready") != "ready":
            self.warming = info.get("warmup") or {}
            self.connected = False
            return
        self.warming = None
        s = self.settings
        d = s.display
        self.client.set_display(
            **display_to_wire(d),
            **render_to_wire(s.render),
            galpixel_order=s.galpixel_order,
            refresh_hz=s.refresh_hz,
            encodings=["colour", "autostereogram"] if _sird_output(d) else ["colour"],
        )
        self.load_scene(apply_states(self._scene, self._records) if self._records else
                        self._scene)
        self._reload = False
        if self.devices:
            self.client.set_viewer(devices=self.devices)
        if self.sub is None:
            self.sub = self._make_sub(self._frames_addr or info["frames"])
        self.connected = True

    def _call(self, fn: Any, *args: Any) -> None:
        """Run a request; on failure mark the link down (the loop reconnects)."""
        if not self.connected:
            self._retry()
            return
        try:
            fn(*args)
        except ServiceError:
            self.connected = False
            self._next_try = time.monotonic() + 0.5

    def _retry(self) -> None:
        if time.monotonic() < self._next_try:
            return
        self._next_try = time.monotonic() + 0.5
        try:
            self._connect()
            self.reconnects += int(self.connected)
        except WarmingUpError as exc:  # it went back to warming up between two requests
            self.warming = exc.warmup
            self.connected = False
        except ServiceError:
            self.connected = False

    def _lost(self) -> None:
        """The service went away or restarted: reconnect at the next chance."""
        self.connected = False
        self._next_try = 0.0

    def update(self, records: list[dict]) -> None:
        """Send the object states (kept to resend after a reconnect)."""
        if self._frozen:
            return
        self._records = records
        if self._reload:  # a new game: its scene loaded with its objects in place
            self._reload = False
            self._call(self.load_scene, apply_states(self._scene, records))
        else:
            self._call(self.client.update_objects, records)

    def explode(self, seed: int = 0) -> None:
        """Fling the objects outward (:func:`game.gameover.burst_records`).

        With ``shatter`` the player's mesh is loaded in pieces that fly apart
        (:func:`game.gameover.explosion_scene`) instead.
        """
        self._frozen = True
        if self.shatter:
            self._call(self.load_scene, explosion_scene(self._scene, self._records, seed))
        else:
            self._call(self.client.update_objects, burst_records(self._records, seed))

    def load_scene(self, scene: Scene) -> None:
        """Load a scene; frames of the scenes before it are not shown from now on."""
        got = self.client.load_scene(scene=scene).get("scene")
        self.scene_version = got if isinstance(got, int) and not isinstance(got, bool) else None

    def resume(self) -> None:
        """A new game: updates go through again, and the game's scene is loaded again.

        The load goes with the new game's first :meth:`update`, its objects in place
        (a load before it would be rendered with the game before's positions).  It
        is a new scene version: :meth:`frame` shows no frame of the game over
        (shatter pieces, flung objects) from then on, only the new game's.
        """
        self._reload = self._reload or self._frozen
        self._frozen = False

    def background(self) -> dict | None:
        """The service's background compile (``stats``' ``compile``), or None.

        ``phase``, ``done`` and ``total`` jobs and ``priority`` (:mod:`service.readiness`).
        """
        try:
            bg = self.client.stats().get("compile")
        except (ServiceError, OSError):
            return None
        return bg if isinstance(bg, dict) else None

    def compiling(self) -> str | None:
        """Why a measurement of renders a second should wait (one line), else None.

        The service's background compile (:meth:`background`) while it competes for
        the CPU: at ``nice 10`` it still takes about a tenth of a busy core.  At
        ``idle`` priority (``SCHED_IDLE``) it runs only on CPU time nothing else
        wants, so it holds nothing back.
        """
        bg = self.background() or {}
        if bg.get("phase") != "compiling" or bg.get("priority") == "idle":
            return None
        return (f"the service compiles kernels in the background ({bg.get('done', 0)} of "
                f"{bg.get('total', '?')} jobs, {bg.get('priority', 'low priority')})")

    def lod_notes(self) -> list[str]:
        """Level-of-detail notes the service reported, new since the last call (each once).

        With level of detail on, the service's ``stats`` (its last render's
        ``lod.chains.notes``) are asked for every ``lod_poll_s`` seconds, without
        waiting: the request goes out on a socket of its own and its reply is
        picked up by a later call, once it is there (a zero-timeout poll), so a
        slow reply never stalls the game's tick.  A reply that takes more than
        ``lod_reply_s`` (:data:`LOD_REPLY_S`) is dropped (``stats_dropped``) and the next period
        asks again; an error reply is left to the frame stream to notice.
        """
        s, now = self.settings, time.monotonic()
        if not self.connected or not _lod_on(s):
            return []
        if self._stats is None:

            self._stats = PendingRequest(self.client.address, self.lod_reply_s)
        try:
            got = self._stats.poll()
        except ServiceError:
            got = None
        if not self._stats.waiting and now >= self._lod_next:
            self._lod_next = now + self.lod_poll_s
            self._stats.send("stats")
        if got is None:
            return []
        return new_notes((got.get("stats") or {}).get("lod"), self._lod_seen)

    @property
    def stats_dropped(self) -> int:
        """``stats`` replies dropped for coming later than :data:`LOD_REPLY_S`."""
        return 0 if self._stats is None else self._stats.dropped

    def frame(self, timeout_s: float = 0.0) -> FrameView | None:
        """The next frame from the stream, or None; a restarted service is reloaded.

        Unconnected (the service is away or warming up) it tries to connect, then
        waits out ``timeout_s``, so the loop keeps its pace instead of spinning.
        """
        if not self.connected:
            t0 = time.monotonic()
            self._retry()
            if not self.connected:
                self._idle.wait(max(0.0, timeout_s - (time.monotonic() - t0)))
            return None
        got = self.sub.next(max(timeout_s, 0.001))
        if not self.sub.alive:
            self._lost()
        if got is None:
            return None
        header, arrays = got
        if header.get("session") != self.session:
            self._lost()  # a restarted service: load the scene again
            return None
        scene = header.get("scene")
        if self.scene_version is not None and scene is not None and scene < self.scene_version:
            self.stale_frames += 1  # rendered (or refreshed) from a scene replaced since
            return None
        if not _shows_colour(arrays):
            self.unusable_frames += 1
            return None
        return _view(header, arrays)

    def close(self) -> None:
        """Close both sockets."""
        if self.sub is not None:
            self.sub.close()
        if self._stats is not None:
            self._stats.close()
        self.client.close()


def new_notes(lod: dict | None, seen: set[str]) -> list[str]:
    """The notes of a render's ``lod`` report (``chains.notes``) not in ``seen``; adds them."""
    notes = ((lod or {}).get("chains") or {}).get("notes") or ()
    new = list(dict.fromkeys(str(n) for n in notes if str(n) not in seen))
    seen.update(new)
    return new


def _sird_output(display: DisplaySettings) -> SirdOutput | None:
    """The local renderer's autostereograms (centre zone), None for a display too narrow."""
    try:
        return SirdOutput(display.cols, display.rows, display.width, "tiw")
    except SettingsError:
        return None


def _shows_colour(arrays: dict) -> bool:
    """Whether a frame has the colour array a game window draws: (Z, R, C, 3) uint8."""
    colour = arrays.get("colour")
    return (isinstance(colour, np.ndarray) and colour.dtype == np.uint8 and colour.ndim == 4
            and colour.shape[3] == 3)


def _view(header: dict, arrays: dict) -> FrameView:
    since = next((header[k] for k in ("pose_t_ns", "t_render_ns")
                  if type(header.get(k)) is int and header[k] > 0), None)
    latency = (header["t_ns"] - since) / 1e6 if since is not None else None
    return FrameView(
        colour=arrays["colour"],
        seq=int(header.get("seq", 0)),
        render_id=int(header.get("render_id", -1)),
        since_render=int(header.get("since_render", 0)),
        zone=header.get("zone"),
        latency_ms=latency,
        sird=arrays.get("autostereogram"),
        scene=header.get("scene"),
        held=header.get("held") is True,
    )
