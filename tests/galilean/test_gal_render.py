import numpy as np
import pytest
from gal_scenes import DISP, FLAT, HZ, box

from service.display import DisplaySettings
from service.galilean.fixed_point import Z_EMPTY, FixedPoint, bit_budget
from service.galilean.galpixmap import GalileanError
from service.galilean.local_update import (
    expired,
    graft,
    object_errors,
    priority,
    render_local,
    use_by_refreshes,
)
from service.galilean.motion_field import render_with_motion
from service.galilean.stage import GalileanSettings, GalileanStage, prediction_errors
from service.render.pipeline import Renderer
from service.render.scene import Scene
from service.scene_motion import advance_scene, control_points


def test_motion_field_matches_object_velocity():
    v = np.array([0.6, -0.3, 0.0])  # world units per second
    scene = Scene([box([0, 0, -0.5], velocity=v)], ambient=1.0)
    up = render_with_motion(Renderer(), scene, DISP, 0.0, HZ, FLAT)
    inside = up.obj[0] >= 0
    s = DISP.pixel_size
    assert inside.sum() > 50
    np.testing.assert_allclose(up.derivatives[0, 0, 0][inside], v[0] / HZ / s, rtol=1e-4)
    np.testing.assert_allclose(up.derivatives[0, 1, 0][inside], -v[1] / HZ / s, rtol=1e-4)
    assert np.abs(up.derivatives[1][:, 0][:, inside]).max() < 1e-6


def psnr(a, b):
    mse = np.mean((a.astype(float) - b.astype(float)) ** 2)
    return 99.0 if mse == 0 else 10 * np.log10(255**2 / mse)


def test_galilean_refreshes_beat_sample_and_hold_on_a_render():
    scene = Scene([box([-0.3, 0, -0.5], velocity=[1.2, 0.0, 0.0], angular_velocity=[0, 0.8, 0])],
                  ambient=1.0)
    r = Renderer()
    truth = [r.render(advance_scene(scene, k / HZ), DISP, FLAT).colour for k in range(5)]
    up = render_with_motion(r, scene, DISP, 0.0, HZ, FLAT)
    score = {}
    for order in (0, 2):
        st = GalileanStage(DISP, GalileanSettings(order=order, refresh_hz=HZ))
        st.update(up, 0)
        outs = [st.refresh().colour for _ in range(5)]
        assert (outs[0] == truth[0]).all()
        score[order] = np.mean([psnr(outs[k], truth[k]) for k in range(1, 5)])
    assert score[2] > score[0] + 3


def two_boxes():
    back = box([0.0, 0.0, -1.0], 0.8, (0.2, 0.2, 0.9), velocity=[0.3, 0, 0])
    front = box([0.1, 0.0, -0.2], 0.4, (0.9, 0.9, 0.1))
    return Scene([back, front], ambient=1.0)


def test_local_update_shadow_renders_obscurers_and_grafts():
    scene = two_boxes()
    fixed = FixedPoint.for_order(bit_budget(48, 16, 16), 2)
    st = GalileanStage(DISP, GalileanSettings(order=2, refresh_hz=HZ))
    st.update(render_with_motion(Renderer(), scene, DISP, 0.0, HZ, FLAT), 0)
    st.refresh()
    lr = render_local(Renderer(), scene, DISP, [0], 2 / HZ, HZ, 2, fixed, settings=FLAT,
                      control=control_points(scene, 2 / HZ, DISP))
    assert lr.finished == [0] and lr.unfinished == [] and lr.shadowed == [1]
    buf = lr.buffer
    front = buf.obj == 1
    assert front.any() and buf.debris[front].all()  # shadow: depth only, debris
    assert (buf.depth[front] != Z_EMPTY).all()
    assert not buf.debris[buf.obj == 0].any()
    assert st.submit(buf, 2, objects=[0])
    st.refresh()
    out = st.refresh()
    assert out.flags["updated"]
    truth = Renderer().render(advance_scene(scene, 2 / HZ), DISP, FLAT)
    # the front box still shows in front of the grafted back box
    front_colour = truth.colour[0][truth.depth[0] == truth.depth[0].min()][0]
    yellow = np.all(truth.colour[0] == front_colour, -1)
    assert (out.colour[0][yellow] == truth.colour[0][yellow]).mean() > 0.9


