"""Honest frames when renders stop: no galpixel shown past its use-by date (seed 002).

A stage starved of renders for 3 s of refreshes propagates the last render for its
use-by (``n_prop`` refreshes, or the render's own ``use_by``), then shows that render
exactly as it came, bit for bit, until the next one: head motion included.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_gal_stage import scene_update, stage

from service.base.errors import SettingsError
from service.galilean.galpixmap import GalileanError
from service.galilean.local_update import render_use_by
from service.galilean.stage import GalileanSettings
from service.render.scene import MotionState, Scene

HZ = 60.0
STARVED = int(3 * HZ)  # 3 s of refreshes without a render
#: a square at rest, one moving, one accelerating (rows, columns, depth, colour, v, a)
SQUARES = [
    (2, 6, 2, 6, 2.0, (40, 40, 200), (0.0, 0.0), (0.0, 0.0)),
    (8, 12, 4, 8, 1.0, (200, 0, 0), (0.4, 0.1), (0.0, 0.0)),
    (14, 18, 20, 24, 1.5, (0, 200, 0), (-0.2, 0.0), (0.01, -0.005)),
]


def _same(a, b) -> bool:
    return (np.array_equal(a.colour, b.colour) and np.array_equal(a.depth, b.depth)
            and np.array_equal(a.debris, b.debris))


def _starve(st, refreshes: int, viewer: MotionState | None = None) -> list:
    out = []
    for _ in range(refreshes):
        if viewer is not None:
            st.viewer(viewer)
        out.append(st.refresh())
    return out


@pytest.mark.parametrize("head", [False, True], ids=["still-head", "head-moving"])
def test_a_starved_stage_shows_the_last_render_once_it_is_past_its_use_by(head: bool):
    """3 s without a render: n_prop refreshes propagated, then the render itself, held."""
    st = stage(2, refresh_hz=HZ)
    free = stage(2, refresh_hz=HZ, hold=False)  # the same stage extrapolating on
    for s in (st, free):
        s.update(scene_update(SQUARES), 0)
    render = st.refresh()
    free.refresh()
    turn = MotionState(angular_velocity=[0.0, 0.4, 0.0]) if head else None
    frames, extrapolated = _starve(st, STARVED, turn), _starve(free, STARVED, turn)
    n = st.settings.n_prop
    for f, x in zip(frames, extrapolated, strict=True):
        age = f.flags["age"]
        assert f.flags["held"] == (age > n) and f.flags["use_by"] == n
        if age <= n:  # within the rating: what the stage always showed
            assert _same(f, x), f"refresh at age {age} differs from the extrapolation"
        else:  # past it: every pixel is the render's own, not an expired galpixel's
            assert _same(f, render), f"held refresh at age {age} is not the last render"
            assert not f.stats.get("viewer_updated")
    # the extrapolated squares did leave the render's places (the hold is not a no-op)
    assert not _same(extrapolated[-1], render)


def test_head_motion_at_the_end_of_the_use_by_does_not_extend_it():
    """A pose just before the use-by date moves the galpixels; one refresh later: held."""
    st = stage(2, refresh_hz=HZ)
    st.update(scene_update(SQUARES), 0)
    render = st.refresh()
    n = st.settings.n_prop
    _starve(st, n - 1)
    st.viewer(MotionState(velocity=[0.3, 0.0, 0.0]))
    last = st.refresh()  # age n: the head-motion update applied, still in date
    assert last.flags["age"] == n and not last.flags["held"] and last.stats["viewer_updated"]
    held = _starve(st, 5, MotionState(velocity=[0.3, 0.0, 0.0]))
    assert all(f.flags["held"] and _same(f, render) for f in held)


def test_the_next_render_ends_the_hold_and_head_motion_goes_on_from_it():
    st = stage(2, refresh_hz=HZ)
    st.update(scene_update(SQUARES), 0)
    st.refresh()
    assert _starve(st, 40)[-1].flags["held"]
    moved = [(r0, r1, c0 + 3, c1 + 3, d, col, v, a) for r0, r1, c0, c1, d, col, v, a in SQUARES]
    st.update(scene_update(moved), st.index)
    fresh = st.refresh()
    assert not fresh.flags["held"] and fresh.flags["updated"] and fresh.flags["age"] == 0
    st.viewer(MotionState(velocity=[0.5, 0.0, 0.0]))
    after = st.refresh()
    assert not after.flags["held"] and after.stats["viewer_updated"] > 0
    later = _starve(st, 3)
    assert not any(f.flags["held"] for f in later)
    assert not _same(later[-1], fresh)  # propagating again


def test_a_render_with_a_short_use_by_is_held_sooner():
    """An object that turns far labels its render with an early use-by date."""
    st = stage(2, refresh_hz=HZ)
    st.update(scene_update(SQUARES), 0, use_by=5)
    render = st.refresh()
    frames = _starve(st, 10)
    assert [f.flags["held"] for f in frames] == [False] * 5 + [True] * 5
    assert all(_same(f, render) for f in frames[5:])
    assert frames[0].flags["use_by"] == 5
    # a later render without one gets the rating again
    st.update(scene_update(SQUARES), st.index)
    st.refresh()
    assert [f.flags["held"] for f in _starve(st, 17)] == [False] * 16 + [True]


def test_a_long_use_by_carries_known_motion_past_the_rating():
    """The game's burst: motion known exact is propagated for as long as it says."""
    st = stage(2, refresh_hz=HZ)
    st.update(scene_update(SQUARES), 0, use_by=100)
    st.refresh()
    assert not any(f.flags["held"] for f in _starve(st, 100))
    assert st.refresh().flags["held"]


