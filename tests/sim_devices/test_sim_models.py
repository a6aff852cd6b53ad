"""Motions, tracker and dial box simulators on their own (no links)."""

from __future__ import annotations

import pytest

from drivers.events import ButtonEvent, DialEvent, PoseEvent
from drivers.protocols import hatire, make_decoder
from drivers.protocols import sgi_dialbox as sgi
from service.base.errors import SettingsError
from sim_devices.dialbox import DialBoxSim, Press, Turn, demo_script
from sim_devices.motion import HeadTurn, Pose, Replay, Still, make_motion, parse_spec
from sim_devices.tracker import TrackerSim


def test_motions_are_deterministic_and_bounded():
    for spec in ("still", "sway", "turn", "walk"):
        a, b = make_motion(spec, seed=5, noise_deg=0.1), make_motion(spec, seed=5, noise_deg=0.1)
        ta = [a.pose(k / 60).as_tuple() for k in range(600)]
        assert ta == [b.pose(k / 60).as_tuple() for k in range(600)]
        assert all(abs(v) < 200 for pose in ta for v in pose)


def test_head_turn_reaches_amplitude_and_comes_back():
    m = HeadTurn(amplitude=45, turn_s=1, hold_s=0.5)
    assert m.pose(0).yaw == 0 and m.pose(1.2).yaw == pytest.approx(45)
    assert m.pose(2.7).yaw == pytest.approx(-45)


def test_replay_holds_and_loops():
    r = Replay([(0.0, Pose(yaw=1)), (0.5, Pose(yaw=2))])
    assert [r.pose(t).yaw for t in (0.0, 0.4, 0.6, 1.1)] == [1, 1, 2, 1]
    with pytest.raises(SettingsError):
        Replay([])


def test_spec_parsing_errors():
    assert parse_spec("turn:amplitude=30,turn_s=2") == ("turn", {"amplitude": 30.0,
                                                                 "turn_s": 2.0})
    for bad in ("fly", "turn:amplitude", "turn:amplitude=x", "turn:speed=3", "replay"):
        with pytest.raises(SettingsError):
            make_motion(bad)


@pytest.mark.parametrize("protocol", ["hatire", "native"])
def test_tracker_frames_decode_to_the_motion(protocol):
    sim = TrackerSim(protocol, Still(Pose(10, 20, 30, 1, 2, 3)), rate_hz=50)
    data = b"".join(make() for _t, make in sim.frames(1.0))
    events = make_decoder(protocol).feed(data, 0)
    assert [e.seq for e in events] == list(range(50))
    assert all(isinstance(e, PoseEvent) for e in events)
    assert (events[0].yaw, events[0].pitch, events[0].roll) == pytest.approx((10, 20, 30),
                                                                               abs=1e-4)
    assert (events[0].x, events[0].y, events[0].z) == (1, 2, 3)


def test_hatire_tracker_commands_and_big_endian():
    sim = TrackerSim("hatire", byte_order="big", autostart=False,
                     commands=hatire.HatireCommands(start=b"G", stop=b"H", reset=b"Z"))
    assert not sim.streaming
    reply = sim.receive(b"ZG")
    events = make_decoder("hatire", byte_order="big").feed(reply, 0)
    assert [e.details["meaning"] for e in events] == ["init", "start"]
    assert sim.streaming and sim.receive(b"H") == b"" and not sim.streaming
    with pytest.raises(SettingsError):
        TrackerSim("morse")


def test_dial_box_handshake_state_and_lamps():
    box = DialBoxSim([Turn(0, 1, 10)])
    assert not box.streaming and box.turn(1, 5) == [] and box.button(0, True) == b""
    reply = box.receive(b"".join(s.data for s in sgi.init_sequence()))
    assert reply == b"\x20\x20" and box.streaming and box.resets == 2
    box.receive(sgi.encode_lamps(1 << 31) + sgi.encode_filter(3, 5))
    assert box.lamp(31) and not box.lamp(0) and box.filters[3] == 5
    box.receive(sgi.encode_all_lamps(True))
    assert all(box.lamp(i) for i in range(32))
    box.receive(sgi.encode_all_lamps(False) + sgi.encode_enable_dials(0b10))
    assert box.lamps == 0 and box.turn(0, 5) == [] and box.turn(1, 5) != []


def test_dial_box_script_decodes_to_the_script():
    script = demo_script(seed=4, seconds=3.0)
    box = DialBoxSim(script, enabled=True)
    data = b"".join(make() for _t, make in box.frames())
    events = make_decoder("sgi").feed(data, 0)
    turns = [s for s in script if isinstance(s, Turn)]
    presses = [s for s in script if isinstance(s, Press)]
    totals = [sum(s.counts for s in turns if s.dial == d) for d in range(8)]
    finals = {e.index: e.value for e in events if isinstance(e, DialEvent)}
    assert all(finals.get(d, 0) == totals[d] for d in range(8))
    buttons = [e for e in events if isinstance(e, ButtonEvent)]
    assert len(buttons) == 2 * len(presses)


def test_the_default_dial_script_never_steers_or_pauses_the_game():
    from game.actions import DIAL_AXES
    from sim_devices.commands.holo_sim import build_parser
    from sim_devices.dialbox import DEFAULT_SCRIPT, SCRIPTS, VIEW_DIALS

    assert build_parser().parse_args(["dials"]).script == DEFAULT_SCRIPT == "view"
    script = SCRIPTS["view"](1, 60.0)
    assert script and all(isinstance(step, Turn) for step in script)  # no button pressed
    assert {step.dial for step in script} == set(VIEW_DIALS)
    assert not set(VIEW_DIALS) & set(DIAL_AXES)  # the game steers with none of them
    assert SCRIPTS["none"](1, 60.0) == []
    assert any(isinstance(step, Press) for step in SCRIPTS["random"](1, 60.0))
