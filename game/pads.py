"""Gamepads: every joystick SDL reports is opened, and its events become actions.

SDL delivers joystick events only for devices that are open.  :class:`Pads` opens
every joystick present when it starts and each one that arrives later
(``JOYDEVICEADDED``), keeping a reference to each, and forgets one on
``JOYDEVICEREMOVED`` together with its stick positions (a stick held while the pad
was pulled out stops pushing).

Buttons and axes arrive as raw numbers that differ between pads and drivers.  When
SDL knows the pad (its game-controller database), the pad's mapping names them
(``a``, ``dpup``, ``leftx``, ...); otherwise SDL's game-controller order is assumed
(:data:`DEFAULT_LAYOUT`: the order of SDL's HIDAPI drivers and virtual pads).  The
names are bound in :mod:`game.actions` (:data:`~game.actions.PAD_BUTTONS`,
:data:`~game.actions.PAD_AXES`); hats are read as they come
(:data:`~game.actions.HAT_BINDINGS`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

import pygame

from game import actions

#: SDL's game-controller buttons in the order of their numbers.
SDL_BUTTONS = (
    "a", "b", "x", "y", "back", "guide", "start", "leftstick", "rightstick",
    "leftshoulder", "rightshoulder", "dpup", "dpdown", "dpleft", "dpright",
)  # fmt: skip
#: SDL's game-controller axes in the order of their numbers.
SDL_AXES = ("leftx", "lefty", "rightx", "righty", "lefttrigger", "righttrigger")
#: Raw input (``b<n>`` button, ``a<n>`` axis) -> SDL name, for pads SDL has no mapping for.
DEFAULT_LAYOUT: dict[str, str] = {
    **{f"b{n}": name for n, name in enumerate(SDL_BUTTONS)},
    **{f"a{n}": name for n, name in enumerate(SDL_AXES)},
}


def layout_from_mapping(mapping: Mapping[str, str]) -> dict[str, str]:
    """Raw input -> SDL name from an SDL game-controller mapping.

    Parameters
    ----------
    mapping : mapping
        SDL name -> raw input, as ``Controller.get_mapping()`` gives it
        (``{"a": "b0", "leftx": "a0", "dpup": "h0.1", "crc": ...}``); hats and
        other entries are left out (hats are read directly).

    Returns
    -------
    dict
        ``{"b0": "a", "a0": "leftx", ...}``
    """
    out = {}
    for name, raw in mapping.items():
        raw = str(raw).strip("+-~")
        if raw[:1] in ("a", "b") and raw[1:].isdigit():
            out[raw] = name
    return out


def pad_layout(index: int) -> dict[str, str]:
    """The layout of joystick ``index``: from SDL's mapping, else :data:`DEFAULT_LAYOUT`."""
    try:
        from pygame._sdl2 import controller

        if not controller.get_init():
            controller.init()
        if not controller.is_controller(index):
            return dict(DEFAULT_LAYOUT)
        pad = controller.Controller(index)
        try:
            layout = layout_from_mapping(pad.get_mapping())
        finally:
            pad.quit()  # the joystick stays open: SDL counts its openings
    except (ImportError, AttributeError, pygame.error):
        return dict(DEFAULT_LAYOUT)
    return layout or dict(DEFAULT_LAYOUT)


class Pads:
    """The open joysticks and what their sticks hold.

    Attributes
    ----------
    joysticks : dict
        SDL instance id -> the open ``pygame.joystick.Joystick``.
    layouts : dict
        Instance id -> raw input -> SDL name (:func:`pad_layout`).
    axes : dict
        (instance id, SDL axis name) -> the stick's last value, -1 to 1.
    """

    def __init__(self) -> None:
        self.joysticks: dict[int, pygame.joystick.JoystickType] = {}
        self.layouts: dict[int, dict[str, str]] = {}
        self.axes: dict[tuple[int, str], float] = {}
        self._handlers: dict[int, Callable[[pygame.event.Event], list[str]]] = {
            pygame.JOYDEVICEADDED: lambda ev: self.open(ev.device_index),
            pygame.JOYDEVICEREMOVED: lambda ev: self.close(ev.instance_id),
            pygame.JOYBUTTONDOWN: self._button,
            pygame.JOYHATMOTION: _hat,
            pygame.JOYAXISMOTION: self._axis,
        }

    def open_all(self) -> None:
        """Open every joystick present now (initialising SDL's joystick system)."""
        if not pygame.joystick.get_init():
            pygame.joystick.init()
        for index in range(pygame.joystick.get_count()):
            self.open(index)

    def open(self, index: int) -> list[str]:
        """Open joystick ``index`` (a device index, not an instance id); no actions."""
        try:
            joy = pygame.joystick.Joystick(index)
            iid = joy.get_instance_id()
        except pygame.error:
            return []  # gone again before it could be opened
        if iid not in self.joysticks:
            self.joysticks[iid] = joy
            self.layouts[iid] = pad_layout(index)
        return []

    def close(self, instance_id: int) -> list[str]:
        """Forget the joystick ``instance_id`` and its sticks; no actions."""
        self.joysticks.pop(instance_id, None)
        self.layouts.pop(instance_id, None)
        self.axes = {k: v for k, v in self.axes.items() if k[0] != instance_id}
        return []

    def read(self, events: Iterable[pygame.event.Event], dt: float) -> actions.Input:
        """The pads' input from one tick's events; sticks held for ``dt`` seconds."""
        names: list[str] = []
        for ev in events:
            handler = self._handlers.get(ev.type)
            if handler is not None:
                names += handler(ev)
        held = ((name, value) for (_, name), value in self.axes.items())
        return actions.Input(names, actions.stick_shift(held, dt))

    def _name(self, ev: pygame.event.Event, raw: str) -> str | None:
        return self.layouts.get(ev.instance_id, DEFAULT_LAYOUT).get(raw)

    def _button(self, ev: pygame.event.Event) -> list[str]:
        action = actions.PAD_BUTTONS.get(self._name(ev, f"b{ev.button}"))
        return [action] if action is not None else []

    def _axis(self, ev: pygame.event.Event) -> list[str]:
        name = self._name(ev, f"a{ev.axis}")
        if name in actions.PAD_AXES:
            self.axes[(ev.instance_id, name)] = float(ev.value)
        return []


def _hat(ev: pygame.event.Event) -> list[str]:
    action = actions.HAT_BINDINGS.get(tuple(ev.value))
    return [action] if action is not None else []
