"""The order guard works through the service: a client that keeps changing an
object's motion gets a lower galpixel order, which the frame header reports."""

from __future__ import annotations

import time

import numpy as np

from service.net.client import FrameSubscriber, ServiceClient

SPEED = 0.8  # world units / s along x; flipped at every new render


def _quad() -> dict:
    """A 0.2 x 0.2 square facing the viewer, both windings (never culled)."""
    v = np.array([[-0.1, -0.1, 0], [0.1, -0.1, 0], [0.1, 0.1, 0], [-0.1, 0.1, 0]], np.float32)
    t = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]], np.int32)
    return {"name": "box", "mesh": {"vertices": v, "triangles": t},
            "material": {"colour": [1.0, 1.0, 1.0]}, "position": [0.0, 0.0, -0.1]}


def _zigzag(frames: FrameSubscriber, c: ServiceClient, renders: int) -> list[dict]:
    """Flip the box's velocity at each new render seen; the frame headers meanwhile."""
    headers, seen, sign = [], -1, 1.0
    deadline = time.monotonic() + 60
    while len({h["render_id"] for h in headers}) < renders and time.monotonic() < deadline:
        got = frames.next(1.0)
        if got is None:
            continue
        headers.append(got[0])
        if got[0]["render_id"] != seen:
            seen, sign = got[0]["render_id"], -sign
            c.update_objects([{"name": "box", "velocity": [sign * SPEED, 0, 0]}])
    return headers


def test_changing_motion_lowers_the_order(service_factory):
    svc = service_factory(
        "--zones", "1", "--angle", "0", "--size", "64x48", "--workers", "0",
        "--refresh", "30", "--max-update-hz", "6",
    )  # fmt: skip
    with FrameSubscriber(svc.frames, hwm=200) as frames, ServiceClient(svc.control) as c:
        c.load_scene(scene={"objects": [_quad()], "lights": [], "ambient": 1.0})
        headers = _zigzag(frames, c, renders=16)
    assert len({h["render_id"] for h in headers}) >= 16, "renders stopped coming"
    orders = [h["order"] for h in headers]
    assert set(orders) <= {0, 1, 2}, orders
    # the first renders' refreshes run at the order asked for (2), with no history
    assert orders[0] == 2
    # later, G(2)'s extrapolation of a motion that flips at every render predicts
    # the next render worse than a lower order, and the guard switches down
    assert min(orders[len(orders) // 2:]) < 2, orders
