"""``update_objects`` with ``acceleration``: the rendered object moves quadratically in time."""

from __future__ import annotations

import time

import numpy as np

from service.net.client import ServiceClient

COLS, ROWS, WIDTH = 64, 48, 2.0
PX = COLS / WIDTH  # pixels per world unit (one zone at angle 0: x maps linearly)
ACCEL = 0.6  # world units / s^2 along x


def _quad() -> dict:
    """A 0.2 x 0.2 square facing the viewer, both windings (never culled)."""
    v = np.array([[-0.1, -0.1, 0], [0.1, -0.1, 0], [0.1, 0.1, 0], [-0.1, 0.1, 0]], np.float32)
    t = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]], np.int32)
    return {
        "name": "box",
        "mesh": {"vertices": v, "triangles": t},
        "material": {"colour": [1.0, 1.0, 1.0]},
        "position": [-0.6, 0.0, -0.1],
    }


def _centre_x(depth: np.ndarray) -> float:
    """Mean column of the object's pixels in zone 0 (world units)."""
    cols = np.nonzero(np.isfinite(depth[0]))[1]
    assert cols.size > 0, "the object left the display"
    return (cols.mean() + 0.5) / PX - WIDTH / 2


def test_accelerating_object_moves_quadratically(service_factory):
    svc = service_factory(
        "--zones", "1", "--angle", "0", "--size", f"{COLS}x{ROWS}",
        "--workers", "0", "--refresh", "30",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=20) as c:
        c.load_scene(scene={"objects": [_quad()], "lights": [], "ambient": 1.0})
        header, arrays = c.render_once()
        x_rest = _centre_x(arrays["depth"])
        assert abs(x_rest - -0.6) < 1.5 / PX, x_rest
        t_before = time.monotonic_ns()
        c.update_objects(
            [{"name": "box", "position": [-0.6, 0.0, -0.1], "acceleration": [ACCEL, 0, 0]}]
        )
        t_after = time.monotonic_ns()
        t0 = (t_before + t_after) / 2e9
        samples = []
        while time.monotonic_ns() / 1e9 - t0 < 1.5:
            header, arrays = c.render_once()
            samples.append((header["t_ns"] / 1e9 - t0, _centre_x(arrays["depth"])))
    t, x = np.array(samples).T
    assert len(t) >= 8 and t.max() > 1.2, f"too few renders: {len(t)}"
    # A render's scene time is the refresh it is aimed at, up to two refresh periods
    # after its t_ns and varying with load, so a least-squares fit over t_ns was
    # flaky on a loaded machine.  What holds whatever the lead: starting from rest,
    # the object covers about three times as much ground in the second half of the
    # window as in the first (a constant velocity would give the same in both).
    half = t.max() / 2
    x0, xm, x1 = (np.interp(u, t, x) for u in (t.min(), half, t.max()))
    first, second = xm - x0, x1 - xm
    assert x1 - x_rest > 0.5 * 0.5 * ACCEL * half**2, (x_rest, x1)  # it did accelerate away
    assert second > 1.6 * first > 0, (first, second)
