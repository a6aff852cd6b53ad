"""The request handlers: one function per message type over a :class:`ServiceState`.

:data:`HANDLERS` maps a request ``type`` to its handler (``docs/protocol.md``).  A
handler takes the state and the parsed request and returns the reply's
``(fields, arrays?, names?)``, or None when the control loop answers later
(``render``); a bad request raises :class:`~service.base.errors.MessageError`.  They need
no socket, so they run in process against a state from :func:`~.state.service_state`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from service.autostereogram import SirdSettings, default_eye_sep
from service.base.errors import HoloError, MeshFileError, MessageError, SettingsError
from service.builtin_scenes import builtin_scene
from service.display import MAX_PIXELS, DisplaySettings
from service.engine.state import Settings, State
from service.engine.viewer import VIEWER_POSE_FIELDS
from service.loaders import load_scene as load_mesh_file
from service.net import protocol, wire
from service.net.settings_wire import display_from_wire, render_from_wire
from service.net.state import ENCODINGS, MAX_INDEX, SIRD_METHODS, ServiceState
from service.quality import MODES as QUALITY_MODES
from service.quality import parse_budget
from service.render.scene import Scene, SceneObject
from service.scene_motion import advance_scene


def hello(st: ServiceState, req: dict[str, Any]) -> tuple:
    """Agree a version; the session, frame address, limits and status."""
    versions = req.get("versions", [protocol.VERSION])
    if not isinstance(versions, list):
        raise MessageError("bad_message", "versions must be a list of ints")
    common = [v for v in protocol.SUPPORTED_VERSIONS if v in versions]
    if not common:
        raise MessageError(
            "bad_version",
            f"no common version; the service speaks {list(protocol.SUPPORTED_VERSIONS)}",
        )
    return (
        {
            "version": max(common),
            "versions": list(protocol.SUPPORTED_VERSIONS),
            "service": protocol.SERVICE_NAME,
            "session": st.session,
            "heartbeat_s": protocol.HEARTBEAT_S,
            "frames": (st.stream.address if st.stream is not None else None),
            "limits": st.limits.as_dict(),
            **st.status(),
        },
    )


def ping(st: ServiceState, req: dict[str, Any]) -> tuple:
    """The service's clock and status."""
    return ({"t_ns": time.monotonic_ns(), **st.status()},)


def load_scene(st: ServiceState, req: dict[str, Any]) -> tuple:
    """Replace the scene (one of ``builtin``, ``path``, ``scene``)."""
    sources = [k for k in ("builtin", "path", "scene") if k in req]
    if len(sources) != 1:
        raise MessageError("bad_message", "give exactly one of builtin, path, scene")
    loaders = {
        "builtin": lambda v: load_builtin(wire.string(v, "builtin", 64)),
        "path": lambda v: _load_path(wire.string(v, "path"), st.config.scene_dirs,
                                     st.state.settings.display),
        "scene": wire.scene_from_wire,
    }
    scene = loaders[sources[0]](req[sources[0]])
    loaded = st.state.load(scene)
    st.queue_chains()
    return (
        {
            "objects": [o.name for o in scene.objects],
            "polygons": int(sum(o.mesh.n_polygons for o in scene.objects)),
            "scene": loaded,
        },
    )


def load_object(st: ServiceState, req: dict[str, Any]) -> tuple:
    """Add one object (``path`` or inline ``object``) to the scene."""
    if "path" in req:

        mesh_scene = _load_path(wire.string(req["path"], "path"), st.config.scene_dirs,
                                st.state.settings.display)
        if not mesh_scene.objects:  # a lone billboard cloud (.hbc) has no mesh object
            raise MessageError("bad_message", f"{req['path']}: no mesh to add as an object "
                               "(a billboard cloud loads with load_scene)")
        obj = mesh_scene.objects[0]
        if "name" in req:
            obj = SceneObject(
                obj.mesh,
                obj.material,
                obj.transform,
                obj.motion,
                wire.string(req["name"], "name", wire.MAX_NAME),
            )
    else:
        obj = wire.object_from_wire(req.get("object"), "object")
    with st.state.lock:
        scene = st.state.scene or Scene()
        if len(scene.objects) >= st.limits.max_objects:
            raise MessageError(
                "too_large", f"a scene holds at most {st.limits.max_objects} objects"
            )
        advance_locked(st.state, time.monotonic())
        scene = st.state.scene or Scene()
        st.state.scene = Scene([*scene.objects, obj], scene.lights, scene.ambient,
                               billboards=scene.billboards)
        st.state.scene_version += 1
        index = len(st.state.scene.objects) - 1
    st.queue_chains()
    return ({"index": index},)


def advance_locked(state: State, now: float) -> None:
    """Move the scene's state to ``now`` (so updates start from the present)."""
    s = state
    if s.scene is not None and s.scene.objects:
        s.scene = advance_scene(s.scene, now - s.scene_t)
    s.scene_t = now


