"""The Galilean stage: turns renders (updates) into frames at the refresh rate.

The service drives one :class:`GalileanStage` per display::

    stage = GalileanStage(display, GalileanSettings(order=2))
    stage.update(render_with_motion(...), rendezvous=n)   # graft at refresh n
    out = stage.refresh()                                 # one displayed frame

Each :meth:`GalileanStage.refresh` (1) applies a pending head-motion update to every
galpixel's motion, (2) propagates the map one refresh (one-pass scatter, Poisson
flags, obscuration cache, expansion sweep) unless a global update replaces it, (3)
grafts every update whose rendezvous is this refresh, and (4) returns the displayed
window with flags and counters.  A render handed in after its rendezvous is refused
(never a late graft); an incomplete one is grafted and reported as an
``incomplete_update`` event.

**Order guard** (section 2.5's warning made a check): when updates carry control
points, each global update measures how well every order up to the configured one
predicted the new control points from the previous update; when a lower order did
better on average, the stage drops the higher derivatives (e.g. G(3) fed noisy,
numerically differentiated motion falls back to G(2)) and flags it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np

from service.base.errors import SettingsError
from service.display import DisplaySettings
from service.galilean.finish import finish
from service.galilean.fixed_point import (
    Z_EMPTY,
    FixedPoint,
    bit_budget,
    points_fixed,
    propagate_points,
)
from service.galilean.galpixmap import FIELDS, GalileanError, Galpixmap, build
from service.galilean.head_motion import apply_viewer_motion
from service.galilean.local_update import check_points, graft
from service.galilean.motion_field import RenderedUpdate
from service.galilean.poisson import EXPANSION_MODES
from service.galilean.poisson_table import TABLE_FROM, poisson_interiors
from service.galilean.propagate import STAT_NAMES, planes, scatter
from service.galilean.scatter_bands import (
    GATHER_RUN,
    batch_buffers,
    map_reach,
    reach_of,
    scatter_bands,
    scatter_bands_plain,
)
from service.galilean.show import debris_words, show_bands
from service.kernel_cache import kernel_ready
from service.render.scene import MotionState

#: Mean number of refreshes between changes of the map (grafts, head-motion
#: updates), or refreshes since the last one, from which a refresh records the
#: still galpixels the two maps share (:func:`scatter_bands`): recording costs
#: about a fifth of a refresh that cannot use it, and the first refresh after a
#: change never can.
STEADY_MIN = 3.0

#: Share of the map's galpixels that must be still (recorded by the first
#: recording refresh after a change) for a refresh to keep recording them: a
#: map in which (almost) every galpixel moves, as after a head turn, gains
#: nothing from the record, which cost such a G(2) refresh at 640x480 about
#: 0.6 ms of 8 (CPU time, loaded machine); a 90 % still map gains 1.2 ms from
#: it, so it pays from about a third still (0.25 leaves a margin).  Still
#: galpixels stay still and moving ones keep moving until the map changes, so
#: one count per change decides.
STILL_MIN = 0.25

#: Seconds between checks whether :func:`scatter_bands_plain` is in numba's cache
#: yet (a look at its index file, about 0.1 ms), while it is not.
PLAIN_CHECK_S = 1.0

#: Name of the thread that loads :func:`scatter_bands_plain` from numba's cache.
PLAIN_LOADER = "galilean-plain-loader"


def _signature(dispatcher: Any, args: tuple) -> tuple:
    """The numba types ``dispatcher(*args)`` is compiled for (its overloads' key)."""
    return tuple(dispatcher.typeof_pyval(a) for a in args)


@dataclass(frozen=True)
class GalileanSettings:
    """Settings of the Galilean stage.

    Attributes
    ----------
    order : int
        Galpixmap order n of G(n), 0..3 (2 recommended, section 2.5).
    n_prop, n_recog : int
        Rated propagation time and recognisability time in refreshes (bit budget).
    refresh_hz : float
        Refresh rate (converts head motion per second to per refresh).
    margin : int
        Out-of-view margin in pixels on every side (0: galpixels leaving the
        display are dropped).
    cache : bool
        Obscuration cache on or off.
    poisson : bool
        Poisson test and expansion sweep on or off.
    poisson_threshold : float
        ``|laplacian(depth)|`` above which a pixel is a source (depth units).
    neighbours : int
        Neighbours the expansion consults: 1 (left) to 4 (left, up, right, down).
    expansion : {"replicate", "average"}
    colour_motion : bool
        Carry colour derivatives dA, dB, dC, d2A.
    order_guard : bool
        Fall back to a lower order when it predicted the control points better.
    threads : int
        Threads a refresh may use (row bands of the scatter, the Poisson tests,
        the second pass with its display copy, and the head-motion update); 0,
        the default: numba's thread count; 1: serial.  With OpenMP threads that
        sleep while waiting (``OMP_WAIT_POLICY=PASSIVE``, which ``holo-service``
        and ``holo-bench`` set) two threads were 1.2-1.5x faster than one on this
        2-core machine when idle and no slower beside a busy render process; with
        spinning threads a busy neighbour made both 2.5x slower.
    hold : bool
        Hold the last render once it is past its use-by date (True, the default):
        a global update is propagated for at most its use-by (``n_prop``
        refreshes, or the update's own ``use_by`` when it gives one); after that,
        until the next global update, every refresh shows the last render (and
        the local updates grafted since) exactly as rendered: no propagation, no
        head-motion update (flag ``held``).  False: extrapolate on past the
        rating (benchmarks of the error past it).  Extrapolated for a second, a
        head turn shears objects into scattered fragments and a 1.4 renders/s
        demo melted every attacker into a smear (docs/galilean.md, "Holding past
        the use-by date").
    """

    order: int = 2
    n_prop: int = 16
    n_recog: int = 16
    refresh_hz: float = 60.0
    margin: int = 0
    cache: bool = False
    poisson: bool = True
    poisson_threshold: float = 0.02
    neighbours: int = 4
    expansion: str = "average"
    colour_motion: bool = True
    order_guard: bool = True
    threads: int = 0
    hold: bool = True

    def __post_init__(self) -> None:
        checks = {
            "order": self.order in (0, 1, 2, 3),
            "n_prop": isinstance(self.n_prop, int) and self.n_prop >= 4,
            "n_recog": isinstance(self.n_recog, int) and self.n_recog >= 1,
            "refresh_hz": np.isfinite(self.refresh_hz) and self.refresh_hz > 0,
            "margin": isinstance(self.margin, int) and 0 <= self.margin <= 4096,
            "poisson_threshold": bool(np.isfinite(self.poisson_threshold))
            and self.poisson_threshold >= 0,
            "neighbours": self.neighbours in (1, 2, 3, 4),
            "expansion": self.expansion in EXPANSION_MODES,
            "threads": isinstance(self.threads, int) and 0 <= self.threads <= 1024,
            "hold": isinstance(self.hold, bool),
        }
        for name, ok in checks.items():
            if not ok:
                raise SettingsError(
                    f"Galilean setting {name} is out of range: {getattr(self, name)!r}"
                )


@dataclass
class Refresh:
    """One displayed frame.

    Attributes
    ----------
    index : int
        Refresh number, from 0.
    colour : ndarray, shape (Z, R, C, 3), uint8
    depth : ndarray, shape (Z, R, C), float32
    debris : ndarray, shape (Z, R, C), bool
        Pixels showing debris (G(0) fallback) rather than a galpixel.
    flags : dict
        ``updated`` (a graft happened), ``age`` (refreshes since the last global
        update), ``past_rating`` (age > N_prop), ``use_by`` (the refreshes the
        last global update may be propagated), ``held`` (the picture is the last
        render as rendered, see ``GalileanSettings.hold``), ``order`` (order in
        use), ``order_fallback``, ``events`` (incomplete updates, late renders
        refused).
    stats : dict
        Kernel counters (see :data:`service.galilean.propagate.STAT_NAMES`) and ``ms``.
    """

    index: int
    colour: np.ndarray
    depth: np.ndarray
    debris: np.ndarray
    flags: dict
    stats: dict


@dataclass
class _Pending:
    buffer: Galpixmap
    rendezvous: int
    objects: tuple[int, ...] | None
    complete: bool
    unfinished: tuple[int, ...]
    points: np.ndarray | None = None
    point_derivs: np.ndarray | None = None
    viewer: MotionState | None = None
    use_by: int | None = None


@dataclass
class _Guard:
    """Running prediction errors of each order (exponentially averaged)."""

    errors: np.ndarray
    last: tuple | None = None
    seen: int = 0


class GalileanStage:
    """Propagates galpixmaps between renders; see the module notes."""

    def __init__(self, display: DisplaySettings, settings: GalileanSettings | None = None) -> None:
        self.display = display
        self.settings = s = settings or GalileanSettings()
        self.budget = bit_budget(max(display.cols, display.rows), s.n_prop, s.n_recog)
        self.fixed = FixedPoint.for_order(self.budget, s.order)
        m = s.margin
        self.shape = (display.zones, display.rows + 2 * m, display.cols + 2 * m)
        # each map in its own slot: a refresh streams all their planes at once
        new = lambda slot: Galpixmap.empty(s.order, self.fixed, self.shape,  # noqa: E731
                                           s.colour_motion, slot)
        self.map, self._spare = new(0), new(1)
        self.cache = (new(2), new(3)) if s.cache else None
        self._src = np.full(self.shape, -1, np.int32)
        #: placeholder outputs for a propagation whose display copy is skipped
        self._no_show = (np.empty(0, np.uint8), np.empty(0, np.float32), np.empty(0, np.bool_))
        self.index = 0
        self.age = 0
        self.order = s.order
        self._pending: list[_Pending] = []
        self._events: list[dict] = []
        self._viewer = MotionState()
        self._viewer_next: MotionState | None = None
        self._guard = _Guard(np.zeros(s.order + 1))
        self._started = False
        #: whether the picture is held (``hold``) until the next global update
        self._held = False
        #: the last render as it came (the last global update's buffer with the
        #: local updates grafted since) and the viewer motion in it; kept only
        #: with ``hold``: a held refresh shows it
        self._last: Galpixmap | None = None
        self._last_viewer = MotionState()
        #: refreshes the last global update may be propagated (its use-by date)
        self._use_by = s.n_prop
        #: refresh periods missed (not computed) since the last global update
        self._missed = 0
        #: rows a galpixel of ``self.map`` can move in one refresh (None: unknown)
        self._reach: int | None = None
        #: 1 where ``map`` and ``_spare`` hold the same static galpixel, and the
        #: plane the next refresh records that in (see :func:`scatter_bands`)
        self._same = (np.zeros(self._src.size, np.uint8), np.zeros(self._src.size, np.uint8))
        #: whether ``_same[0]`` holds what the last refresh recorded
        self._same_valid = False
        #: refreshes since ``map`` last changed otherwise than by a refresh, and
        #: their running mean over past changes (records ``same`` only if it pays)
        self._steady, self._steady_mean = 0, float(STEADY_MIN)
        #: share of still galpixels the last change's first record found (None: not yet)
        self._still: float | None = None
        #: the Poisson test of every galpixel of ``map``, computed before each expansion
        self._interior = np.zeros(self._src.size, np.uint8)
        #: whether the last refresh left enough debris for that table to pay
        #: (:data:`TABLE_FROM`): the banded scatter computes it when so
        self._table = True
        #: scratch of :func:`finish`'s bands: the debris flags the scatter left
        self._snap = np.zeros(self._src.size, np.uint8)
        #: id of a map -> (its field arrays, their :func:`planes`), see :meth:`_planes`
        self._plane_views: dict[int, tuple] = {}
        #: whether :func:`scatter_bands_plain` is loaded for the refresh's types (see
        #: :meth:`_plain_ready`), and when its cache was last checked (monotonic s)
        self._plain, self._plain_checked = False, float("-inf")
        #: the thread loading it from numba's cache, while it does
        self._plain_loader: threading.Thread | None = None
        #: the scatter kernels' batch buffers and the finish's fix-up scratch (the
        #: kernels allocate nothing: :meth:`_batch_buffers`, :meth:`_fix_columns`)
        self._batch: tuple | None = None
        self._columns: np.ndarray | None = None

    def _planes(self, gp: Galpixmap) -> tuple:
        """:func:`planes` of one of the stage's maps, built once per map and field set.

        Building the views took about 30 us a call, two calls a refresh; the maps'
        fields are written in place, so the views stay valid unless a field is
        replaced (then they are built again).
        """
        arrays = gp.arrays()
        kept = self._plane_views.get(id(gp))
        if kept is None or any(a is not b for a, b in zip(kept[0], arrays, strict=True)):
            kept = self._plane_views[id(gp)] = (arrays, planes(arrays))
        return kept[1]

    def _batch_buffers(self, bands: int) -> tuple:
        """:func:`batch_buffers` for ``bands`` bands, made once and kept."""
        if self._batch is None or self._batch[0].shape[0] != bands:
            self._batch = batch_buffers(bands, self.shape)
        return self._batch

    def _fix_columns(self, bands: int) -> np.ndarray:
        """:func:`finish`'s fix-up scratch, (bands, 2, W) int64, made once and kept."""
        if self._columns is None or self._columns.shape[0] != bands:
            self._columns = np.empty((bands, 2, self.shape[2]), np.int64)
        return self._columns

    def _plain_ready(self, args: tuple) -> bool:
        """Whether :func:`scatter_bands_plain` is loaded for ``args``' types.

        Until it is, a refresh that neither uses nor records the still galpixels
        runs :func:`scatter_bands` with both off: the same map, bit for bit, with
        the bookkeeping's tests at run time.  On a cold cache the plain kernel (27 s
        of CPU) thus compiles in the background phase, off the first frame's path
        (docs/compile-time.md).  Its cache is checked at most every
        :data:`PLAIN_CHECK_S`; once it holds the kernel, a thread of its own
        (:data:`PLAIN_LOADER`) loads it (25-30 ms of CPU, which inside a refresh
        was a hitch of 70-100 ms at load 5-8), and the stage switches to it at
        the first refresh after that thread ends.
        """
        if self._plain:
            return True
        loader = self._plain_loader
        if loader is not None:
            if not loader.is_alive():
                self._plain_loader = None
                self._plain = _signature(scatter_bands_plain, args) in scatter_bands_plain.overloads
                if not self._plain:  # it raised (on stderr): keep the banded kernel
                    self._plain_checked = float("inf")
            return self._plain
        now = time.monotonic()
        if now - self._plain_checked >= PLAIN_CHECK_S:
            self._plain_checked = now
            if kernel_ready(scatter_bands_plain, args):
                sig = _signature(scatter_bands_plain, args)
                if sig in scatter_bands_plain.overloads:  # this process has it already
                    self._plain = True
                else:  # load it from the cache (compile it if the cache went meanwhile)
                    self._plain_loader = threading.Thread(
                        target=scatter_bands_plain.compile, args=(sig,), name=PLAIN_LOADER,
                        daemon=True)
                    self._plain_loader.start()
        return self._plain

    def _map_changed(self) -> None:
        """Forget what is known of ``map`` (a graft or a motion update wrote it)."""
        self._reach = None
        self._same_valid = False
        self._still = None
        if self._started:  # the first graft ends no steady stretch
            self._steady_mean += 0.25 * (self._steady - self._steady_mean)
        self._steady = 0

    # ----------------------------------------------------------------- inputs
    def update(
        self,
        rendered: RenderedUpdate,
        rendezvous: int | None = None,
        objects: tuple[int, ...] | None = None,
        complete: bool = True,
        unfinished: tuple[int, ...] = (),
        use_by: int | None = None,
    ) -> bool:
        """Hand in a render to graft at refresh ``rendezvous`` (default: the next one).

        ``objects`` None is a global update (the map is replaced); a tuple makes it
        a local update of those objects (a Flinders Street buffer: pixels of other
        objects are debris).  A render of the display's size gets an empty margin
        (cache-only out-of-view buffering); a render of :func:`margin_display`'s
        size fills the margin too (full out-of-view buffering).  Returns False (and
        records an event) when the rendezvous has already passed: late renders are
        never grafted.  ``use_by`` (global updates): the refreshes after its graft
        for which the render may be propagated (its use-by date, seed 002 section
        4.1: sooner for an object that turns far, see
        :func:`~service.galilean.local_update.use_by_refreshes`; later only for
        motion known to be exact, such as the game's burst); None: ``n_prop``.
        """
        fr = rendered.frame
        shown = (self.display.zones, self.display.rows, self.display.cols)
        if fr.colour.shape[:3] not in (shown, self.shape):
            raise GalileanError(
                f"update colour has shape {fr.colour.shape}, display needs "
                f"{(*shown, 3)} (or {(*self.shape, 3)} with its margin)"
            )
        pad = self.settings.margin if fr.colour.shape[:3] == shown else 0
        buf, info = build(
            fr.colour,
            fr.depth,
            self.settings.order,
            self.fixed,
            rendered.derivatives,
            rendered.dcolour if self.settings.colour_motion else None,
            rendered.obj,
            pad,
        )
        if objects is not None:
            keep = np.isin(buf.obj, np.asarray(objects, np.int32))
            buf.debris[~keep] = 1
        if info["clamped"]:
            self._events.append({"kind": "motion_clamped", "count": info["clamped"]})
        return self.submit(
            buf,
            rendezvous,
            objects,
            complete,
            unfinished,
            rendered.points,
            rendered.point_derivs,
            rendered.viewer_motion,
            use_by,
        )

    def submit(
        self,
        buffer: Galpixmap,
        rendezvous: int | None = None,
        objects: tuple[int, ...] | None = None,
        complete: bool = True,
        unfinished: tuple[int, ...] = (),
        points: np.ndarray | None = None,
        point_derivs: np.ndarray | None = None,
        viewer: MotionState | None = None,
        use_by: int | None = None,
    ) -> bool:
        """Queue a galpixmap (e.g. a Flinders Street buffer) for grafting; see :meth:`update`.

        ``points``/``point_derivs`` feed the order guard; ``viewer`` is the viewer
        motion baked into the buffer's motion (None: the stage's current one);
        ``use_by`` as in :meth:`update`.  With ``hold`` the stage keeps ``buffer``
        as the last render (a held refresh shows it): do not write to it after.
        """
        check_points(points, point_derivs)
        if use_by is not None and not (isinstance(use_by, int) and use_by >= 0):
            raise GalileanError(f"use_by must be a number of refreshes >= 0, got {use_by!r}")
        if buffer.shape != self.shape or buffer.order != self.settings.order:
            raise GalileanError(
                f"buffer must be a G({self.settings.order}) map of shape "
                f"{self.shape}, got G({buffer.order}) {buffer.shape}"
            )
        when = self.index if rendezvous is None else int(rendezvous)
        if when < self.index:
            self._events.append({"kind": "late_refused", "rendezvous": when, "refresh": self.index})
            return False
        self._pending.append(
            _Pending(
                buffer,
                when,
                None if objects is None else tuple(objects),
                complete,
                tuple(unfinished),
                points,
                point_derivs,
                viewer,
                use_by,
            )
        )
        return True

    def viewer(self, motion: MotionState) -> None:
        """New viewer motion (viewer frame, per second) from the pose filter.

        At the next refresh every galpixel's motion gets the change from the
        viewer motion already in it (section 4.2's global update).
        """
        self._viewer_next = motion

    # ---------------------------------------------------------------- refresh
    def refresh(self, periods: int = 1) -> Refresh:
        """Produce the next displayed frame.

        ``periods``: refresh periods since the last refresh, more than 1 when the
        caller missed ticks (a busy machine).  The map is still propagated one
        refresh (motion is per refresh), but the missed periods count towards the
        render's use-by, so that a picture is held once the rated propagation
        time has passed on the clock, not only in refreshes computed.
        """
        if not (isinstance(periods, int) and periods >= 1):
            raise GalileanError(f"periods must be an integer >= 1, got {periods!r}")
        self._missed += periods - 1
        with self._thread_limit():
            return self._refresh()

    @contextmanager
    def _thread_limit(self) -> Iterator[None]:
        """Limit numba's threads to ``settings.threads`` (0: leave numba's count) for a block."""
        threads = self.settings.threads
        if not threads:
            yield
            return
        before = nb.get_num_threads()  # per calling thread in numba
        nb.set_num_threads(min(threads, nb.config.NUMBA_NUM_THREADS))
        try:
            yield
        finally:
            nb.set_num_threads(before)

    def _apply_viewer(self) -> int:
        """The global head-motion update: the new viewer motion into every galpixel."""
        changed, clamped = apply_viewer_motion(
            self.map,
            self.display,
            self.settings.margin,
            self._viewer,
            self._viewer_next,
            self.settings.refresh_hz,
        )
        if clamped:
            self._events.append({"kind": "motion_clamped", "count": clamped,
                                 "source": "viewer"})
        self._viewer, self._viewer_next = self._viewer_next, None
        self._map_changed()
        return changed

    def _refresh(self) -> Refresh:
        t0 = time.perf_counter()
        stats = dict.fromkeys(STAT_NAMES, 0)
        due = [p for p in self._pending if p.rendezvous == self.index]
        self._pending = [p for p in self._pending if p.rendezvous > self.index]
        global_due = any(p.objects is None for p in due)
        held = self._hold(global_due)
        if self._viewer_next is not None and not held:  # held: kept for the next render
            stats["viewer_updated"] = self._apply_viewer()
        z, r, c = self.display.zones, self.display.rows, self.display.cols
        shown = (
            np.empty((z, r, c, 3), np.uint8),
            np.empty((z, r, c), np.float32),
            np.empty((z, r, c), np.bool_),
        )
        propagate = self._started and not global_due and not held
        if propagate:
            stats.update(self._propagate(shown if not due else None))
            self.age += 1
            self._viewer = _advance_motion(self._viewer, 1.0 / self.settings.refresh_hz)
        elif held:
            self.age += 1
        for p in due:
            self._graft(p)
        if due or not propagate:
            self._show(shown)
        colour, depth, debris = shown
        events, self._events = self._events, []
        flags = {
            "updated": bool(due),
            "age": self.age,
            "past_rating": self.age > self.settings.n_prop,
            "use_by": self._use_by,
            "held": held,
            "order": self.order,
            "order_fallback": self.order < self.settings.order,
            "events": events,
        }
        stats["ms"] = (time.perf_counter() - t0) * 1e3
        out = Refresh(self.index, colour, depth, debris, flags, stats)
        self.index += 1
        return out

    def _hold(self, global_due: bool) -> bool:
        """Whether this refresh holds the last render: it is past its use-by, none is due.

        The refresh would show the last global update ``age + 1`` refreshes (and
        the periods missed since) after its graft, past its use-by (``n_prop`` or
        its own ``use_by``).  The first
        held refresh puts the last render back into the map as it came (with the
        local updates grafted since); the map then stays as it is (shown again each
        refresh, local grafts shown where they land) until the next global update.
        """
        if not self.settings.hold or not self._started or global_due:
            self._held = False
            return False
        if not self._held and self.age + self._missed >= self._use_by:
            if self._last is not None:  # None: local updates only, the map stays as it is
                self._restore_last()
            self._held = True
        return self._held

    def _restore_last(self) -> None:
        """Put the last render back into the map, as it came (the start of a hold)."""
        self._map_changed()
        for name, arr in zip(FIELDS, self._last.arrays(), strict=True):
            np.copyto(getattr(self.map, name), arr)
        if self.cache is not None:
            self.cache[0].debris.fill(1)
        if self.order < self.settings.order:
            _drop_orders(self.map, self.order)
        self._viewer = self._last_viewer

    def _show(self, shown: tuple) -> None:
        """Copy the displayed window of the map into ``shown`` (no expansion)."""
        show_bands(
            self._planes(self.map),
            self.shape,
            self.settings.margin,
            *(a.reshape(-1) for a in shown),
            2.0**-self.fixed.fz,
        )

    def _propagate(self, shown: tuple | None) -> dict:
        """One refresh of the whole map (both sweeps); fills ``shown`` unless None."""
        s = self.settings
        new = self._spare
        new.debris.fill(1)
        counters = np.zeros(len(STAT_NAMES), np.int64)
        if self.cache is not None:
            cold, cnew = self.cache
            cnew.debris.fill(1)
        else:
            cold = cnew = new
        # the Poisson threshold in fixed-point depth units
        thr = s.poisson_threshold * 2.0**self.fixed.fz if s.poisson else -1.0
        self._sweeps(new, cold, cnew, thr, counters, shown)
        self.map, self._spare = new, self.map
        if self.cache is not None:
            self.cache = (cnew, cold)
        return dict(zip(STAT_NAMES, counters.tolist(), strict=True))

    def _sweeps(
        self,
        new: Galpixmap,
        cold: Galpixmap,
        cnew: Galpixmap,
        thr: float,
        counters: np.ndarray,
        shown: tuple | None,
    ) -> None:
        """The kernels of one refresh, ``self.map`` into ``new`` (debris all set).

        ``cold``/``cnew`` are the old and new obscuration caches (``new`` twice
        when off), ``thr`` the Poisson threshold in fixed-point depth units (< 0:
        no expansion); ``counters`` (:data:`STAT_NAMES`) accumulate; ``shown`` is
        filled unless None.  Tests override this to run the reference kernels.
        """
        s = self.settings
        src = self._src.reshape(-1)
        old_p, new_p = self._planes(self.map), self._planes(new)
        threads = nb.get_num_threads()
        ncol = self.map.colour_planes
        # record which still galpixels the maps share only where that will be used:
        # a map that changes every refresh or two never gets to leave them in place
        record = (
            self.cache is None
            and max(self._steady, self._steady_mean) >= STEADY_MIN
            and (self._still is None or self._still >= STILL_MIN)
        )
        # the origins' Poisson tests all at once when many pixels are debris: the
        # banded scatter computes them, going by the last refresh (either way
        # gives the same result)
        table = thr >= 0 and self._table
        if self.cache is None:
            if self._reach is None:
                self._reach = map_reach(self.map.motion, self.fixed.fm)
            bands = max(1, min(threads, self.shape[1] // 8))
            band_stats = np.zeros((bands, 3), np.int64)
            reach = np.zeros((bands, 3), np.int64)
            args = (
                old_p,
                new_p,
                src,
                self.shape,
                self.order,
                self.fixed.fp,
                self.fixed.fm,
                ncol,
                s.poisson,
                self._reach,
                bands,
                band_stats,
                reach,
                *self._same,
                self._same_valid,
                record,
                self._interior,
                thr,
                table,
                GATHER_RUN,
                self._batch_buffers(bands),
            )
            # the bookkeeping compiled out when it is neither used nor recorded
            plain = not (record or self._same_valid) and self._plain_ready(args)
            (scatter_bands_plain if plain else scatter_bands)(*args)
            counters[:3] += band_stats.sum(axis=0)
            top = reach.max(axis=0)
            next_reach = reach_of(top[0], top[1], top[2], self.fixed.fm)
        else:
            scatter(old_p, new_p, self._planes(cold), self._planes(cnew), True, src, self.shape,
                    self.order, self.fixed.fp, self.fixed.fm, s.poisson, counters)
            next_reach = None
        fresh = counters[0] - counters[2] - counters[1]
        self._table = bool(src.size - fresh >= TABLE_FROM * src.size)
        if self.cache is not None:
            table = thr >= 0 and self._table
            if table:
                poisson_interiors(old_p[1], old_p[6], self.shape, thr, self._interior)
        # expansion, debris arm and display copy in row bands, each fixed up where
        # the band above changes what it saw (see finish)
        rows = self.shape[0] * self.shape[1]
        fbands = max(1, min(threads, rows // 8))
        out = self._no_show if shown is None else tuple(a.reshape(-1) for a in shown)
        finish(
            new_p,
            old_p,
            src,
            debris_words(new.debris),
            self.shape,
            new.motion.shape[0],
            new.zmotion.shape[0],
            ncol,
            thr,
            s.neighbours,
            EXPANSION_MODES[s.expansion],
            s.margin,
            *out,
            shown is not None,
            s.poisson,
            counters,
            self._same[1],
            self._interior,
            table,
            fbands,
            self._snap,
            np.zeros((fbands, 4), np.int64),
            self._fix_columns(fbands),
            2.0**-self.fixed.fz,
        )
        self._reach = next_reach
        self._same = self._same[::-1]
        self._same_valid = record
        if record and self._still is None:
            self._still = np.count_nonzero(self._same[0]) / self._same[0].size
        self._steady += 1

    def _graft(self, p: _Pending) -> None:
        self._map_changed()
        if p.objects is None:
            for name, arr in zip(FIELDS, p.buffer.arrays(), strict=True):
                np.copyto(getattr(self.map, name), arr)
            if self.cache is not None:
                self.cache[0].debris.fill(1)
            self._guard_update(p)
            self.age = self._missed = 0
            self._viewer = p.viewer or self._viewer
            self._use_by = self.settings.n_prop if p.use_by is None else p.use_by
            if self.settings.hold:
                self._last, self._last_viewer = p.buffer, self._viewer
        else:
            graft(self.map, p.buffer, p.objects)
            if self._last is not None and not self._held:
                graft(self._last, p.buffer, p.objects)
        if not p.complete:
            self._events.append(
                {
                    "kind": "incomplete_update",
                    "refresh": self.index,
                    "unfinished": list(p.unfinished),
                }
            )
        self._started = True
        if self.order < self.settings.order:
            _drop_orders(self.map, self.order)

    def new_scene(self) -> None:
        """A new scene: a discontinuity, nothing of the old one is carried on.

        The map is cleared (black, empty, all debris), updates still pending (renders
        of the old scene) are dropped, the order guard forgets, and the refreshes show
        the empty map without propagating until the next global update is grafted.
        Without it the old scene's galpixels would go on flying (extrapolated) until
        the new scene's first render lands.
        """
        self._map_changed()
        self._pending.clear()
        m = self.map
        m.colour.fill(0)
        m.depth.fill(Z_EMPTY)
        m.debris.fill(1)
        m.obj.fill(-1)
        if self.cache is not None:
            for c in self.cache:
                c.debris.fill(1)
        self._started = self._held = False
        self._last = None
        self.age = self._missed = 0
        self.reset_guard()

    def reset_guard(self) -> None:
        """Forget the order guard's history (call it when a new scene is loaded).

        The guard compares the control points of one update with the prediction
        from the previous one; across two scenes that comparison means nothing, and
        when the point counts differ it cannot be made at all.
        """
        self._guard = _Guard(np.zeros(self.settings.order + 1))
        self.order = self.settings.order

    def _guard_update(self, p: _Pending) -> None:
        """Order guard: score each order's prediction of the new control points."""
        if not self.settings.order_guard or p.points is None:
            return
        last = self._guard.last
        if last is not None and last[0].shape != p.points.shape:
            self.reset_guard()  # another scene: its points predict nothing of this one
        g = self._guard
        steps = self.age + 1  # the propagated refreshes plus this one
        if g.last is not None:
            errs = prediction_errors(
                g.last[0], g.last[1], p.points, steps, self.fixed, self.settings.order
            )
            g.errors = errs if g.seen == 0 else 0.8 * g.errors + 0.2 * errs
            g.seen += 1
            best = int(np.argmin(g.errors + 1e-9 * np.arange(g.errors.size)))
            self.order = (
                best
                if g.errors[best] < 0.8 * g.errors[self.settings.order]
                else self.settings.order
            )
        g.last = (p.points, p.point_derivs)


def _advance_motion(m: MotionState, dt: float) -> MotionState:
    """The viewer motion the map now holds, ``dt`` seconds on (velocities advanced).

    Without acceleration that is ``m`` itself (a new state, validated, cost about
    0.1 ms a refresh; the sums would differ from ``m`` at most in a zero's sign).
    """
    if not (m.acceleration.any() or m.angular_acceleration.any()):
        return m
    return MotionState(
        m.velocity + m.acceleration * dt,
        m.acceleration,
        m.angular_velocity + m.angular_acceleration * dt,
        m.angular_acceleration,
    )


def margin_display(display: DisplaySettings, margin: int) -> DisplaySettings:
    """The display grown by ``margin`` pixels on every side (same pixel size and zones).

    Render into it for full out-of-view buffering: the stage then holds what lies
    just outside the display, ready to slide in.
    """
    cols, rows = display.cols + 2 * margin, display.rows + 2 * margin
    return DisplaySettings(
        zones=display.zones,
        angle_deg=display.angle_deg,
        cols=cols,
        rows=rows,
        width=display.pixel_size * cols,
    )


def _drop_orders(gp: Galpixmap, order: int) -> None:
    """Zero the motion planes above ``order`` (a lower-order fallback)."""
    gp.motion[2 * order :] = 0
    gp.zmotion[order:] = 0


def prediction_errors(
    points: np.ndarray,
    derivs: np.ndarray,
    actual: np.ndarray,
    steps: int,
    fixed: FixedPoint,
    order: int,
) -> np.ndarray:
    """How far each order 0..``order`` would have displayed control points after ``steps``.

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Control points' display positions (px) at the earlier update.
    derivs : ndarray, shape (3, N, 2)
        Their velocity, acceleration, jerk per refresh^n.
    actual : ndarray, shape (N, 2)
        Their true positions ``steps`` refreshes later.
    steps : int
    fixed : FixedPoint
    order : int

    Returns
    -------
    ndarray, shape (order + 1,)
        Maximum distance in px per order.
    """
    out = np.zeros(order + 1)
    for n in range(order + 1):
        x, v, a, j = points_fixed(points, derivs, fixed, n)
        path = propagate_points(x, v, a, j, n, fixed.fp, fixed.fm, steps)
        shown = path[-1] / 2.0**fixed.fp
        out[n] = float(np.max(np.linalg.norm(shown - actual, axis=-1))) if len(actual) else 0.0
    return out
