import numpy as np
import pytest

from service.base.errors import SettingsError
from service.display import DisplaySettings
from service.galilean.fixed_point import Z_EMPTY, pixel_of, points_fixed, propagate_points
from service.galilean.galpixmap import GalileanError, build
from service.galilean.motion_field import RenderedUpdate
from service.galilean.poisson import poisson_map
from service.galilean.stage import GalileanSettings, GalileanStage
from service.render.frame import Frame
from service.render.scene import MotionState

R, C = 24, 32


def scene_update(objects, rows=R, cols=C):
    """objects: list of (r0, r1, c0, c1, depth, colour, velocity (vx, vy), acceleration)."""
    col = np.zeros((1, rows, cols, 3), np.uint8)
    dep = np.full((1, rows, cols), np.inf, np.float32)
    der = np.zeros((3, 3, 1, rows, cols), np.float32)
    obj = np.full((1, rows, cols), -1, np.int32)
    for i, (r0, r1, c0, c1, d, colour, v, a) in enumerate(objects):
        sl = (0, slice(r0, r1), slice(c0, c1))
        nearer = d < dep[sl]
        for k, val in enumerate(colour):
            col[sl + (k,)] = np.where(nearer, val, col[sl + (k,)])
        dep[sl] = np.where(nearer, d, dep[sl])
        obj[sl] = np.where(nearer, i, obj[sl])
        for k in range(2):
            der[(0, k) + sl] = np.where(nearer, v[k], der[(0, k) + sl])
            der[(1, k) + sl] = np.where(nearer, a[k], der[(1, k) + sl])
    return RenderedUpdate(Frame(col, dep), der, None, obj, MotionState())


def stage(order=2, **kw):
    disp = DisplaySettings(zones=1, cols=kw.pop("cols", C), rows=kw.pop("rows", R))
    return GalileanStage(disp, GalileanSettings(order=order, colour_motion=False, **kw))


def where(out, colour):
    ys, xs = np.nonzero(np.all(out.colour[0] == colour, axis=-1))
    return list(zip(ys.tolist(), xs.tolist(), strict=True))


def test_map_galpixel_moves_like_the_point_arithmetic():
    st = stage(2)
    st.update(scene_update([(5, 6, 4, 5, 1.0, (200, 0, 0), (0.7, 0.3), (0.05, 0.02))]), 0)
    fx = st.fixed
    x, v, a, j = points_fixed(np.array([[4.0, 5.0]]),
                              np.array([[[0.7, 0.3]], [[0.05, 0.02]], [[0.0, 0.0]]]), fx, 2)
    path = propagate_points(x, v, a, j, 2, fx.fp, fx.fm, 12)
    for k in range(13):
        out = st.refresh()
        px = [int(pixel_of(int(p), fx.fp)) for p in path[k, 0]]
        galpix = [(r, c) for r, c in where(out, (200, 0, 0)) if not out.debris[0, r, c]]
        assert galpix == [(px[1], px[0])]


@pytest.mark.parametrize("v, jump", [(1 / 16, 8), (-1 / 16, 9)])
def test_map_symmetric_rounding(v, jump):
    st = stage(1)
    st.update(scene_update([(5, 6, 10, 11, 1.0, (0, 250, 0), (v, 0.0), (0, 0))]), 0)
    cols = []
    for _ in range(12):
        out = st.refresh()
        cols.append([c for r, c in where(out, (0, 250, 0)) if not out.debris[0, r, c]][0])
    moved = [k for k in range(1, 12) if cols[k] != cols[k - 1]]
    assert moved == [jump]


@pytest.mark.parametrize("near_first", [True, False])
def test_clash_nearest_wins(near_first):
    a = (5, 6, 4, 5, 1.0, (255, 0, 0), (2.0, 0.0), (0, 0))  # lands on column 6
    b = (5, 6, 8, 9, 3.0, (0, 0, 255), (-2.0, 0.0), (0, 0))  # lands on column 6
    if not near_first:
        a, b = (*a[:4], 3.0, *a[5:]), (*b[:4], 1.0, *b[5:])
    st = stage(1)
    st.update(scene_update([a, b]), 0)
    st.refresh()
    out = st.refresh()
    winner = (255, 0, 0) if near_first else (0, 0, 255)
    assert out.colour[0, 5, 6].tolist() == list(winner)
    assert out.stats["clashes"] >= 1