def update_objects(st: ServiceState, req: dict[str, Any]) -> tuple:
    """Change objects' fields (by ``index`` or ``name``), all or none."""
    ups = req.get("objects")
    if not isinstance(ups, list):
        raise MessageError("bad_message", "objects must be a list")
    if len(ups) > st.limits.max_objects:
        raise MessageError("too_large", f"at most {st.limits.max_objects} updates")
    with st.state.lock:
        if st.state.scene is None:
            raise MessageError("no_scene", "load a scene first")
        objs = list(st.state.scene.objects)
        todo = [(_object_index(u, objs, i), u) for i, u in enumerate(ups)]
        changed = [
            (k, wire.apply_fields(objs[k], u, f"objects[{i}]")) for i, (k, u) in enumerate(todo)
        ]
        advance_locked(st.state, time.monotonic())
        objs = list(st.state.scene.objects)
        for k, new in changed:
            objs[k] = replace(new, transform=new.transform, motion=new.motion)
        sc = st.state.scene
        st.state.scene = Scene(objs, sc.lights, sc.ambient, billboards=sc.billboards)
        st.state.scene_version += 1
    return ({"updated": len(changed)},)


def set_viewer(st: ServiceState, req: dict[str, Any]) -> tuple:
    """Set the viewer's pose and motion, or the devices' stream to track it from."""
    pose = [k for k in VIEWER_POSE_FIELDS if k in req]
    if pose and "devices" in req:
        raise MessageError(
            "bad_message", f"set_viewer takes a pose or devices, not both (got {pose})"
        )
    with st.state.lock:
        if "devices" in req:
            dev = req["devices"]
            st.state.devices = None if dev is None else wire.string(dev, "devices", 256)
        st.state.viewer.set_fields(req)
        return ({"viewer": st.state.viewer.as_dict(), "devices": st.state.devices},)


def set_display(st: ServiceState, req: dict[str, Any]) -> tuple:
    """Change the display and render settings (a new ``generation``)."""
    with st.state.lock:
        new = _apply_display(st.state.settings, req)
        st.state.settings = new
    st.queue_chains()  # level of detail may have been turned on
    return ({"display": new.as_dict()},)


def render(st: ServiceState, req: dict[str, Any]) -> None:
    """Check a ``render`` request; the control loop answers it with the next render."""
    if "encodings" in req:
        _encodings(req["encodings"])
    with st.state.lock:
        if st.state.scene is None:
            raise MessageError("no_scene", "load a scene first")
    return None


def stats(st: ServiceState, req: dict[str, Any]) -> tuple:
    """Counters, rates and the state of workers and errors."""
    s = st.counters.as_dict()
    s.update(
        frames_published=(st.stream.published if st.stream is not None else 0),
        clients=len(st.clients),
        pose_count=st.state.viewer.poses,
        zone=st.state.viewer.zone,
        **_worker_stats(st),
        band_retries=st.band_retries,
        render_retries=st.band_retries,
        jobs_resent=st.band_retries,
        split=st.config.split if st.to_workers() else "in_process",
        max_in_flight=st.pipe.max_in_flight if st.pipe is not None else None,
        last_render_error=st.last_render_error,
        last_refresh_error=st.last_refresh_error,
        lod=st.last_lod,
        chains=st.chains.status(),
        session=st.session,
        compile=st.warmup.background_dict() if st.warmup is not None else None,
        **st.status(),
    )
    return ({"stats": s},)


def _worker_stats(st: ServiceState) -> dict[str, Any]:
    """The workers' part of ``stats`` (``docs/protocol.md``).

    ``workers``, ``worker_pids`` (live only), ``worker_deaths``, ``worker_restarts``
    and ``worker_error`` (why local workers were given up; "" while none was).
    """
    sup = st.supervisor
    if sup is None:
        return {"workers": None, "worker_pids": [], "worker_deaths": 0, "worker_restarts": 0,
                "worker_error": ""}
    return {"workers": sup.info(), "worker_pids": sup.pids(), "worker_deaths": sup.deaths,
            "worker_restarts": sup.restarts, "worker_error": "; ".join(sup.errors())}


def shutdown(st: ServiceState, req: dict[str, Any]) -> tuple:
    """Stop the service (after this reply)."""
    st.stop.set()
    return ({},)


#: request type -> handler (``docs/protocol.md``)
HANDLERS: dict[str, Callable[[ServiceState, dict[str, Any]], tuple | None]] = {
    "hello": hello,
    "ping": ping,
    "load_scene": load_scene,
    "load_object": load_object,
    "update_objects": update_objects,
    "set_viewer": set_viewer,
    "set_display": set_display,
    "render": render,
    "stats": stats,
    "shutdown": shutdown,
}


def load_builtin(name: str) -> Scene:
    """A builtin scene by name; an unknown name is ``not_found``."""
    try:
        return builtin_scene(name)
    except SettingsError as exc:
        raise MessageError("not_found", str(exc)) from exc


