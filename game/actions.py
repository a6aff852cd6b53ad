"""Input: keyboard, gamepad, dial box and buttons mapped to abstract actions.

Every binding is a lookup table from an input to an action name; nothing below
branches on which key was pressed.  Discrete actions are the six moves of
:data:`game.rules.MOVES` plus the game's own commands (:data:`COMMANDS`);
continuous input (dials, stick axes) becomes a shift of the player's origin.

Dial box (``holo-devices`` PUB stream): dials 0, 1, 2 move the player continuously
along x, y and z (:data:`DIAL_AXES`, world units per count); buttons 0 to 5 make the
six discrete moves and button 6 pauses (:data:`BUTTON_BINDINGS`).  The lamps of the
bound buttons are lit on the device side: :func:`lamp_mask` gives the mask for
``holo-devices --lamps``.

Gamepad: buttons and sticks are bound by their SDL game-controller names
(:data:`PAD_BUTTONS`, :data:`PAD_AXES`), hats by direction (:data:`HAT_BINDINGS`);
:class:`game.pads.Pads` opens the pads and turns their raw numbers into those names.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import pygame

from drivers.events import ButtonEvent, DialEvent

#: Commands besides the moves.
COMMANDS = (
    "pause",
    "quit",
    "start",
    "mode_head",
    "mode_strip",
    "mode_zone",
    "mode_autostereogram",
    "zone_prev",
    "zone_next",
)

KEY_BINDINGS: dict[int, str] = {
    pygame.K_UP: "moveup",
    pygame.K_DOWN: "movedown",
    pygame.K_LEFT: "moveleft",
    pygame.K_RIGHT: "moveright",
    pygame.K_w: "moveup",
    pygame.K_s: "movedown",
    pygame.K_a: "moveleft",
    pygame.K_d: "moveright",
    pygame.K_PAGEUP: "movein",
    pygame.K_q: "movein",
    pygame.K_PAGEDOWN: "moveout",
    pygame.K_e: "moveout",
    pygame.K_p: "pause",
    pygame.K_SPACE: "start",
    pygame.K_RETURN: "start",
    pygame.K_ESCAPE: "quit",
    pygame.K_1: "mode_head",
    pygame.K_2: "mode_strip",
    pygame.K_3: "mode_zone",
    pygame.K_4: "mode_autostereogram",
    pygame.K_LEFTBRACKET: "zone_prev",
    pygame.K_RIGHTBRACKET: "zone_next",
}

#: Gamepad button (SDL game-controller name; :mod:`game.pads` maps the pad's raw
#: button numbers to these names) -> action.
PAD_BUTTONS: dict[str, str] = {
    "dpup": "moveup",
    "dpdown": "movedown",
    "dpleft": "moveleft",
    "dpright": "moveright",
    "leftshoulder": "movein",
    "rightshoulder": "moveout",
    "start": "pause",
    "a": "start",
    "back": "quit",
}

#: Joystick hat direction -> move (d-pads that SDL reports as a hat).
HAT_BINDINGS: dict[tuple[int, int], str] = {
    (0, 1): "moveup",
    (0, -1): "movedown",
    (-1, 0): "moveleft",
    (1, 0): "moveright",
}

#: Stick axis (SDL game-controller name) -> (world axis, sign); sticks nudge
#: continuously.
PAD_AXES: dict[str, tuple[int, float]] = {
    "leftx": (0, 1.0),
    "lefty": (1, -1.0),
    "righty": (2, 1.0),
}

#: Dial index -> (world axis, world units per count).
DIAL_AXES: dict[int, tuple[int, float]] = {0: (0, 0.002), 1: (1, 0.002), 2: (2, 0.002)}

#: Dial-box button -> action (pressed edges only).
BUTTON_BINDINGS: dict[int, str] = {
    0: "moveleft",
    1: "moveright",
    2: "moveup",
    3: "movedown",
    4: "movein",
    5: "moveout",
    6: "pause",
}

STICK_DEAD_ZONE = 0.2
#: Stick speed at full deflection, world units per second.
STICK_SPEED = 0.8


def lamp_mask(bindings: dict[int, str] | None = None) -> int:
    """Lamp mask lighting every bound dial-box button (for ``holo-devices --lamps``)."""
    return sum(1 << b for b in (BUTTON_BINDINGS if bindings is None else bindings))


@dataclass
class Input:
    """What one tick's input asks for.

    Attributes
    ----------
    actions : list of str
        Discrete actions in the order they came.
    shift : ndarray, shape (3,)
        Continuous shift of the player's origin (world units).
    """

    actions: list[str] = field(default_factory=list)
    shift: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def merge(self, other: Input) -> Input:
        """The input ``self`` followed by ``other``."""
        return Input(self.actions + other.actions, self.shift + other.shift)


def _key(ev: pygame.event.Event) -> list[str]:
    return [KEY_BINDINGS[ev.key]] if ev.key in KEY_BINDINGS else []


#: pygame event type -> its discrete actions (pads: :class:`game.pads.Pads`).
EVENT_HANDLERS = {
    pygame.KEYDOWN: _key,
    pygame.QUIT: lambda ev: ["quit"],
}


def from_pygame(events: Iterable[pygame.event.Event]) -> Input:
    """Discrete actions from pygame events (keys, window close)."""
    actions: list[str] = []
    for ev in events:
        handler = EVENT_HANDLERS.get(ev.type)
        if handler is not None:
            actions.extend(handler(ev))
    return Input(actions)


def stick_shift(axes: Iterable[tuple[str, float]], dt: float) -> np.ndarray:
    """Continuous shift from stick positions held for ``dt`` seconds.

    Parameters
    ----------
    axes : iterable of (str, float)
        (SDL axis name, value from -1 to 1); names not in :data:`PAD_AXES` and values
        inside :data:`STICK_DEAD_ZONE` do nothing.
    dt : float
    """
    shift = np.zeros(3)
    for axis, value in axes:
        if axis in PAD_AXES and abs(value) > STICK_DEAD_ZONE:
            world, sign = PAD_AXES[axis]
            shift[world] += sign * value * STICK_SPEED * dt
    return shift


def _dial(ev: DialEvent) -> Input:
    if ev.index not in DIAL_AXES:
        return Input()
    world, gain = DIAL_AXES[ev.index]
    shift = np.zeros(3)
    shift[world] = ev.delta * gain
    return Input(shift=shift)


def _button(ev: ButtonEvent) -> Input:
    bound = ev.pressed and ev.index in BUTTON_BINDINGS
    return Input([BUTTON_BINDINGS[ev.index]] if bound else [])


#: device event class -> its input.
DEVICE_HANDLERS = {DialEvent: _dial, ButtonEvent: _button}


def from_devices(events: Iterable[object]) -> Input:
    """Input from ``DeviceSubscriber.take_events()`` (dials, buttons; others ignored)."""
    out = Input()
    for ev in events:
        handler = DEVICE_HANDLERS.get(type(ev))
        if handler is not None:
            out = out.merge(handler(ev))
    return out


#: Hat direction -> its name in :func:`binding_help`.
HAT_NAMES = {(0, 1): "hat up", (0, -1): "hat down", (-1, 0): "hat left", (1, 0): "hat right"}
AXIS_NAMES = "xyz"


def _grouped(pairs: Iterable[tuple[str, str]]) -> dict[str, list[str]]:
    """(input, action) pairs -> action -> its inputs, in the order first seen."""
    out: dict[str, list[str]] = {}
    for name, action in pairs:
        out.setdefault(action, []).append(name)
    return out


def _section(title: str, grouped: dict[str, list[str]]) -> list[str]:
    """A titled help section: one line per action, then its inputs."""
    return [f"{title}:", *(f"  {a:<26}  {', '.join(names)}" for a, names in grouped.items())]


def _shift_name(world: int, scale: float, unit: str) -> str:
    """A continuous move's name: ``along x (+0.002 per count)``."""
    return f"along {AXIS_NAMES[world]} ({scale:+g} {unit})"