def test_debris_left_behind_has_no_motion_and_never_overrides():
    st = stage(1)
    st.update(scene_update([(4, 8, 4, 8, 1.0, (90, 90, 90), (1.0, 0.0), (0, 0))]), 0)
    st.refresh()
    out = st.refresh()
    assert out.debris[0, 4:8, 4].all()  # trailing column: debris showing the old colour
    assert (out.colour[0, 4:8, 4] == 90).all()
    for _ in range(3):
        out = st.refresh()
    assert out.debris[0, 4:8, 4].all() and (out.colour[0, 4:8, 4] == 90).all()  # it stays put
    assert not out.debris[0, 4:8, 8:12].any()  # the galpixels moved on, debris never covered them


def test_galpixels_leaving_the_display_are_dropped_or_kept_in_the_margin():
    obj = [(10, 11, 28, 29, 1.0, (255, 255, 0), (2.0, 0.0), (-0.25, 0.0))]
    seen = {}
    for margin in (0, 8):
        st = stage(2, margin=margin)
        st.update(scene_update(obj), 0)
        cols = []
        for _ in range(17):
            out = st.refresh()
            cols.append([c for r, c in where(out, (255, 255, 0)) if not out.debris[0, r, c]])
        seen[margin] = cols
    assert seen[0][8] == [] and seen[0][16] == []  # dropped at the edge, gone for good
    assert seen[8][8] == [] and seen[8][16] != []  # out of view, then back by itself


def test_obscuration_cache_restores_uncovered_background():
    bg = (0, 24, 0, 32, 5.0, (0, 0, 200), (0.0, 0.0), (0, 0))
    near = (8, 14, 6, 12, 1.0, (250, 250, 250), (1.0, 0.0), (0, 0))
    wrong = {}
    for cache in (False, True):
        st = stage(1, cache=cache, poisson=False)
        st.update(scene_update([bg, near]), 0)
        for _ in range(9):
            out = st.refresh()
        # truth: the near square at columns 14..19, blue everywhere else
        truth = np.zeros((24, 32, 3), np.uint8)
        truth[:] = (0, 0, 200)
        truth[8:14, 14:20] = 250
        wrong[cache] = int(np.any(out.colour[0] != truth, axis=-1).sum())
    assert wrong[False] > 0
    assert wrong[True] < wrong[False]


def test_poisson_flags():
    yy, xx = np.mgrid[0:8, 0:8]
    plane = (2.0 + 0.1 * xx + 0.05 * yy).astype(np.float32)[None]
    deb = np.zeros((1, 8, 8), np.uint8)
    f = poisson_map(plane, deb, 1e-3)
    assert f[0, 1:-1, 1:-1].sum() == 0 and f[0, 0].all() and f[0, :, -1].all()
    step = plane.copy()
    step[0, :, 4:] += 1.0
    f = poisson_map(step, deb, 1e-3)
    assert f[0, 1:-1, 3:5].all() and f[0, 1:-1, 1:3].sum() == 0
    deb[0, 4, 4] = 1
    f = poisson_map(plane, deb, 1e-3)
    assert f[0, 4, 4] and f[0, 3, 4] and f[0, 4, 5] and not f[0, 2, 2]


def expanding(rows=R, cols=C, rate=0.12):
    """A plane filling the display, expanding about its centre, over a black empty background."""
    u = scene_update([(4, 20, 6, 26, 2.0, (180, 60, 20), (0, 0), (0, 0))])
    yy, xx = np.mgrid[0:rows, 0:cols]
    inside = np.isfinite(u.frame.depth[0])
    u.derivatives[0, 0, 0] = np.where(inside, rate * (xx - 15.5), 0)
    u.derivatives[0, 1, 0] = np.where(inside, rate * (yy - 11.5), 0)
    return u


def test_expansion_fills_holes_inside_an_expanding_surface():
    holes = {}
    for poisson in (False, True):
        st = stage(1, poisson=poisson, poisson_threshold=1e-3)
        st.update(expanding(), 0)
        for _ in range(3):
            out = st.refresh()
        inner = out.debris[0, 8:16, 10:22]
        holes[poisson] = int(inner.sum())
        if poisson:
            assert out.stats["expanded"] > 0
            assert out.colour[0, 8:16, 10:22].tolist() == [[[180, 60, 20]] * 12] * 8
    assert holes[False] > 0 and holes[True] == 0


