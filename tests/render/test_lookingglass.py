"""Looking Glass interleave: every subpixel's view against the lenticular shader's formula.

The expected view is computed here from Looking Glass's shader as published
(``HoloPlayCore/include/HoloPlayShaders.h``, LookingGlassCoreSDK): per subpixel ``k``,
``(u + k subp + v tilt) pitch - center``, taken modulo 1, times the view count, with
``u, v`` the GL texture coordinates (v up) of the pixel's centre; red reads ``rgb[ri]``,
blue ``rgb[bi]``.  The views are flat images whose value is their index, so the
interleaved panel shows, in every subpixel, the view it took.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from testkit import ROOT, shared_fixture

from service.base.errors import SettingsError
from service.lookingglass import (
    Calibration,
    Interleaver,
    calibration_from_dict,
    load_calibration,
    parse_display,
    sample_maps,
)

FIXTURE = shared_fixture("lookingglass/visual.json")
#: The sample calibration the README's commands use.
EXAMPLE = ROOT / "examples" / "lookingglass-visual.json"

#: Two made-up panels (odd sizes, negative slope, every flag) beside the sample device.
SYNTHETIC = {
    "odd": {"pitch": 47.5, "slope": -6.1, "center": 0.73, "viewCone": 35.0, "invView": 0,
            "DPI": 338.0, "screenW": 517, "screenH": 311, "flipImageX": 0, "flipSubp": 0},
    "flipped": {"pitch": 52.3, "slope": 4.2, "center": -1.37, "viewCone": 50.0,
                "invView": 1, "DPI": 290.0, "screenW": 384, "screenH": 640,
                "flipImageX": 1, "flipSubp": 1},
}


def _visual(fields: dict) -> dict:
    """A visual.json object: every field as {"value": n}."""
    return {"configVersion": "1.0", **{k: {"value": v} for k, v in fields.items()}}


def expected_views(fields: dict, n: int) -> np.ndarray:
    """(H, W, 3) view of each subpixel, straight from the shader's text."""
    w, h = int(fields["screenW"]), int(fields["screenH"])
    slope = fields["slope"]
    tilt = h / (w * slope) * (-1 if fields.get("flipImageX") else 1)
    pitch = fields["pitch"] * w / fields["DPI"] * math.cos(math.atan(1.0 / slope))
    subp = 1.0 / (w * 3)
    u = (np.arange(w) + 0.5) / w
    v = ((h - 1 - np.arange(h)) + 0.5) / h  # GL: v = 0 at the bottom row
    rgb = []
    for k in range(3):
        z = (u[None, :] + k * subp + v[:, None] * tilt) * pitch - fields["center"]
        view = np.minimum(np.floor(np.mod(z, 1.0) * n), n - 1)
        rgb.append(n - 1 - view if fields.get("invView") else view)
    ri, bi = (2, 0) if fields.get("flipSubp") else (0, 2)
    return np.stack([rgb[ri], rgb[1], rgb[bi]], axis=2).astype(np.uint8)


def index_views(n: int, rows: int, cols: int) -> np.ndarray:
    """``n`` flat views, view ``k`` of value ``k`` in every channel."""
    return np.broadcast_to(np.arange(n, dtype=np.uint8)[:, None, None, None],
                           (n, rows, cols, 3)).copy()


@pytest.mark.parametrize("name", sorted(SYNTHETIC))
@pytest.mark.parametrize("n", [45, 7])
def test_every_subpixel_shows_the_view_of_the_formula(name, n):
    fields = SYNTHETIC[name]
    cal = calibration_from_dict(_visual(fields), views=n)
    h, w = fields["screenH"], fields["screenW"]
    panel = Interleaver(cal)(index_views(n, h, w))
    want = expected_views(fields, n)
    assert panel.shape == (h, w, 3)
    assert np.array_equal(panel, want), f"{(panel != want).sum()} subpixels differ"
    assert set(np.unique(panel)) == set(range(n))  # every view shows somewhere


@pytest.mark.skipif(not FIXTURE.is_file(), reason=f"no shared fixture {FIXTURE}")
def test_the_sample_device_matches_the_formula_on_every_subpixel():
    fields = {k: v["value"] for k, v in json.loads(FIXTURE.read_text()).items()
              if isinstance(v, dict)}
    cal = load_calibration(FIXTURE)
    assert (cal.screen_w, cal.screen_h, cal.views, cal.inv_view) == (2560, 1600, 45, True)
    panel = Interleaver(cal)(index_views(45, 5, 8))  # 8x5: the panel's aspect, any pixel
    assert np.array_equal(panel, expected_views(fields, 45))


