"""Render and display settings on the wire: one table each way (``docs/protocol.md`` 1.2).

``set_display`` takes flat keys, its reply and every render job carry them, and a
worker turns them back into the settings types of the pipeline.  Each key is read
from and written into :class:`~service.render.pipeline.RenderSettings` (or
:class:`~service.display.DisplaySettings`) by one row of :data:`RENDER_FIELDS`
(:data:`DISPLAY_FIELDS`); the defaults are those types' own, so a render option
added to the pipeline reaches the service, its clients and its workers by a row
here and nothing else.  Values are checked (type, choice, range) before any
settings object is made; a bad one is a ``bad_settings``
:class:`~service.base.errors.MessageError` naming the key.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

from service.base.errors import MessageError, SettingsError
from service.display import DisplaySettings
from service.lod.settings import COLOUR_PCT_MAX, DEFAULT_COLOUR_PCT, LodSettings, lod_from
from service.net import wire
from service.render.cull import CULLS
from service.render.light import EVALUATIONS, MODELS
from service.render.pipeline import FALLBACKS, METHOD_NAMES, RenderSettings


def _choice(allowed: tuple | list) -> Callable[[Any, str], Any]:
    def check(v: Any, key: str) -> Any:
        if not isinstance(v, str) or v not in allowed:
            raise MessageError("bad_settings", f"{key} must be one of {list(allowed)}")
        return v
    return check


def _flag(v: Any, key: str) -> bool:
    if not isinstance(v, bool):
        raise MessageError("bad_settings", f"{key} must be true or false")
    return v


def _number(lo: float, hi: float) -> Callable[[Any, str], float]:
    return lambda v, key: wire.number(v, key, lo, hi)


def _integer(lo: int, hi: int) -> Callable[[Any, str], int]:
    return lambda v, key: wire.integer(v, key, lo, hi)


def _lod_error(r: RenderSettings) -> float:
    return r.lod.error_px if r.lod is not None and r.lod.enabled else 0.0


def _lod_budget(r: RenderSettings) -> float:
    return (r.lod.budget_ms or 0.0) if r.lod is not None and r.lod.enabled else 0.0


def _with_lod(r: RenderSettings, error_px: float, budget_ms: float) -> RenderSettings:
    """``r`` with level of detail at these budgets (:func:`lod_from`), its other fields kept.

    Turned off, ``r.lod`` keeps only what the wire cannot turn off (the colour budget)
    and is None where that is the default, so that settings go to the wire and back
    unchanged.
    """
    new = lod_from(error_px, budget_ms)
    if r.lod is None:
        return replace(r, lod=new)
    if new is None:
        return replace(r, lod=_off(replace(r.lod, error_px=LodSettings.error_px,
                                           budget_ms=None)))
    return replace(r, lod=replace(r.lod, error_px=new.error_px, budget_ms=new.budget_ms,
                                  enabled=True))


def _off(lod: LodSettings) -> LodSettings | None:
    """Level of detail off: None, or (a colour budget not the default) kept, disabled."""
    lod = replace(lod, enabled=False)
    return None if lod == LodSettings(enabled=False) else lod


def _lod_colour(r: RenderSettings) -> float | None:
    return r.lod.colour_pct if r.lod is not None else DEFAULT_COLOUR_PCT


def _with_colour(r: RenderSettings, pct: float | None) -> RenderSettings:
    """``r`` with this colour budget; kept while level of detail is off (it does not turn it on)."""
    if r.lod is None:
        return replace(r, lod=_off(LodSettings(colour_pct=pct)))
    lod = replace(r.lod, colour_pct=pct)
    return replace(r, lod=lod if lod.enabled else _off(lod))


def _colour_pct(v: Any, key: str) -> float | None:
    """A colour budget on the wire: a % from 0 to 100, or null (colour not counted)."""
    return None if v is None else wire.number(v, key, 0.0, COLOUR_PCT_MAX)


def _rgb(v: Any, key: str) -> tuple[int, int, int]:
    if not isinstance(v, list) or len(v) != 3:
        raise MessageError("bad_settings", f"{key} must be a list of 3 integers 0..255")
    return tuple(wire.integer(c, f"{key}[{i}]", 0, 255) for i, c in enumerate(v))


Row = tuple[Callable[[Any], Any], Callable[[Any, Any], Any], Callable[[Any, str], Any]]

#: wire key -> (read it from RenderSettings, write it into one, check a wire value).
RENDER_FIELDS: dict[str, Row] = {
    "method": (lambda r: r.method, lambda r, v: replace(r, method=v), _choice(METHOD_NAMES)),
    "light_model": (lambda r: r.light.model,
                    lambda r, v: replace(r, light=replace(r.light, model=v)),
                    _choice(tuple(MODELS))),
    "specular": (lambda r: r.light.evaluation,
                 lambda r, v: replace(r, light=replace(r.light, evaluation=v)),
                 _choice(tuple(EVALUATIONS))),
    "background": (lambda r: list(r.light.background),
                   lambda r, v: replace(r, light=replace(r.light, background=v)), _rgb),
    "cull": (lambda r: r.cull.mode, lambda r, v: replace(r, cull=replace(r.cull, mode=v)),
             _choice(tuple(sorted(CULLS)))),
    "per_zone_cull": (lambda r: r.cull.per_zone,
                      lambda r, v: replace(r, cull=replace(r.cull, per_zone=v)), _flag),
    "painter_fallback": (lambda r: r.painter_fallback,
                         lambda r, v: replace(r, painter_fallback=v), _choice(FALLBACKS)),
    "painter_tolerance": (lambda r: r.painter_tolerance,
                          lambda r, v: replace(r, painter_tolerance=v), _integer(0, 1 << 30)),
    # 0 turns level of detail off; a time budget alone turns it on at 0.5 px
    "lod_error": (_lod_error, lambda r, v: _with_lod(r, v, _lod_budget(r)), _number(0.0, 1e6)),
    "lod_budget_ms": (_lod_budget, lambda r, v: _with_lod(r, _lod_error(r), v),
                      _number(0.0, 1e6)),
    # null: colour not counted; kept while level of detail is off, and does not turn it on
    "lod_colour_pct": (_lod_colour, _with_colour, _colour_pct),
}

#: wire key -> (read it from DisplaySettings, check a wire value's type).  The ranges
#: are the display's own (:class:`~service.display.DisplaySettings` checks them).
DISPLAY_FIELDS: dict[str, tuple[Callable[[DisplaySettings], Any], Callable[[Any, str], Any]]] = {
    "zones": (lambda d: d.zones, _integer(-(1 << 31), 1 << 31)),
    "angle_deg": (lambda d: d.angle_deg, _number(-1e9, 1e9)),
    "cols": (lambda d: d.cols, _integer(-(1 << 31), 1 << 31)),
    "rows": (lambda d: d.rows, _integer(-(1 << 31), 1 << 31)),
    "width": (lambda d: d.width, _number(-1e9, 1e9)),
}


def render_to_wire(r: RenderSettings) -> dict[str, Any]:
    """Every key of :data:`RENDER_FIELDS`, read from ``r``."""
    return {key: read(r) for key, (read, _, _) in RENDER_FIELDS.items()}


def render_from_wire(d: dict[str, Any], base: RenderSettings | None = None) -> RenderSettings:
    """``base`` (default: the pipeline's defaults) with the keys of ``d`` that name a field.

    Keys in the order of :data:`RENDER_FIELDS`; other keys of ``d`` are not looked at.

    Raises
    ------
    MessageError
        ``bad_settings``: a value of the wrong type, choice or range.
    """
    r = base if base is not None else RenderSettings()
    for key, (_, write, check) in RENDER_FIELDS.items():
        if key in d:
            try:
                r = write(r, check(d[key], key))
            except SettingsError as exc:
                raise MessageError("bad_settings", f"{key}: {exc}") from None
    return r


def display_to_wire(d: DisplaySettings) -> dict[str, Any]:
    """Every key of :data:`DISPLAY_FIELDS`, read from ``d``."""
    return {key: read(d) for key, (read, _) in DISPLAY_FIELDS.items()}


def display_from_wire(d: dict[str, Any], base: DisplaySettings | None = None) -> DisplaySettings:
    """``base`` (default: the display's defaults) with the keys of ``d`` that name a field.

    Raises
    ------
    MessageError
        ``bad_settings``: a value of the wrong type or range.
    """
    base = base if base is not None else DisplaySettings()
    values = {key: check(d[key], key) if key in d else read(base)
              for key, (read, check) in DISPLAY_FIELDS.items()}
    try:
        return DisplaySettings(**values)
    except SettingsError as exc:
        raise MessageError("bad_settings", f"display: {exc}") from None