def test_a_local_update_while_held_is_shown_where_it_lands():
    """A Flinders Street buffer grafted during a hold: the held picture takes it as rendered."""
    st = stage(2, refresh_hz=HZ)
    st.update(scene_update(SQUARES), 0)
    render = st.refresh()
    _starve(st, 20)
    moved = list(SQUARES)
    moved[1] = (8, 12, 10, 14, 1.0, (200, 0, 0), (0.4, 0.1), (0.0, 0.0))
    st.update(scene_update(moved), st.index, objects=(1,))
    local = st.refresh()
    assert local.flags["held"] and local.flags["updated"]
    red = np.all(local.colour[0] == (200, 0, 0), axis=-1) & ~local.debris[0]
    assert red[8:12, 10:14].all() and red.sum() == 16  # the new render of object 1 only
    blue = np.all(render.colour[0] == (40, 40, 200), axis=-1)
    assert np.array_equal(blue, np.all(local.colour[0] == (40, 40, 200), axis=-1))
    assert all(_same(f, local) for f in _starve(st, 5))  # held as it now is


def test_a_local_update_before_the_hold_is_part_of_the_render_held():
    st = stage(2, refresh_hz=HZ)
    st.update(scene_update(SQUARES), 0)
    st.refresh()
    moved = list(SQUARES)
    moved[0] = (2, 6, 12, 16, 2.0, (40, 40, 200), (0.0, 0.0), (0.0, 0.0))
    st.update(scene_update(moved), st.index + 2, objects=(0,))
    held = _starve(st, 30)[-1]
    assert held.flags["held"]
    blue = np.all(held.colour[0] == (40, 40, 200), axis=-1) & ~held.debris[0]
    assert blue[2:6, 12:16].all() and blue.sum() == 16
    red = np.all(held.colour[0] == (200, 0, 0), axis=-1) & ~held.debris[0]
    assert red[8:12, 4:8].all() and red.sum() == 16  # object 1 as the global render put it


def test_without_hold_the_stage_extrapolates_past_the_rating():
    st = stage(2, refresh_hz=HZ, hold=False)
    st.update(scene_update(SQUARES), 0)
    st.refresh()
    frames = _starve(st, 30)
    assert not any(f.flags["held"] for f in frames) and frames[-1].flags["past_rating"]


def test_bad_hold_settings_are_refused():
    with pytest.raises(SettingsError, match="hold"):
        GalileanSettings(hold=1)
    st = stage(2)
    for bad in (-1, 2.5, "16"):
        with pytest.raises(GalileanError, match="use_by"):
            st.update(scene_update(SQUARES), 0, use_by=bad)


def _spinning(rad_per_s: float) -> Scene:
    from service.render.mesh import Mesh
    from service.render.scene import SceneObject

    still = SceneObject(Mesh.from_triangles(np.eye(3), [[0, 1, 2]]))
    spin = SceneObject(still.mesh, motion=MotionState(angular_velocity=[0.0, rad_per_s, 0.0]))
    return Scene([still, spin])


def test_a_render_is_used_by_the_refresh_before_an_object_turns_45_degrees():
    """Seed 002 section 4.1: past 45 degrees a turn's parabola breaks down."""
    fast = np.pi / 4 / (10.5 / HZ)  # 45 degrees in 10.5 refreshes
    assert render_use_by(_spinning(fast), HZ, 16) == 10
    assert render_use_by(_spinning(fast / 10), HZ, 16) == 16  # the rating comes first
    assert render_use_by(_spinning(0.0), HZ, 16) == 16
    head = MotionState(angular_velocity=[0.0, -fast, 0.0])  # the viewer turning too
    assert render_use_by(_spinning(0.0), HZ, 16, viewer=head) == 10
    assert render_use_by(_spinning(fast * 20), HZ, 16) == 0  # held from the first refresh


def test_missed_refresh_periods_count_towards_the_use_by():
    """A busy machine computes 1 refresh in 5 periods: held once 16 periods have passed."""
    st = stage(2, refresh_hz=HZ)
    st.update(scene_update(SQUARES), 0)
    render = st.refresh()
    frames = [st.refresh(periods=5) for _ in range(5)]
    assert [f.flags["held"] for f in frames] == [False] * 3 + [True] * 2  # at 15, 20 periods
    assert [f.flags["age"] for f in frames] == [1, 2, 3, 4, 5]  # refreshes computed
    assert all(_same(f, render) for f in frames[3:])
    st.update(scene_update(SQUARES), st.index)  # a render starts the count again
    st.refresh(periods=3)
    assert [f.flags["held"] for f in _starve(st, 16)] == [False] * 16
    for bad in (0, 1.5):
        with pytest.raises(GalileanError, match="periods"):
            st.refresh(periods=bad)