def binding_help(notes: dict[str, str] | None = None) -> str:
    """Every binding, made from the tables above (``holo-game --help``'s epilog).

    Parameters
    ----------
    notes : dict, optional
        Action -> a remark printed after its name (``"not available"``).

    Returns
    -------
    str
        Sections ``keys:``, ``dial box:`` and ``gamepad:``; each line is an action
        (or a continuous move) followed by its inputs, comma-separated.
    """
    notes = notes or {}

    def named(grouped: dict[str, list[str]]) -> dict[str, list[str]]:
        return {(f"{a} ({notes[a]})" if a in notes else a): n for a, n in grouped.items()}

    keys = _grouped((pygame.key.name(k), a) for k, a in KEY_BINDINGS.items())
    dials = _grouped(
        (f"dial {i}", _shift_name(w, g, "per count")) for i, (w, g) in DIAL_AXES.items()
    )
    buttons = _grouped((f"button {b}", a) for b, a in BUTTON_BINDINGS.items())
    pad = _grouped([*PAD_BUTTONS.items(), *((HAT_NAMES[v], a) for v, a in HAT_BINDINGS.items())])
    sticks = _grouped(
        (name, _shift_name(w, s * STICK_SPEED, "per s")) for name, (w, s) in PAD_AXES.items()
    )
    lines = _section("keys", named(keys))
    lines += _section("dial box (lamps of bound buttons lit)", {**dials, **named(buttons)})
    lines += _section("gamepad (SDL game-controller names)", {**named(pad), **sticks})
    return "\n".join(lines)