def _load_path(path: str, roots: tuple[str, ...] = (),
               display: DisplaySettings | None = None) -> Scene:
    """Load a scene or mesh file; with ``roots``, only from inside those directories.

    A lone mesh is fitted to ``display`` (the service's own, not the default one).
    """
    if roots:
        real = Path(path).resolve()
        if not any(real.is_relative_to(Path(r).resolve()) for r in roots):
            raise MessageError("not_found", f"{path} is outside the service's scene directories")
    if not Path(path).is_file():
        raise MessageError("not_found", f"no such file: {path}")
    try:
        scene = load_mesh_file(path, display=display)
    except MeshFileError as exc:
        raise MessageError("not_found", str(exc)) from exc
    return scene


def _object_index(u: Any, objs: list, i: int) -> int:
    """The scene index an ``update_objects`` entry names (by ``index`` or ``name``).

    Raises
    ------
    MessageError
        ``bad_message`` for a malformed entry (not an object, neither key, an index
        that is not a non-negative integer); ``not_found`` for a well-formed index or
        name that names no object of the scene.
    """
    if not isinstance(u, dict):
        raise MessageError("bad_message", f"objects[{i}] must be an object")
    if "index" in u:
        k = wire.integer(u["index"], f"objects[{i}].index", 0, MAX_INDEX)
        if k >= len(objs):
            raise MessageError(
                "not_found", f"objects[{i}]: no object {k} (the scene has {len(objs)})"
            )
        return k
    if "name" not in u:
        raise MessageError("bad_message", f"objects[{i}] needs an index or a name")
    name = wire.string(u["name"], f"objects[{i}].name", wire.MAX_NAME)
    for k, o in enumerate(objs):
        if o.name == name:
            return k
    raise MessageError("not_found", f"objects[{i}]: no object {name!r}")


def _encodings(v: Any) -> tuple[str, ...]:
    if not isinstance(v, list) or not v or not all(e in ENCODINGS for e in v):
        raise MessageError("bad_message", f"encodings must be a non-empty list from {ENCODINGS}")
    return tuple(dict.fromkeys(v))


def _check_sird(cols: int, eye_sep: float) -> None:
    """Refuse an autostereogram the eyes cannot fuse (``bad_settings``)."""
    try:
        SirdSettings(eye_sep=eye_sep or default_eye_sep(cols)).check_width(cols)
    except SettingsError as exc:
        raise MessageError("bad_settings", f"autostereogram: {exc}") from None


def _apply_display(s: Settings, req: dict[str, Any]) -> Settings:
    """``s`` with the fields of a ``set_display`` request (checked; a new generation)."""
    kw: dict[str, Any] = {"render": render_from_wire(req, s.render)}
    if "sird_method" in req:
        if req["sird_method"] not in SIRD_METHODS:
            raise MessageError("bad_settings", f"sird_method must be one of {list(SIRD_METHODS)}")
        kw["sird_method"] = req["sird_method"]
    if "galpixel_order" in req:
        kw["galpixel_order"] = wire.integer(req["galpixel_order"], "galpixel_order", 0, 3)
    if "encodings" in req:
        kw["encodings"] = _encodings(req["encodings"])
    if "refresh_hz" in req:
        kw["refresh_hz"] = wire.number(req["refresh_hz"], "refresh_hz", 1.0, 240.0)
    if "sird_eye_sep" in req:
        kw["sird_eye_sep"] = wire.number(req["sird_eye_sep"], "sird_eye_sep", 0.0, 4096.0)
    kw.update(_quality_fields(req))
    display = _display(req, s.display)
    if "autostereogram" in kw.get("encodings", s.encodings):
        _check_sird(display.cols, kw.get("sird_eye_sep", s.sird_eye_sep))
    return replace(s, display=display, generation=s.generation + 1, **kw)


def _display(req: dict[str, Any], d: DisplaySettings) -> DisplaySettings:
    """The display a ``set_display`` request asks for (``too_large`` past MAX_PIXELS)."""
    size = [wire.integer(req.get(k, getattr(d, k)), k, 1, 8192) for k in ("zones", "cols", "rows")]
    if size[0] * size[1] * size[2] > MAX_PIXELS:
        raise MessageError("too_large", f"display has more than {MAX_PIXELS:,} pixels")
    return display_from_wire(req, d)


def _quality_fields(req: dict[str, Any]) -> dict[str, str]:
    """``quality`` ("fixed" / "auto") and ``max_error`` ("0.5%", 0.5, "40dB") of set_display."""
    kw = {}
    if "quality" in req:
        if req["quality"] not in QUALITY_MODES:
            raise MessageError("bad_settings", f"quality must be one of {list(QUALITY_MODES)}")
        kw["quality"] = req["quality"]
    if "max_error" in req:
        v = req["max_error"]
        try:
            if not isinstance(v, str | int | float) or isinstance(v, bool):
                raise SettingsError("max_error must be a number or a string like 40dB")
            parse_budget(v)
        except SettingsError as exc:
            raise MessageError("bad_settings", str(exc)) from None
        kw["max_error"] = str(v)
    return kw


def error_code(exc: Exception) -> str:
    """The reply's error code for an exception a handler raised (else ``internal``)."""
    codes: dict[type, str] = {
        SettingsError: "bad_settings",
        MeshFileError: "not_found",
        HoloError: "bad_message",
    }
    for cls, code in codes.items():
        if isinstance(exc, cls):
            return code
    return "internal"

