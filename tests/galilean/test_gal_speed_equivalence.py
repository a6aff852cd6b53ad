"""The optimised refresh gives bit-identical results to the straightforward one.

``ReferenceStage`` runs the kernels the stage used before the optimisation
(:func:`service.galilean.propagate.sweep` and
:func:`service.galilean.propagate.second_sweep`, kept unchanged as the reference);
both stages get the same random galpixmaps and must agree on every byte of every
displayed frame, of the counters and of every field of the maps they hold.
"""

import contextlib
from collections.abc import Iterator

import numpy as np
import pytest

from service.display import DisplaySettings
from service.galilean import stage as stage_module
from service.galilean.finish import finish
from service.galilean.fixed_point import Z_EMPTY
from service.galilean.galpixmap import Galpixmap, build
from service.galilean.poisson import EXPANSION_MODES, poisson_map
from service.galilean.poisson_table import poisson_interiors
from service.galilean.propagate import STAT_NAMES, planes, second_sweep, sweep
from service.galilean.scatter_bands import (
    GATHER_RUN,
    batch_buffers,
    map_reach,
    reach_of,
    scatter_bands,
    scatter_bands_plain,
)
from service.galilean.show import debris_words
from service.galilean.stage import GalileanSettings, GalileanStage
from service.render.scene import MotionState


class ReferenceStage(GalileanStage):
    """The stage with the pre-optimisation propagation (one-pass scan, then second sweep)."""

    def _show(self, shown: tuple) -> None:
        counters = np.zeros(len(STAT_NAMES), np.int64)
        with _contiguous(self.map) as (m,):
            self._show_kernel(m, shown, counters)

    def _show_kernel(self, m: tuple, shown: tuple, counters: np.ndarray) -> None:
        second_sweep(
            m,
            self._src,
            m[1],  # the same arrays as the tuple's depth and debris, as the stage passes
            m[6],
            -1.0,
            1,
            0,
            self.settings.margin,
            *shown,
            counters,
            2.0**-self.fixed.fz,
        )

    def _sweeps(self, new: Galpixmap, cold: Galpixmap, cnew: Galpixmap, *rest: object) -> None:
        """The stage's ``_sweeps`` (same arguments) on contiguous copies of the maps."""
        with _contiguous(self.map, new, cold, cnew) as (m, n, co, cn):
            self._sweep_kernels(m, n, co, cn, *rest)

    def _sweep_kernels(self, m: tuple, new: tuple, cold: tuple, cnew: tuple, thr: float,
                       counters: np.ndarray, shown: tuple | None) -> None:
        s = self.settings
        sweep(
            planes(m),
            planes(new),
            planes(cold),
            planes(cnew),
            self.cache is not None,
            self._src.reshape(-1),
            self.shape,
            self.order,
            self.fixed.fp,
            self.fixed.fm,
            s.poisson,
            counters,
        )
        if shown is None:
            z, r, c = self.display.zones, self.display.rows, self.display.cols
            shown = (
                np.empty((z, r, c, 3), np.uint8),
                np.empty((z, r, c), np.float32),
                np.empty((z, r, c), np.bool_),
            )
        second_sweep(
            new,
            self._src,
            m[1],
            m[6],
            thr,
            s.neighbours,
            EXPANSION_MODES[s.expansion],
            s.margin,
            *shown,
            counters,
            2.0**-self.fixed.fz,
        )


@contextlib.contextmanager
def _contiguous(*maps: Galpixmap) -> Iterator[list[tuple]]:
    """Each map's arrays as C-contiguous copies, written back into the map afterwards.

    A map's multi-plane fields are staggered views ('A' to numba) with 2 or more
    planes and contiguous ('C') with 0 or 1, which depends on the order and on colour
    motion; the reference kernels compiled once per combination (6 each, about 70 s
    of a fresh clone's test run).  Copies are 'C' whatever the map, so one compile
    serves all.  A map given twice (the stage passes ``new`` as both cache maps when
    the cache is off) gets one copy, so the kernels see the same aliasing.
    """
    copies = {id(gp): tuple(np.array(a, order="C") for a in gp.arrays())
              for gp in maps}
    yield [copies[id(gp)] for gp in maps]
    for gp in {id(g): g for g in maps}.values():
        for dst, src in zip(gp.arrays(), copies[id(gp)], strict=True):
            dst[...] = src


