"""The whole loop (``make demo``): holo-service, holo-sim, holo-devices and holo-game.

Starts the render service, a simulated head tracker (swaying) and dial box
(scripted turns and presses) on pty pairs, the device driver publishing their
events (with the game's button lamps lit), and the game.  With a display the game
opens its window in attract mode until a key; without one the bot plays headless
for ``--seconds`` (20) and ``demo-out/`` gets screenshots of each mode, a film
strip, a GIF and ``stats.json``, and a summary is printed.  Every process started
here is stopped at the end, on Ctrl-C and on errors.  ``--local`` leaves the
service out (the game renders in process).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from game.actions import lamp_mask
from game.display import has_display, headless_env

ANY = "tcp://127.0.0.1:0"


class Proc:
    """A child process whose output lines are collected by threads.

    Parameters
    ----------
    name : str
    args : list of str
    env : dict, optional
    """

    def __init__(self, name: str, args: list[str], env: dict | None = None) -> None:
        self.name = name
        self.p = subprocess.Popen(
            args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
        )
        self.out: list[str] = []
        self.err: list[str] = []
        for stream, lines in ((self.p.stdout, self.out), (self.p.stderr, self.err)):
            threading.Thread(target=_pump, args=(stream, lines), daemon=True).start()

    def wait_line(self, lines: list[str], pred: Callable[[str], bool], timeout: float) -> str:
        """The first line satisfying ``pred``, polled until ``timeout`` seconds pass."""
        deadline = time.monotonic() + timeout
        tick = threading.Event()
        while time.monotonic() < deadline:
            found = next((ln for ln in list(lines) if pred(ln)), None)
            if found is not None:
                return found
            if self.p.poll() is not None:
                break
            tick.wait(0.02)
        raise RuntimeError(f"{self.name} did not start (rc={self.p.poll()}): {self.err[-5:]}")

    def stop(self, timeout: float = 5.0) -> None:
        """Terminate, then kill if it does not go."""
        if self.p.poll() is None:
            self.p.terminate()
            try:
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(timeout)


def _pump(stream: object, lines: list[str]) -> None:
    for line in stream:
        lines.append(line.rstrip("\n"))


def _script(name: str) -> list[str]:
    return [sys.executable, "-m", name]


def start_devices(procs: list[Proc], seconds: float) -> str:
    """holo-sim tracker and dial box on ptys, holo-devices publishing; returns its address."""
    tracker = Proc(
        "holo-sim tracker",
        [*_script("sim_devices.cli"), "tracker", "--pty", "--motion", "sway:scale=2"],
    )
    procs.append(tracker)
    dials = Proc(
        "holo-sim dials",
        [
            *_script("sim_devices.cli"),
            "dials",
            "--pty",
            "--seconds",
            str(seconds + 30),
            "--seed",
            "1",
        ],
    )
    procs.append(dials)
    t_path = tracker.wait_line(tracker.out, lambda ln: ln.startswith("/dev/"), 20)
    d_path = dials.wait_line(dials.out, lambda ln: ln.startswith("/dev/"), 20)
    devices = Proc(
        "holo-devices",
        [
            *_script("drivers.cli_devices"),
            "--tracker",
            t_path,
            "--dials",
            d_path,
            "--pub",
            ANY,
            "--reset-wait",
            "0.5",
            "--lamps",
            hex(lamp_mask()),
        ],
    )
    procs.append(devices)
    line = devices.wait_line(devices.err, lambda ln: "publishing on" in ln, 20)
    return line.split()[-1]


def start_service(procs: list[Proc]) -> str:
    """holo-service on free ports; returns its control address."""
    svc = Proc(
        "holo-service",
        [
            *_script("service.cli_service"),
            "--control",
            ANY,
            "--frames",
            ANY,
            "--worker-address",
            ANY,
        ],
    )
    procs.append(svc)
    line = svc.wait_line(svc.err, lambda ln: ln.startswith("holo-service: control"), 30)
    return line.split()[2]


def game_args(
    args: argparse.Namespace, control: str | None, devices: str, headless: bool
) -> list[str]:
    """The holo-game command line."""
    cmd = [
        *_script("game.cli"),
        "--devices",
        devices,
        "--bot",
        "--highscores",
        str(Path(args.out) / "highscores.json"),
    ]
    cmd += ["--local"] if control is None else ["--service", control]
    if headless:
        cmd += [
            "--headless",
            "--seconds",
            str(args.seconds),
            "--out",
            args.out,
            "--bot-gives-up",
            str(args.gives_up),
        ]
    return cmd


def main(argv: Sequence[str] | None = None) -> int:
    """Run the whole loop; returns the exit status."""
    ap = argparse.ArgumentParser(prog="holo-demo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="demo-out")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--gives-up", type=float, default=6.0, help="bot gives up after S s")
    ap.add_argument("--local", action="store_true", help="no service: render in the game")
    ap.add_argument("--headless", action="store_true", help="even with a display")
    args = ap.parse_args(argv)
    headless = args.headless or not has_display()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    procs: list[Proc] = []
    try:
        devices = start_devices(procs, args.seconds)
        control = None if args.local else start_service(procs)
        env = headless_env() if headless else None
        game = Proc("holo-game", game_args(args, control, devices, headless), env)
        procs.append(game)
        rc = game.p.wait(None if not headless else args.seconds + 120)
        if rc != 0:
            print(f"holo-demo: holo-game exited {rc}: {game.err[-5:]}", file=sys.stderr)
            return 1
        if headless:
            _summary(args.out, control)
        return 0
    except KeyboardInterrupt:
        return 130
    except (RuntimeError, subprocess.TimeoutExpired) as exc:
        print(f"holo-demo: {exc}", file=sys.stderr)
        return 1
    finally:
        for proc in reversed(procs):
            proc.stop()


def _summary(out: str, control: str | None) -> None:
    stats = json.loads((Path(out) / "stats.json").read_text())
    where = "in process (--local)" if control is None else f"holo-service at {control}"
    print(f"holo-demo: rendered {where}")
    print(
        f"  {stats['refreshes']} refreshes ({stats['refresh_hz']} Hz), {stats['renders']} "
        f"renders ({stats['update_hz']} Hz), window {stats['fps']} fps"
    )
    print(f"  score {stats['score']} over {stats['games']} games, beeps {stats['beeps']}")
    print(f"  tracker poses {stats['tracker_events']}, dial-box events {stats['dial_events']}")
    print(
        f"  modes {', '.join(stats['modes'])} (unavailable: "
        f"{', '.join(stats['modes_unavailable'])})"
    )
    print(f"  wrote {', '.join(stats.get('files', []))} and stats.json to {out}/")


if __name__ == "__main__":
    sys.exit(main())
