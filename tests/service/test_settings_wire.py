"""Render and display settings on the wire: one table, every render option, both ways.

``service.net.settings_wire`` is the one place a render option meets the wire: a field
of the pipeline's ``RenderSettings`` reaches ``set_display``, its reply, the job and
the worker by one row of ``RENDER_FIELDS``.  The service tests run a real service with
a real worker process and check what its renders did.
"""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.base.errors import MessageError
from service.display import DisplaySettings
from service.net.client import ServiceClient
from service.net.settings_wire import (
    RENDER_FIELDS,
    display_from_wire,
    display_to_wire,
    render_from_wire,
    render_to_wire,
)
from service.render.cull import CULLS
from service.render.light import EVALUATIONS, MODELS
from service.render.pipeline import FALLBACKS, METHOD_NAMES, RenderSettings

#: Fields of RenderSettings (dotted paths) that are deliberately not on the wire: the
#: level-of-detail chain recipe (how chains are built and cached, a per-host choice)
#: and the hysteresis (kept per renderer).  Any other field must have a row.
NOT_ON_WIRE = {"lod.enabled", "lod.hysteresis", "lod.fractions", "lod.cloud_eps",
               "lod.texture_res"}
#: dotted field path -> the wire key that carries it.
CARRIED = {"method": "method", "light.model": "light_model", "light.evaluation": "specular",
           "light.background": "background", "cull.mode": "cull",
           "cull.per_zone": "per_zone_cull", "painter_fallback": "painter_fallback",
           "painter_tolerance": "painter_tolerance", "lod.error_px": "lod_error",
           "lod.budget_ms": "lod_budget_ms", "lod.colour_pct": "lod_colour_pct"}


def _leaves(cls: type, prefix: str = "") -> set[str]:
    """Dotted paths of a settings dataclass's fields, nested settings opened."""
    out = set()
    hints = {f.name: f for f in dataclasses.fields(cls)}
    nested = {"cull": "CullSettings", "light": "LightSettings", "lod": "LodSettings"}
    for name in hints:
        if name in nested and not prefix:
            sub = type(getattr(RenderSettings(), name)) if name != "lod" else _lod_type()
            out |= _leaves(sub, f"{name}.")
        else:
            out.add(prefix + name)
    return out


def _lod_type() -> type:
    from service.lod.settings import LodSettings

    return LodSettings


def test_every_render_option_has_one_row_or_is_named_as_not_on_the_wire():
    # a field added to RenderSettings fails here until RENDER_FIELDS carries it
    assert _leaves(RenderSettings) == set(CARRIED) | NOT_ON_WIRE
    assert set(CARRIED.values()) == set(RENDER_FIELDS)


renders = st.builds(
    lambda m, lm, ev, bg, cull, pz, fb, tol, err, budget, colour: render_from_wire({
        "method": m, "light_model": lm, "specular": ev, "background": bg, "cull": cull,
        "per_zone_cull": pz, "painter_fallback": fb, "painter_tolerance": tol,
        "lod_error": err, "lod_budget_ms": budget, "lod_colour_pct": colour}),
    st.sampled_from(METHOD_NAMES), st.sampled_from(sorted(MODELS)),
    st.sampled_from(sorted(EVALUATIONS)), st.lists(st.integers(0, 255), min_size=3, max_size=3),
    st.sampled_from(sorted(CULLS)), st.booleans(), st.sampled_from(FALLBACKS),
    st.integers(0, 1000), st.sampled_from([0.0, 0.25, 0.5, 2.0]),
    st.sampled_from([0.0, 1.0, 40.0]), st.sampled_from([None, 0.0, 1.0, 2.5, 100.0]))


@settings(deadline=None)  # a first call on a loaded machine took 0.48 s
@given(renders)
def test_render_settings_go_to_the_wire_and_back_unchanged(r):
    back = render_from_wire(render_to_wire(r))
    assert back == r
    assert render_to_wire(back) == render_to_wire(r)


def test_keys_not_given_keep_the_base_and_the_defaults_are_the_pipelines():
    assert render_from_wire({}) == RenderSettings()
    base = render_from_wire({"cull": "none", "lod_error": 1.0})
    r = render_from_wire({"painter_fallback": "frame"}, base)
    assert (r.cull.mode, r.lod.error_px, r.painter_fallback) == ("none", 1.0, "frame")
    assert display_from_wire({}) == DisplaySettings()
    d = DisplaySettings(zones=3, cols=64, rows=48)
    assert display_from_wire(display_to_wire(d)) == d