def random_map(stage: GalileanStage, rng: np.random.Generator, debris: float = 0.08) -> Galpixmap:
    """A random G(n) map of the stage's shape: ties, planes, edges, debris, fast movers."""
    s = stage.settings
    gp = Galpixmap.empty(s.order, stage.fixed, stage.shape, s.colour_motion)
    z, h, w = stage.shape
    gp.colour[:] = rng.uniform(-10, 265, gp.colour.shape)
    # depth: tilted planes per 8x8 block (Poisson interiors), quantised offsets (exact ties)
    rr, cc = np.mgrid[0:h, 0:w]
    tilt = 0.001 * rr + 0.002 * cc
    block = rng.integers(0, 6, (z, h // 8 + 1, w // 8 + 1)).astype(np.float64)
    depth = 1.0 + block[:, rr // 8, cc // 8] * 0.5 + tilt
    ties = rng.random(depth.shape) < 0.1
    depth[ties] = 2.0
    depth[rng.random(depth.shape) < 0.03] = np.inf
    gp.depth[:] = stage.fixed.depth_fixed(depth)[0]
    half = 1 << (stage.fixed.fp - 1)
    gp.frac[:] = rng.integers(-half, half, gp.frac.shape)
    unit = 1 << stage.fixed.fm
    m = rng.normal(0, 1.2 * unit, gp.motion.shape)
    fast = rng.random(gp.motion.shape) < 0.01
    m[fast] = rng.uniform(-40 * unit, 40 * unit, int(fast.sum()))
    gp.motion[:] = np.round(
        m / np.array([1, 1, 8, 8, 64, 64][: gp.motion.shape[0]]).reshape(-1, 1, 1, 1)
    ).astype(np.int32)
    gp.zmotion[:] = stage.fixed.zmotion_fixed(rng.normal(0, 0.01, gp.zmotion.shape))[0]
    gp.dcolour[:] = rng.normal(0, 1.0, gp.dcolour.shape)
    deb = rng.random(gp.debris.shape) < debris
    deb[:, h // 3 : h // 3 + 4, w // 4 : w // 2] = True  # a debris hole to expand into
    gp.debris[:] = deb
    gp.obj[:] = rng.integers(-1, 5, gp.obj.shape)
    return gp


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Byte-for-byte equality (NaN and -0.0 included)."""
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def assert_identical(fast: GalileanStage, ref: GalileanStage, k: int) -> None:
    a, b = fast.refresh(), ref.refresh()
    for name in ("colour", "depth", "debris"):
        assert same(getattr(a, name), getattr(b, name)), f"refresh {k}: displayed {name}"
    sa = {n: v for n, v in a.stats.items() if n != "ms"}
    sb = {n: v for n, v in b.stats.items() if n != "ms"}
    assert sa == sb, f"refresh {k}: stats"
    assert a.flags == b.flags
    maps = [(fast.map, ref.map, "map"), (fast._spare, ref._spare, "spare")]
    if fast.cache is not None:
        maps += [(fast.cache[0], ref.cache[0], "cache")]
    for x, y, what in maps:
        for name, u, v in zip(
            ("colour", "depth", "frac", "motion", "zmotion", "dcolour", "debris", "obj"),
            x.arrays(),
            y.arrays(),
            strict=True,
        ):
            assert same(u, v), f"refresh {k}: {what}.{name}"
    if fast.settings.poisson:
        assert same(fast._src, ref._src), f"refresh {k}: origins"


CASES = [
    dict(),
    dict(colour_motion=False),
    dict(expansion="replicate", neighbours=1),
    dict(neighbours=2, poisson_threshold=0.0),
    dict(poisson=False),
    dict(margin=5),
    dict(cache=True, margin=3),
]


@pytest.mark.parametrize("order", [0, 1, 2, 3])
@pytest.mark.parametrize("case", range(len(CASES)))
@pytest.mark.parametrize("table_from", [0.0, 2.0])
def test_fast_refresh_is_bit_identical(
    order: int, case: int, table_from: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Poisson tests from the parallel table always (0.0), or on the spot always (2.0)
    monkeypatch.setattr(stage_module, "TABLE_FROM", table_from)
    display = DisplaySettings(zones=2 if case == 0 else 1, cols=72, rows=40)
    gs = GalileanSettings(order=order, refresh_hz=50.0, **CASES[case])
    fast, ref = GalileanStage(display, gs), ReferenceStage(display, gs)
    rng = np.random.default_rng(100 * order + case)
    k = 0
    for step in range(3):
        gp = random_map(fast, rng)
        objects = None if step != 1 else (1, 2)  # a local update (Flinders Street buffer)
        for st in (fast, ref):
            assert st.submit(gp.copy(), st.index + (0 if step == 0 else 2), objects)
        if step == 2:
            vm = MotionState(velocity=[0.1, 0.0, 0.0], angular_velocity=[0.0, 0.3, 0.0])
            fast.viewer(vm)
            ref.viewer(vm)
        for _ in range(5):
            assert_identical(fast, ref, k)
            k += 1


def test_fast_refresh_is_bit_identical_at_page_sized_planes() -> None:
    """640 x 64 planes are a whole number of pages (the staggered-plane layout's case)."""
    display = DisplaySettings(zones=1, cols=640, rows=64)
    for order in (2, 3):
        gs = GalileanSettings(order=order)
        fast, ref = GalileanStage(display, gs), ReferenceStage(display, gs)
        gp = random_map(fast, np.random.default_rng(order), debris=0.02)
        for st in (fast, ref):
            st.submit(gp.copy(), 0)
        for k in range(4):
            assert_identical(fast, ref, k)


def _plane_lines(gp: Galpixmap) -> list[int]:
    """The cache line (modulo the 4 KiB page) each plane of ``gp`` starts on."""
    lines = []
    for a in gp.arrays():
        for plane in a.reshape(-1, *gp.shape) if a.ndim == 4 else [a]:
            lines.append(plane.ctypes.data % 4096 // 64)
    return lines


def test_stage_maps_planes_staggered_by_slot_not_by_history() -> None:
    """Every plane of a refresh's maps starts on its own cache line, whatever came before.

    The stagger comes from each map's slot (no module counter): the same stage
    built twice, with other maps made in between, has the same layout.
    """
    display = DisplaySettings(zones=1, cols=640, rows=64)  # page-sized planes
    for cache in (False, True):
        layouts = []
        for _ in range(2):
            st = GalileanStage(display, GalileanSettings(order=2, cache=cache))
            maps = [st.map, st._spare, *(st.cache or ())]
            lines = [x for gp in maps for x in _plane_lines(gp)]
            assert len(lines) == 18 * len(maps)  # G(2) with colour motion
            assert len(set(lines)) == min(len(lines), 64)  # 64 lines a page
            layouts.append(lines)
            Galpixmap.empty(3, st.fixed, st.shape)  # another map between the two stages
        assert layouts[0] == layouts[1]
    buf, _ = build(np.zeros((1, 64, 640, 3)), np.ones((1, 64, 640)), 2, st.fixed,
                np.zeros((3, 3, 1, 64, 640)), np.zeros((4, 1, 64, 640)))
    assert not set(_plane_lines(buf)) & set(_plane_lines(st.map) + _plane_lines(st._spare))


@pytest.mark.parametrize("order", [1, 2, 3])
def test_bands_scatter_like_one_band_whatever_the_band_count(order: int) -> None:
    """scatter_bands: any band count with a motion bound gives the one-band result.

    Its Poisson table (each band its own old rows, bands starting inside zones and
    at zone edges, one band per row) is :func:`poisson_interiors` of the old map;
    without ``table`` the table is left alone.
    """
    display = DisplaySettings(zones=2, cols=40, rows=30)
    st = GalileanStage(display, GalileanSettings(order=order))
    old = random_map(st, np.random.default_rng(7 + order))
    reach = map_reach(old.motion, st.fixed.fm)
    thr = 0.02 * 2.0**st.fixed.fz
    want = np.zeros(old.depth.size, np.uint8)
    poisson_interiors(old.depth.reshape(-1), old.debris.reshape(-1), st.shape, thr, want)
    assert 0 < want.sum() < want.size
    results = []
    cases = [(1, st.shape[1], True), (2, reach, True), (3, reach, False), (5, reach, True),
             (st.shape[1], reach, True)]
    for bands, r, table in cases:
        new = Galpixmap.empty(order, st.fixed, st.shape, True)
        src = np.full(new.depth.size, -7, np.int32)
        stats, out = np.zeros((bands, 3), np.int64), np.zeros((bands, 3), np.int64)
        interior = np.full(src.size, 7, np.uint8)
        scatter_bands(planes(old.arrays()), planes(new.arrays()), src, st.shape, order,
                      st.fixed.fp, st.fixed.fm, 4, True, r, bands, stats, out,
                      np.zeros(src.size, np.uint8), np.zeros(src.size, np.uint8), False, True,
                      interior, thr, table, GATHER_RUN, batch_buffers(bands, st.shape))
        assert same(interior, want) if table else (interior == 7).all()
        results.append((new, src, stats.sum(0), out.max(0)))
    first = results[0]
    for new, src, stats, top in results[1:]:
        for u, v in zip(new.arrays(), first[0].arrays(), strict=True):
            assert same(u, v)
        assert same(src, first[1]) and (stats == first[2]).all() and (top == first[3]).all()
    # the bound tracked for the next refresh is that of the motion written
    new = first[0]
    written = np.abs(new.motion[1::2][:, new.debris == 0].astype(np.int64)).max(axis=1)
    assert (first[3][:order] == written).all()
    assert reach_of(*first[3], st.fixed.fm) == map_reach(
        np.where(new.debris == 0, new.motion, 0), st.fixed.fm
    )


def test_serial_refresh_matches_the_parallel_one() -> None:
    """threads=1 (serial) and threads=0 (all of numba's threads) give the same refreshes."""
    display = DisplaySettings(zones=1, cols=64, rows=48)
    one, many = (GalileanStage(display, GalileanSettings(order=2, threads=t)) for t in (1, 0))
    gp = random_map(one, np.random.default_rng(11))
    for st in (one, many):
        st.submit(gp.copy(), 0)
    for k in range(6):
        if k == 3:  # a head-motion update (rows in parallel too)
            for st in (one, many):
                st.viewer(MotionState(velocity=[0.1, 0.0, 0.0], angular_velocity=[0.0, 0.4, 0.1]))
        a, b = one.refresh(), many.refresh()
        assert same(one.map.motion, many.map.motion), f"refresh {k}: motion"
        for name in ("colour", "depth", "debris"):
            assert same(getattr(a, name), getattr(b, name)), f"refresh {k}: {name}"
        assert {n: v for n, v in a.stats.items() if n != "ms"} == {
            n: v for n, v in b.stats.items() if n != "ms"
        }


def mostly_static_map(stage: GalileanStage, rng: np.random.Generator) -> Galpixmap:
    """A wall that does not move, crossed by movers landing on it from every side.

    Static galpixels have no motion, z motion or colour motion; some of them sit
    at a fraction of exactly +1/2 px (they move one pixel, then stay), some have
    colour motion only (they are not static).  Movers come from above and below
    (landing before and after the static pixel in scan order), nearer and
    farther than the wall.
    """
    gp = random_map(stage, rng, debris=0.02)
    z, h, w = stage.shape
    moving = np.zeros((z, h, w), bool)
    moving[:, h // 4 : h // 4 + 6, :] = True  # a band of movers across the map
    moving[:, :, w // 3 : w // 3 + 5] = True  # and a column of them
    moving |= rng.random(moving.shape) < 0.03
    still = ~moving
    gp.motion[:, still] = 0
    gp.zmotion[:, still] = 0
    gp.dcolour[:, still] = 0.0
    gp.colour[:] = np.abs(gp.colour) + 1.0  # no -0.0 (the one documented difference)
    half = 1 << (stage.fixed.fp - 1)
    gp.frac[0][still & (rng.random(still.shape) < 0.02)] = half
    glow = still & (rng.random(still.shape) < 0.02)
    if gp.dcolour.shape[0]:
        gp.dcolour[0][glow] = 0.5
    unit = 1 << stage.fixed.fm
    if gp.motion.shape[0]:  # movers cross rows: some land on the wall before its pixel
        gp.motion[1][moving] = rng.choice([-3 * unit, 2 * unit, 4 * unit], int(moving.sum()))
    return gp


@pytest.mark.parametrize("order", [0, 1, 2, 3])
@pytest.mark.parametrize(
    "case", [dict(), dict(colour_motion=False), dict(poisson=False), dict(margin=4)]
)
def test_static_galpixels_left_in_place_give_the_same_refreshes(order: int, case: dict) -> None:
    """Skipping the copy of static galpixels (scatter_bands' same_in) changes no byte.

    Ten refreshes after a global update, a local update grafted, then a head-motion
    update (both make the stage forget which pixels the two maps share: after the
    head-motion update the wall moves, and a stage that still took it as static
    would show it where it was).
    """
    _static_refreshes(DisplaySettings(zones=2, cols=56, rows=40), order, case, 40 + order)


@pytest.mark.parametrize("order", [2, 3])
def test_static_chunks_left_in_place_give_the_same_refreshes(order: int) -> None:
    """The z-test's chunks of still galpixels (32 at once), rows of an odd width.

    203 px rows: chunks start anywhere in a row and straddle rows; movers land on
    some chunks before their own galpixels do (those are taken one by one).
    """
    _static_refreshes(DisplaySettings(zones=1, cols=203, rows=48), order, {}, 60 + order)


def _static_pair(display: DisplaySettings, gs: GalileanSettings, seed: int) -> tuple:
    """A fast and a reference stage given the same mostly static map, and the generator."""
    fast, ref = GalileanStage(display, gs), ReferenceStage(display, gs)
    rng = np.random.default_rng(seed)
    gp = mostly_static_map(fast, rng)
    for st in (fast, ref):
        st.submit(gp.copy(), 0)
    return fast, ref, rng


def _static_refreshes(display: DisplaySettings, order: int, case: dict, seed: int) -> None:
    """The body of the two tests above: 24 refreshes of a mostly static map, compared."""
    fast, ref, rng = _static_pair(display, GalileanSettings(order=order, refresh_hz=50.0, **case),
                                  seed)
    skipped = []
    for k in range(24):
        if k == 10:
            part = mostly_static_map(fast, rng)
            for st in (fast, ref):
                assert st.submit(part.copy(), st.index, (1, 2))
        if k == 16:
            vm = MotionState(velocity=[0.05, 0.0, 0.0], angular_velocity=[0.0, 0.2, 0.0])
            fast.viewer(vm)
            ref.viewer(vm)
        assert_identical(fast, ref, k)
        skipped.append(int(fast._same[0].sum()) if fast._same_valid else 0)
    # skipped[k]: pixels refresh k + 1 may leave in place; none right after a graft
    assert skipped[0] == 0 and min(skipped[1:10]) > 0.5 * fast._src.size
    assert skipped[10] == 0 and skipped[11] > 0


@pytest.mark.parametrize("threshold", [0.0, 3.0, 1e9])
def test_poisson_interiors_are_the_poisson_test(threshold: float) -> None:
    """The parallel all-at-once Poisson test agrees with poisson_map pixel for pixel.

    Tilted planes (interiors), steps (sources), empty depths, debris, the border,
    and depths near the int32 limit, whose laplacian overflows 32 bits.
    """
    rng = np.random.default_rng(int(threshold) % 97)
    z, h, w = 2, 33, 47
    rr, cc = np.mgrid[0:h, 0:w]
    depth = (1000 + 3 * rr + 2 * cc + 500 * (cc > w // 2)).astype(np.int64)
    depth = np.broadcast_to(depth, (z, h, w)).copy()
    depth[rng.random(depth.shape) < 0.05] = Z_EMPTY
    depth[1, 5:9, 5:9] = 2**31 - 40  # near the top of int32, next to small depths
    depth[1, 20:24, 30:34] = 2**31 - 40 - rr[20:24, 30:34]
    depth = depth.astype(np.int32)
    debris = (rng.random((z, h, w)) < 0.04).astype(np.uint8)
    out = np.full(depth.size, 7, np.uint8)
    poisson_interiors(depth.reshape(-1), debris.reshape(-1), (z, h, w), threshold, out)
    want = 1 - poisson_map(depth, debris, threshold)
    assert (out.reshape(z, h, w) == want).all()
    assert out.sum() > 0 and (out == 0).sum() > 0


def test_still_galpixels_are_recorded_only_while_the_map_stays_steady() -> None:
    """Grafts every other refresh switch the recording off; a steady map switches it on.

    The refreshes stay byte for byte those of the reference throughout.
    """
    # no hold: its last refreshes are past n_prop after the last graft, and a held
    # map does not propagate
    fast, ref, rng = _static_pair(DisplaySettings(zones=1, cols=48, rows=32),
                                  GalileanSettings(order=2, refresh_hz=50.0, hold=False), 5)
    recorded = []
    for k in range(40):
        if 6 <= k < 24 and k % 2 == 0:
            nxt = mostly_static_map(fast, rng)
            for st in (fast, ref):
                assert st.submit(nxt.copy(), st.index)
        assert_identical(fast, ref, k)
        recorded.append(fast._same_valid)
    assert all(recorded[1:6])  # steady from the start
    assert not any(recorded[14:24])  # a graft every second refresh: not worth recording
    assert all(recorded[27:])  # steady again for three refreshes: recording again


def test_recording_stops_while_almost_every_galpixel_moves() -> None:
    """After a head turn (every galpixel moves) one refresh records, then none until a graft.

    The first refresh after the change measures the still share; under
    ``STILL_MIN`` the stage stops recording; a mostly still map grafted later is
    recorded again.  The refreshes stay byte for byte those of the reference.
    """
    fast, ref, rng = _static_pair(DisplaySettings(zones=1, cols=48, rows=32),
                                  GalileanSettings(order=2, refresh_hz=50.0), 9)
    recorded, still = [], []
    for k in range(28):
        if k == 8:
            vm = MotionState(velocity=[0.05, 0.0, 0.0], angular_velocity=[0.0, 0.2, 0.0])
            fast.viewer(vm)
            ref.viewer(vm)
        if k == 18:
            nxt = mostly_static_map(fast, rng)
            for st in (fast, ref):
                assert st.submit(nxt.copy(), st.index)
        assert_identical(fast, ref, k)
        recorded.append(fast._same_valid)
        still.append(fast._still)
    assert all(recorded[1:9]) and still[1] > stage_module.STILL_MIN  # steady, mostly still
    assert still[8] < stage_module.STILL_MIN  # measured once after the head turn
    assert not any(recorded[9:18])  # then not recorded while everything moves
    assert all(recorded[19:]) and still[19] > stage_module.STILL_MIN  # grafted: again


@pytest.mark.parametrize("table", [True, False])
def test_plain_scatter_is_the_banded_one_with_its_bookkeeping_off(table: bool) -> None:
    """scatter_bands with ``use_same`` and ``record`` False gives scatter_bands_plain's result.

    Bit for bit: the new map (pixels nothing lands on kept as they were), origins,
    counters, motion bounds and Poisson table, ``same_in`` not read and ``same_out``
    not written.  A stage runs it so until the plain kernel is cached (that one
    compiles in the background phase, off the first frame's path).  The stage's own
    maps, so both kernels see the types a refresh passes.
    """
    st = GalileanStage(DisplaySettings(zones=2, cols=40, rows=30), GalileanSettings(order=2))
    rng = np.random.default_rng(11)
    for dst, src in zip(st.map.arrays(), random_map(st, rng).arrays(), strict=True):
        dst[...] = src
    before = random_map(st, rng).arrays()
    reach, thr = map_reach(st.map.motion, st.fixed.fm), 0.02 * 2.0**st.fixed.fz
    n = st.map.depth.size
    same_in = rng.integers(0, 2, n).astype(np.uint8)  # not to be read
    results = []
    for kernel in (scatter_bands, scatter_bands_plain):
        for dst, src in zip(st._spare.arrays(), before, strict=True):
            dst[...] = src
        st._spare.debris.fill(1)
        origin, same_out = np.full(n, -7, np.int32), np.full(n, 7, np.uint8)
        stats, top, interior = np.zeros((3, 3), np.int64), np.zeros((3, 3), np.int64), np.full(
            n, 9, np.uint8)
        kernel(st._planes(st.map), st._planes(st._spare), origin, st.shape, 2, st.fixed.fp,
               st.fixed.fm, st.map.colour_planes, True, reach, 3, stats, top, same_in, same_out,
               False, False, interior, thr, table, GATHER_RUN, batch_buffers(3, st.shape))
        results.append([*(a.copy() for a in st._spare.arrays()), origin, same_out, stats, top,
                        interior])
    assert results[0][-3][:, 0].sum() > 0 and (results[0][-4] == 7).all()
    for u, v in zip(*results, strict=True):
        assert same(u, v)


def test_stage_without_the_plain_kernel_refreshes_alike(monkeypatch: pytest.MonkeyPatch) -> None:
    """Until scatter_bands_plain is cached the stage runs scatter_bands: the same refreshes.

    A head turn (every galpixel moves: the stage then neither uses nor records the
    still galpixels, where it would run the plain kernel), byte for byte those of
    the reference stage.
    """
    monkeypatch.setattr(stage_module, "kernel_ready", lambda kernel, args: False)
    fast, ref, _ = _static_pair(DisplaySettings(zones=1, cols=48, rows=32),
                                GalileanSettings(order=2, refresh_hz=50.0), 9)
    vm = MotionState(velocity=[0.05, 0.0, 0.0], angular_velocity=[0.0, 0.2, 0.0])
    plainless = []
    for k in range(16):
        if k == 4:
            fast.viewer(vm)
            ref.viewer(vm)
        assert_identical(fast, ref, k)
        plainless.append(not fast._same_valid)
    assert sum(plainless[6:]) >= 5 and not fast._plain  # where plain would have run


def _finish_input(order: int, rng: np.random.Generator) -> tuple:
    """A stage, an old map, and a new map after a scatter: strips and holes of debris.

    Two zones of an odd size (debris words straddle rows); a debris column down
    both zones (the expansion runs down it from row to row, so a band's fix-up
    runs the whole band), a hole crossing the middle rows, scattered debris.
    """
    display = DisplaySettings(zones=2, cols=37, rows=29)
    st = GalileanStage(display, GalileanSettings(order=order))
    old = random_map(st, rng, debris=0.1)
    new = random_map(st, rng, debris=0.15)
    z, h, w = st.shape
    new.debris[:, :, 5] = 1
    new.debris[:, :, 20:22] = 1
    new.debris[:, h // 2 - 3 : h // 2 + 4, 9:17] = 1
    new.debris[0, 0, :] = 1
    src = rng.integers(0, h * w, new.debris.size).astype(np.int32)
    src[rng.random(src.size) < 0.05] = -1
    src[new.debris.reshape(-1) == 1] = -9
    return st, old, new, src


@pytest.mark.parametrize("order", [0, 2, 3])
@pytest.mark.parametrize(
    "threshold, neighbours, mode, table, margin",
    [(3e6, 4, 1, True, 0), (3e6, 4, 0, False, 2), (3e6, 2, 1, False, 0), (0.0, 1, 0, True, 1),
     (-1.0, 4, 1, False, 0)],
)
def test_finish_in_bands_like_one_band(
    order: int, threshold: float, neighbours: int, mode: int, table: bool, margin: int
) -> None:
    """finish: any band count gives the one-band scan's maps, origins, counters and display.

    Bands start inside zones and at zone edges (1 to one band per row); the fix-up
    must redo whole bands down the debris columns.
    """
    rng = np.random.default_rng(3 + order)
    st, old, new, src = _finish_input(order, rng)
    z, h, w = st.shape
    interior = np.zeros(src.size, np.uint8)
    poisson_interiors(old.depth.reshape(-1), old.debris.reshape(-1), st.shape, max(threshold, 0),
                      interior)
    zs, hs, ws = z, h - 2 * margin, w - 2 * margin
    results = []
    for bands in (1, 2, 3, 5, 7, z * h):
        n, s = new.copy(), src.copy()
        shown = (np.zeros(zs * hs * ws * 3, np.uint8), np.zeros(zs * hs * ws, np.float32),
                 np.zeros(zs * hs * ws, np.bool_))
        stats, band_stats = np.zeros(7, np.int64), np.zeros((bands, 4), np.int64)
        same_out = np.ones(src.size, np.uint8)
        finish(planes(n.arrays()), planes(old.arrays()), s, debris_words(n.debris), st.shape,
               n.motion.shape[0], n.zmotion.shape[0], 4, threshold, neighbours, mode, margin,
               *shown, True, True, stats, same_out, interior, table, bands,
               np.zeros(src.size, np.uint8), band_stats, np.full((bands, 2, w), -5, np.int64), 0.5)
        results.append((n, s, stats, same_out, shown, band_stats))
    first = results[0]
    assert first[2][5] > 0 or threshold < 0
    for n, s, stats, same_out, shown, _ in results[1:]:
        for u, v in zip(n.arrays(), first[0].arrays(), strict=True):
            assert same(u, v)
        assert same(s, first[1]) and (stats == first[2]).all() and same(same_out, first[3])
        for u, v in zip(shown, first[4], strict=True):
            assert same(u, v)
    if threshold >= 0 and neighbours >= 2:  # the fix-ups ran down the debris columns
        assert results[1][5][1, 2] > h // 2


@pytest.mark.parametrize("order", [1, 2, 3])
@pytest.mark.parametrize("colour_motion", [True, False])
def test_scatter_copies_alike_by_runs_and_by_winners(order: int, colour_motion: bool) -> None:
    """scatter_bands' copy step: run by run, winner by winner, or mixed, the same bytes.

    200 px wide rows give 20-row batches, several per band; the top rows move
    alike (long runs), the rest at random (runs of one or two), so a threshold
    between switches the copy from one way to the other within a band.
    """
    display = DisplaySettings(zones=2, cols=200, rows=70)
    st = GalileanStage(display, GalileanSettings(order=order, colour_motion=colour_motion))
    old = random_map(st, np.random.default_rng(30 + order))
    old.motion[:, :, :30] = old.motion[:, :1, :1]  # one motion for the top rows: long runs
    old.frac[:, :, :30] = 0
    reach = map_reach(old.motion, st.fixed.fm)
    ncol = old.colour_planes
    results = []
    for bands in (1, 3):
        for gather_run in (0.0, 3.0, GATHER_RUN, np.inf):
            new = Galpixmap.empty(order, st.fixed, st.shape, colour_motion)
            src = np.full(new.depth.size, -7, np.int32)
            stats, top = np.zeros((bands, 3), np.int64), np.zeros((bands, 3), np.int64)
            scatter_bands(planes(old.arrays()), planes(new.arrays()), src, st.shape, order,
                          st.fixed.fp, st.fixed.fm, ncol, True, reach, bands, stats, top,
                          np.zeros(src.size, np.uint8), np.zeros(src.size, np.uint8), False,
                          False, np.zeros(src.size, np.uint8), -1.0, False, gather_run,
                          batch_buffers(bands, st.shape))
            results.append((new, src, stats.sum(0), top.max(0)))
    first = results[0]
    assert first[2][1] > 0  # clashes: pixels written twice, the later winner kept
    for new, src, stats, top in results[1:]:
        for u, v in zip(new.arrays(), first[0].arrays(), strict=True):
            assert same(u, v)
        assert same(src, first[1]) and (stats == first[2]).all() and (top == first[3]).all()
