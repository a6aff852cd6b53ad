"""The ``autostereogram`` output: every refresh (Galilean ones too) carries a SIRD of its depth."""

from __future__ import annotations

import numpy as np
import pytest
from testkit import wait_until

from service.autostereogram import SirdSettings, default_eye_sep, separation_map
from service.base.errors import HoloError
from service.net.client import FrameSubscriber, ServiceClient


def test_frames_carry_a_stereogram_of_their_own_depth(service_factory):
    svc = service_factory("--scene", "game", "--zones", "3", "--size", "96x64",
                          "--workers", "0", "--refresh", "20", "--max-update-hz", "2")
    with FrameSubscriber(svc.frames, hwm=100) as frames, ServiceClient(svc.control) as c:
        shown = c.set_display(encodings=["depth", "autostereogram"], sird_method="row")
        assert shown["encodings"] == ["depth", "autostereogram"]
        assert shown["sird_method"] == "row"
        seen = {"render": 0, "galilean": 0}

        def check() -> bool:
            got = frames.next(0.5)
            if got is None or "autostereogram" not in got[1]:
                return False
            header, arrays = got
            zone = 1 if header["zone"] is None else header["zone"]  # the centre of 3
            sird, depth = arrays["autostereogram"], arrays["depth"][zone]
            assert sird.shape == (64, 96) and sird.dtype == np.uint8
            s = SirdSettings(method="row", eye_sep=default_eye_sep(96), near=-0.6, far=0.6)
            sep = separation_map(depth, s)
            xs = np.arange(96 - s.max_sep)
            assert (sird[:, xs] == np.take_along_axis(sird, xs + sep[:, xs], axis=1)).all()
            seen["galilean" if header["since_render"] > 0 else "render"] += 1
            return seen["galilean"] >= 1 and seen["render"] >= 1 and np.isfinite(depth).any()

        assert wait_until(check, 90), seen
        stats = c.request("stats")["stats"]
        assert stats["sird_ms_p50"] is not None and stats["sird_ms_p50"] < 50


def test_a_display_too_narrow_to_fuse_is_refused(service_factory):
    svc = service_factory("--scene", "game", "--zones", "1", "--size", "64x48",
                          "--workers", "0", "--refresh", "30")
    with ServiceClient(svc.control) as c:
        with pytest.raises(HoloError, match="autostereogram"):
            c.set_display(encodings=["autostereogram"], sird_eye_sep=100)
        assert "autostereogram" not in c.set_display()["encodings"]