def test_inv_view_reverses_the_views_and_flip_subp_swaps_red_and_blue():
    base = dict(SYNTHETIC["odd"])
    views = index_views(9, base["screenH"], base["screenW"])
    plain = Interleaver(calibration_from_dict(_visual(base), 9))(views)
    inv = Interleaver(calibration_from_dict(_visual({**base, "invView": 1}), 9))(views)
    assert np.array_equal(inv, 8 - plain)
    sub = Interleaver(calibration_from_dict(_visual({**base, "flipSubp": 1}), 9))(views)
    assert np.array_equal(sub, plain[:, :, ::-1])


def test_flip_image_x_mirrors_the_slant():
    base = dict(SYNTHETIC["odd"], center=0.0)
    views = index_views(12, base["screenH"], base["screenW"])
    plain = Interleaver(calibration_from_dict(_visual(base), 12))(views)
    flip = Interleaver(calibration_from_dict(_visual({**base, "flipImageX": 1}), 12))(views)
    assert not np.array_equal(flip, plain)
    # tilt changes sign, the horizontal pitch (cos(atan(1 / slope))) does not: the
    # pattern of the same panel with its slope negated
    neg = Interleaver(calibration_from_dict(_visual({**base, "slope": -base["slope"]}), 12))
    assert np.array_equal(flip, neg(views))


def test_one_view_gives_the_plain_image():
    rng = np.random.default_rng(3)
    fields = SYNTHETIC["flipped"]
    image = rng.integers(0, 256, (1, fields["screenH"], fields["screenW"], 3), np.uint8)
    cal = calibration_from_dict(_visual(fields), views=1)
    assert np.array_equal(Interleaver(cal)(image), image[0])


def test_views_of_another_aspect_get_black_bars_and_keep_their_shape():
    cal = calibration_from_dict(_visual(SYNTHETIC["odd"]), views=1)  # 517x311, wider
    rows, cols = sample_maps(cal, 100, 100)  # a square view: bars left and right
    assert (rows >= 0).all() and cols[0] == -1 and cols[-1] == -1
    inside = cols[cols >= 0]
    assert inside.min() == 0 and inside.max() == 99 and np.all(np.diff(inside) >= 0)
    assert abs((cols >= 0).sum() - 311) <= 1  # as wide as the panel is tall
    panel = Interleaver(cal)(np.full((1, 100, 100, 3), 200, np.uint8))
    assert (panel[:, cols < 0] == 0).all() and (panel[:, cols >= 0] == 200).all()


@pytest.mark.skipif(not FIXTURE.is_file(), reason=f"no shared fixture {FIXTURE}")
def test_the_example_calibration_is_the_shared_sample():
    assert load_calibration(EXAMPLE) == load_calibration(FIXTURE)


@pytest.mark.parametrize(("text", "words"), [
    ("{", "not a JSON calibration"),
    ("[1, 2]", "not a calibration"),
    ('{"pitch": {"value": 50}}', "calibration has no slope"),
    (json.dumps(_visual({**SYNTHETIC["odd"], "slope": "steep"})), "slope is 'steep'"),
    (json.dumps(_visual({**SYNTHETIC["odd"], "slope": 0})), "slope is 0"),
    (json.dumps(_visual({**SYNTHETIC["odd"], "DPI": -3})), "DPI is -3"),
    (json.dumps(_visual({**SYNTHETIC["odd"], "screenW": 517.5})), "not a whole number"),
    ('{"pitch": {"value": NaN}}', "pitch is nan"),
])
def test_a_malformed_calibration_gets_a_one_line_error(tmp_path, text, words):
    path = tmp_path / "visual.json"
    path.write_text(text)
    with pytest.raises(SettingsError) as err:
        load_calibration(path)
    message = str(err.value)
    assert words in message and str(path) in message and "\n" not in message


def test_display_values_name_their_problem(tmp_path):
    with pytest.raises(SettingsError, match="want lookingglass:CALIBRATION.json"):
        parse_display("holovideo")
    with pytest.raises(SettingsError, match="cannot read the calibration"):
        parse_display(f"lookingglass:{tmp_path / 'missing.json'}")
    cal = parse_display(f"lookingglass:{EXAMPLE}")
    assert isinstance(cal, Calibration) and cal.view_cone == 40.0


def test_wrong_stacks_are_refused():
    il = Interleaver(calibration_from_dict(_visual(SYNTHETIC["odd"]), views=5))
    with pytest.raises(SettingsError, match="interleaves 5 views, got 4"):
        il(index_views(4, 10, 10))
    with pytest.raises(SettingsError, match="uint8"):
        il(np.zeros((5, 10, 10, 3), np.float32))