def test_unobscured_pixels_are_not_expanded():
    bg = (0, 24, 0, 32, 5.0, (0, 0, 200), (0.0, 0.0), (0, 0))
    near = (8, 14, 6, 12, 1.0, (250, 250, 250), (2.0, 0.0), (0, 0))
    st = stage(1, poisson_threshold=1e-3)
    st.update(scene_update([bg, near]), 0)
    st.refresh()  # the update itself
    out = st.refresh()
    # the two columns the square uncovered keep its debris (white), not the background blue
    assert out.debris[0, 8:14, 6:8].all()
    assert (out.colour[0, 8:14, 6:8] == 250).all()


def test_past_rating_flag():
    st = stage(1, n_prop=4)
    st.update(scene_update([(5, 6, 4, 5, 1.0, (9, 9, 9), (0.1, 0.0), (0, 0))]), 0)
    flags = [st.refresh().flags["past_rating"] for _ in range(7)]
    assert flags == [False] * 5 + [True] * 2


def test_bad_motion_is_clamped_and_flagged():
    u = scene_update([(5, 9, 4, 9, 1.0, (9, 9, 9), (0.5, 0.0), (0, 0))])
    u.derivatives[0, 0, 0, 5, 4] = np.nan
    u.derivatives[0, 1, 0, 6, 4] = np.inf
    u.derivatives[0, 0, 0, 7, 4] = 1e12
    u.derivatives[1, 2, 0, 8, 4] = -np.inf
    st = stage(2)
    st.update(u, 0)
    out = st.refresh()
    events = [e for e in out.flags["events"] if e["kind"] == "motion_clamped"]
    assert events and events[0]["count"] == 4
    for _ in range(5):
        out = st.refresh()
    assert np.isfinite(out.depth[np.isfinite(out.depth)]).all()


def test_mismatched_shapes_raise_value_error_naming_the_field():
    u = scene_update([(5, 6, 4, 5, 1.0, (9, 9, 9), (0.1, 0.0), (0, 0))])
    st = stage(2)
    with pytest.raises(ValueError, match="derivatives"):
        st.update(RenderedUpdate(u.frame, u.derivatives[:, :, :, :-1], None, u.obj, MotionState()))
    with pytest.raises(GalileanError, match="obj"):
        build(u.frame.colour, u.frame.depth, 2, st.fixed, obj=np.zeros((1, 3, 3), np.int32))
    with pytest.raises(GalileanError, match="dcolour"):
        build(u.frame.colour, u.frame.depth, 2, st.fixed, dcolour=np.zeros((3, 1, R, C)))
    with pytest.raises(GalileanError, match="update colour"):
        stage(2, cols=16).update(u)
    # control points and their derivatives (the order guard's input) must agree
    pts = np.zeros((4, 2))
    for derivs, field in ((np.zeros((3, 5, 2)), "point_derivs"), (np.zeros((3, 4, 3)),
                                                                  "point_derivs")):
        bad = RenderedUpdate(u.frame, u.derivatives, None, u.obj, MotionState(), pts, derivs)
        with pytest.raises(GalileanError, match=field):
            st.update(bad)
    with pytest.raises(GalileanError, match="points"):
        st.update(RenderedUpdate(u.frame, u.derivatives, None, u.obj, MotionState(),
                                 np.zeros((4, 3)), np.zeros((3, 4, 3))))
    with pytest.raises(SettingsError, match="velocity must be 3 numbers"):
        MotionState(velocity=[1.0, 2.0])
    with pytest.raises(SettingsError, match="angular_velocity must be 3 numbers"):
        MotionState(angular_velocity=[[1.0, 2.0, 3.0], [0, 0, 0]])


