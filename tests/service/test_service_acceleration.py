"""``update_objects`` with ``acceleration``: the rendered object moves quadratically in time."""

from __future__ import annotations

import time

import numpy as np

from service.client import ServiceClient

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
        "--zones", "1", "--angle", "0", "--cols", str(COLS), "--rows", str(ROWS),
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
    # renders are aimed at a refresh a little after they start: a constant lead only
    # adds terms of degree 0 and 1, so the t^2 coefficient is a/2 whatever it is
    c2, c1, c0 = np.polyfit(t, x, 2)
    assert abs(c2 - ACCEL / 2) < 0.2 * ACCEL / 2, f"x = {c2:.3f} t^2 + {c1:.3f} t + {c0:.3f}"
    line = np.polyval(np.polyfit(t, x, 1), t)
    curve = np.polyval([c2, c1, c0], t)
    assert np.abs(x - curve).max() < 2 / PX, "positions off the parabola"
    assert np.abs(x - line).max() > 3 * np.abs(x - curve).max(), "motion looks linear"
    assert x[-1] - x_rest > 0.5 * ACCEL * 1.2**2 * 0.8