def test_missed_rendezvous_grafts_what_finished_and_reports_it():
    scene = two_boxes()
    fixed = FixedPoint.for_order(bit_budget(48, 16, 16), 2)
    ticks = iter([0.0, 0.0, 10.0, 20.0, 30.0])
    lr = render_local(Renderer(), scene, DISP, [1, 0], 1 / HZ, HZ, 2, fixed, budget_ms=5.0,
                      settings=FLAT, clock=lambda: float(next(ticks)))
    assert lr.finished == [1] and lr.unfinished == [0]
    st = GalileanStage(DISP, GalileanSettings(order=2, refresh_hz=HZ))
    st.update(render_with_motion(Renderer(), scene, DISP, 0.0, HZ, FLAT), 0)
    st.refresh()
    assert st.submit(lr.buffer, 1, objects=lr.finished, complete=False, unfinished=lr.unfinished)
    out = st.refresh()
    ev = [e for e in out.flags["events"] if e["kind"] == "incomplete_update"]
    assert ev == [{"kind": "incomplete_update", "refresh": 1, "unfinished": [0]}]
    # a render handed in after its rendezvous is refused, never grafted late
    assert not st.submit(lr.buffer, 1, objects=[0])
    out = st.refresh()
    assert [e["kind"] for e in out.flags["events"]] == ["late_refused"]
    assert not out.flags["updated"]


def test_graft_turns_stale_pixels_of_updated_objects_to_debris():
    fixed = FixedPoint.for_order(bit_budget(48, 16, 16), 1)
    from service.galilean.galpixmap import Galpixmap
    main = Galpixmap.empty(1, fixed, (1, 4, 4), False)
    main.debris[:] = 0
    main.obj[:] = 0
    main.obj[:, :, 3] = 1
    buf = Galpixmap.empty(1, fixed, (1, 4, 4), False)
    buf.debris[0, 0, 0] = 0
    buf.obj[0, 0, 0] = 0
    buf.colour[:, 0, 0, 0] = 77
    info = graft(main, buf, [0])
    assert info == {"grafted": 1, "stale": 11}
    assert main.colour[0, 0, 0, 0] == 77 and main.debris[0, :, 3].sum() == 0


def test_use_by_date_fires_past_45_degrees():
    w = np.radians(90.0)  # 90 degrees per second about a non-trivial axis
    scene = Scene([box([0, 0, -1], angular_velocity=[w, 0, 0]), box([0.5, 0, -1])])
    assert expired(scene, [0.49, 10.0]) == []
    assert expired(scene, [0.51, 10.0]) == [0]
    n = use_by_refreshes(scene, HZ)
    assert n[0] == 31 and n[1] == 100000


def test_error_estimate_orders_re_renders():
    fixed = FixedPoint.for_order(bit_budget(48, 16, 16), 2)
    pts = np.array([[10.0, 10.0], [20.0, 10.0], [30.0, 5.0]])
    der = np.zeros((3, 3, 2))
    der[0] = [[0.5, 0], [0.5, 0], [0.0, 0.1]]
    truth = pts + [[2.0, 0], [8.0, 0], [0.0, 0.4]]  # object 1 accelerated unexpectedly
    err = object_errors(pts, der, truth, np.array([0, 1, 2]), 4, fixed, 2, 3)
    np.testing.assert_allclose(err, [0.0, 6.0, 0.0], atol=0.15)
    assert priority(err, expired_objects=[2]) == [2, 1]
    owner = np.array([0, 1, 2])
    for args, field in (((pts, der[:, :2], truth, owner), "point_derivs"),
                        ((pts, der, truth[:2], owner), "truth"),
                        ((pts, der, truth, owner[:2]), "owner")):
        with pytest.raises(GalileanError, match=field):
            object_errors(*args, 4, fixed, 2, 3)


def test_order_guard_falls_back_from_noisy_g3():
    from service.bench.galilean_experiments import tracker_head_turn
    fixed = FixedPoint.for_order(bit_budget(1024, 16, 16), 3)
    exact, estimate = tracker_head_turn("raw", 200)
    errs = np.zeros(4)
    for t0 in range(8, 160, 8):
        pos, der = estimate(t0)
        errs += prediction_errors(pos, der, exact(t0 + 8)[0], 8, fixed, 3)
    assert errs[3] > errs[2]
    st = GalileanStage(DisplaySettings(zones=1, cols=8, rows=8),
                       GalileanSettings(order=3, colour_motion=False))
    from service.galilean.galpixmap import Galpixmap
    empty = Galpixmap.empty(3, st.fixed, st.shape, False)
    used = []
    for t0 in range(8, 160, 8):
        pos, der = estimate(t0)
        st.submit(empty, st.index, points=pos, point_derivs=der)
        flags = st.refresh().flags
        used.append(flags["order"])
        assert flags["order_fallback"] == (flags["order"] < 3)
        for _ in range(7):
            st.refresh()
    assert sum(o < 3 for o in used) >= 0.8 * len(used)


@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_all_orders_run_on_a_render(order):
    scene = Scene([box([0, 0, -0.5], velocity=[0.5, 0.2, 0.1], angular_velocity=[0, 1, 0])])
    up = render_with_motion(Renderer(), scene, DISP, 0.0, HZ, FLAT)
    st = GalileanStage(DISP, GalileanSettings(order=order, margin=4, cache=True))
    st.update(up, 0)
    for _ in range(4):
        out = st.refresh()
    assert out.colour.shape == (1, 32, 48, 3) and out.flags["order"] == order