def test_head_motion_adds_depth_dependent_motion():
    near = (4, 8, 4, 8, 1.0, (9, 9, 9), (0.0, 0.0), (0, 0))
    far = (12, 16, 4, 8, 4.0, (7, 7, 7), (0.0, 0.0), (0, 0))
    st = stage(2, refresh_hz=60.0)
    st.update(scene_update([near, far]), 0)
    st.refresh()
    st.viewer(MotionState(angular_velocity=[0.0, 0.6, 0.0]))
    st.refresh()
    vx = st.fixed.to_float(st.map.motion[0, 0])
    s = st.display.pixel_size
    expect_near, expect_far = 0.6 / 60 * 1.0 / s, 0.6 / 60 * 4.0 / s
    assert vx[5, 5] == pytest.approx(expect_near, abs=0.01)
    assert vx[13, 5] == pytest.approx(expect_far, abs=0.01)
    assert vx[0, 0] == 0.0  # empty (infinitely far) pixels untouched


def test_absurd_viewer_motion_is_clamped_and_flagged_never_wrapped():
    near = (4, 8, 4, 8, 1.0, (9, 9, 9), (0.0, 0.0), (0, 0))
    for v, a in (([0.0, 0.0, 1e30], [0.0, 0.0, 0.0]), ([0.0, 0.0, -1e30], [0.0, 0.0, 0.0]),
                 ([0.0, 0.0, 0.0], [0.0, -1e9, 0.0])):
        st = stage(2, refresh_hz=60.0)
        st.update(scene_update([near]), 0)
        st.refresh()
        st.viewer(MotionState(velocity=v, acceleration=a))
        out = st.refresh()
        events = [e for e in out.flags["events"] if e["kind"] == "motion_clamped"]
        assert events and events[0]["source"] == "viewer" and events[0]["count"] > 0
        live = (st.map.debris[0] == 0) & (st.map.depth[0] != Z_EMPTY)
        assert live.sum() > 4
        vel, acc = (st.fixed.to_float(st.map.motion[k:k + 2, 0][:, live]) for k in (0, 2))
        # velocity within v_max, acceleration within a_max (not v_max), nothing wrapped
        assert np.abs(vel).max() <= st.fixed.v_max and np.abs(acc).max() <= st.fixed.a_max
        if a[1]:
            assert np.abs(acc[1]).max() == pytest.approx(st.fixed.a_max)
        if v[2]:
            # a viewer receding fast along z: every galpixel's z motion saturates with
            # the sign of the motion, where int32 arithmetic would have wrapped it
            vz = st.map.zmotion[0, 0][live].astype(np.int64)
            assert (np.sign(vz) == np.sign(v[2])).all() and (np.abs(vz) > 2**30).all()
        assert np.isfinite(out.depth).any()


def test_full_out_of_view_buffering_brings_in_what_was_outside():
    from service.galilean.stage import margin_display
    disp = DisplaySettings(zones=1, cols=C, rows=R)
    big = margin_display(disp, 6)
    assert (big.cols, big.rows) == (C + 12, R + 12) and big.pixel_size == disp.pixel_size
    # an object just left of the display (in the margin) moving right into view
    u = scene_update([(10, 12, 1, 4, 1.0, (200, 100, 0), (1.0, 0.0), (0, 0))], R + 12, C + 12)
    st = stage(1, margin=6)
    st.update(u, 0)
    outs = [st.refresh() for _ in range(6)]
    assert where(outs[0], (200, 100, 0)) == []
    assert len(where(outs[5], (200, 100, 0))) > 0


def test_debris_keeps_the_colour_it_last_showed_not_the_spare_buffers():
    """Old debris stays debris with its last displayed colour (G(0) fallback), never
    whatever the spare buffer held from two refreshes before."""
    disp = DisplaySettings(zones=1, cols=8, rows=6)
    st = GalileanStage(disp, GalileanSettings(order=2, poisson=False))
    red = st.map.copy()
    red.colour[0] = 255.0
    red.depth[:] = 1 << st.fixed.fz  # 1.0 depth units
    red.debris[:] = 0
    red.obj[:] = 0
    assert st.submit(red, 0)
    st.refresh()
    st.refresh()  # the spare buffer now holds the red map
    blue = red.copy()
    blue.colour[:] = 0.0
    blue.colour[2] = 255.0
    blue.debris[0, 2, 3] = 1  # debris that shows blue
    assert st.submit(blue, 2)
    out = st.refresh()
    assert tuple(out.colour[0, 2, 3]) == (0, 0, 255) and out.debris[0, 2, 3]
    for _ in range(3):
        out = st.refresh()
        assert tuple(out.colour[0, 2, 3]) == (0, 0, 255) and out.debris[0, 2, 3]