@pytest.mark.parametrize(("req", "words"), [
    ({"cull": "sometimes"}, "cull must be one of"),
    ({"per_zone_cull": 1}, "per_zone_cull must be true or false"),
    ({"painter_fallback": None}, "painter_fallback must be one of"),
    ({"background": [0, 0]}, "background must be a list of 3"),
    ({"specular": "glossy"}, "specular must be one of"),
])
def test_a_bad_value_is_bad_settings_naming_the_key(req, words):
    with pytest.raises(MessageError, match=words) as err:
        render_from_wire(req)
    assert err.value.code == "bad_settings"


@pytest.mark.parametrize(("value", "words"), [
    (-0.5, r"lod_colour_pct must be in \[0.0, 100.0\], got -0.5"),
    (100.5, r"lod_colour_pct must be in \[0.0, 100.0\]"),
    ("1%", "lod_colour_pct must be a number"),
    (True, "lod_colour_pct must be a number"),
    (float("nan"), "lod_colour_pct must be finite"),
])
def test_a_bad_colour_budget_is_refused_naming_the_key(value, words):
    with pytest.raises(MessageError, match=words):
        render_from_wire({"lod_error": 0.5, "lod_colour_pct": value})


def test_the_colour_budget_is_kept_while_lod_is_off_and_does_not_turn_it_on():
    """``lod_colour_pct``: LodSettings.colour_pct; null counts no colour."""
    r = render_from_wire({"lod_colour_pct": 2.5})
    assert r.lod is not None and not r.lod.enabled and r.lod.colour_pct == 2.5
    r = render_from_wire({"lod_error": 0.5}, r)  # turned on: the budget set before holds
    assert r.lod.enabled and (r.lod.error_px, r.lod.colour_pct) == (0.5, 2.5)
    r = render_from_wire({"lod_error": 0.0}, r)  # off, and on again: still kept
    assert not r.lod.enabled and render_from_wire({"lod_budget_ms": 5}, r).lod.colour_pct == 2.5
    assert render_from_wire({"lod_error": 1.0, "lod_colour_pct": None}).lod.colour_pct is None
    assert render_from_wire({"lod_colour_pct": 1.0}).lod is None  # the default: nothing kept
    assert render_to_wire(RenderSettings())["lod_colour_pct"] == 1.0


def _render_stats(c: ServiceClient) -> dict:
    header, _ = c.render_once()
    return header["stats"]


def test_cull_and_the_painter_fallback_reach_the_worker(service_factory):
    svc = service_factory("--scene", "game", "--zones", "2", "--size", "64x48",
                          "--refresh", "30", "--workers", "1")
    with ServiceClient(svc.control, timeout_s=30) as c:
        shown = c.set_display(cull="none", per_zone_cull=False, method="runlength",
                              painter_fallback="frame", painter_tolerance=0)
        assert (shown["cull"], shown["per_zone_cull"], shown["painter_fallback"]) == (
            "none", False, "frame")
        stats = _render_stats(c)
        assert stats["polygons"]["culled"] == 0 and stats["method"] == "runlength"
        c.set_display(cull="modified", per_zone_cull=True)
        stats = _render_stats(c)
        assert stats["polygons"]["culled"] > 0  # the game's closed meshes face away
        with pytest.raises(Exception, match="cull must be one of"):
            c.set_display(cull="sometimes")


def test_one_frame_settings_value_for_the_service_and_the_game():
    from game.backends import LocalRenderer, ServiceBackend
    from service.engine.state import Settings
    from service.frame_settings import FrameSettings

    assert issubclass(Settings, FrameSettings)  # the service's adds only a generation
    assert {f.name for f in dataclasses.fields(Settings)} - {
        f.name for f in dataclasses.fields(FrameSettings)} == {"generation"}
    for backend in (LocalRenderer, ServiceBackend):  # the game's local and remote modes
        assert backend.__init__.__annotations__["settings"] == "FrameSettings | None"
    # every field reaches the wire: set_display's reply names each one
    reply = Settings().as_dict()
    nested = {"display": display_to_wire(DisplaySettings()),
              "render": render_to_wire(RenderSettings())}
    for f in dataclasses.fields(FrameSettings):
        assert set(nested.get(f.name, {f.name: None})) <= set(reply), f.name
