"""The engine's warm-up job (:mod:`service.warmup` runs it): the service's own path.

Band renders as the workers make them (:func:`service.engine.jobs.render_job`),
stitched, submitted to the Galilean stage and refreshed, as the render and refresh
threads do.
"""

from __future__ import annotations

from service.engine.jobs import render_job, stitch
from service.galilean import GalileanSettings, GalileanStage
from service.render.pipeline import Renderer
from service.render.scene import MotionState
from service.warmup_job import APART, Job, Kit, stage_refreshes


def _galilean_service(kit: Kit) -> None:
    """The service's path: band renders (``render_job``), stitched, submitted, refreshed."""
    d = kit.display
    stage = GalileanStage(d, GalileanSettings(order=2, refresh_hz=60.0))
    job = {
        "display": {"zones": d.zones, "angle_deg": d.angle_deg, "cols": d.cols, "rows": d.rows,
                    "width": d.width},
        "rows": [0, d.rows], "t": 0.1, "refresh_hz": 60.0, "order": 2,
        "render": {"method": "zbuffer", "light_model": "blinn", "specular": "polygon"},
    }
    renderer = Renderer()
    for k in range(2):
        half = d.rows // 2
        bands = [render_job(renderer, {**job, "rows": r}, kit.scene())[0]
                 for r in ([0, half], [half, d.rows])]
        rendered, buf = stitch(bands, MotionState(), stage.fixed, 2)
        stage.submit(buf, stage.index + 1, None, True, (), rendered.points,
                     rendered.point_derivs, rendered.viewer_motion)
        stage.viewer(MotionState(velocity=[0.1 * k, 0.0, 0.0], angular_velocity=[0.0, 0.2, 0.0]))
        stage_refreshes(stage)


#: This subsystem's jobs, in order (:data:`service.warmup.JOBS` gathers them).
WARMUP_JOBS: dict[str, Job] = {
    "galilean: service refresh": Job(_galilean_service, APART, service=True,
                                     first_frame=True),
}
