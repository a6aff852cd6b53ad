"""``holo-bench targets``: the open speed targets, each a ratio measured side by side.

* ``zones``: stages 1-4 (project, cull, sort, occlusion) of 5 zones over 1 zone, the
  game scene, renders of both counts interleaved (target <= 2); the figure is the
  scene frozen, as before, and the scene moving as the game shows it is timed beside
  it (``ratio_moving``; see :func:`zones_target`).
* ``update``, ``update-g3``: ``render_with_motion`` (what every Galilean update
  costs: colour, depth, motion and colour derivatives) over ``Renderer.render``, the
  game scene at 5 zones x 240x180, Blinn, interleaved: the G(2) update (target <= 2)
  and the G(3) one, which also makes the jerk maps (target <= 2.5).
* ``refresh``: a G(2) refresh at 640x480 (one zone) after a head turn, so that
  every galpixel moves, beside a refresh of the same update without one (target
  <= 4 ms); both re-updated every 15 refreshes, as ``holo-bench galilean`` times
  them.
* ``floor``: the same two refreshes against the floor of memory traffic, a plain
  ``np.copyto`` of every array of the galpixmap they read into a map of the same
  shape, the copy and the refreshes interleaved; each refresh stated as a ratio to
  the copy (goal <= 2 after a head turn, <= 1.2 for a still scene; see
  :func:`floor_target`).
* ``premise``: the Galilean premise on the complexity scenes (the rotating cube plus
  a grid of spinning spheres): G(2) refresh ms at about 1k and 1M triangles (target
  ratio <= 1.2) and ``render_with_motion`` (the G(2) update) over a refresh at 100k
  triangles and more (target >= 10).

The refresh and premise targets run ``--rounds`` times (default 3): the speed of a
shared host drifts from one second to the next (the same head-turn refresh, in
separate processes a minute apart on an idle machine: medians 3.5 to 5.6 ms), so
each figure is the median round's and the JSON lists every round's.

Writes ``targets.json`` and ``targets.csv`` (one row per target: name, figure,
target, met) to ``--out``; the report collects them from there.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

from service.base.cli_args import add_size_option, exit_rule_epilog, int_range
from service.bench.galilean_bench import (
    HZ,
    REFRESHES_PER_UPDATE,
    _complexity_step,
    bench_scene,
    complexity_scene,
    head_turn,
)
from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.galilean.motion_field import render_with_motion
from service.galilean.stage import GalileanSettings, GalileanStage
from service.render.light import LightSettings
from service.render.pipeline import Renderer, RenderSettings, StageClock, warm_up
from service.scene_motion import advance_scene

STAGES_1_4 = ("project", "cull", "sort", "occlusion", "fallback")
#: The targets ``--only`` picks from, in the order they run.
TARGETS = ("zones", "update", "refresh", "floor", "premise")


def zones_target(size: tuple[int, int], repeats: int, scene_name: str = "game",
                 rounds: int = 5) -> dict:
    """Stages 1-4 ms of 5 zones and of 1 zone, side by side.

    Each round renders ``repeats`` frames of one count, then of the other (as
    :func:`service.bench.render_bench.zone_cost` does), so each count runs with its
    own buffers warm, as a render loop at that count would; ``figure`` is the ratio
    of the medians over all rounds, ``ratio_min`` that of the best frames (what an
    idle machine would show; a loaded one inflates memory-bound 5-zone passes most).

    The same scene frozen is rendered again and again there, and a CPU learns a
    repeated frame: one zone's z-buffer pass, the same branches every frame, ran
    2.7x faster than on a scene that moves (0.15 against 0.40 ms).  The ``moving``
    keys time the scene as the game shows it, moving along its own motion (16
    frames, 1/30 s apart, flattened before timing), in the same interleaved rounds.
    """
    scene = builtin_scene(scene_name)
    still = [scene.flatten()]
    moving = [advance_scene(scene, k / 30).flatten() for k in range(16)]
    displays = {z: DisplaySettings(zones=z, cols=size[0], rows=size[1]) for z in (1, 5)}
    r, s = Renderer(), RenderSettings()
    ms: dict[tuple, list[float]] = {}
    cpu: dict[tuple, list[float]] = {}  # process CPU ms: less hurt by a busy machine
    for _ in range(rounds):
        for kind, frames in (("still", still), ("moving", moving)):
            for z, d in displays.items():
                r.visibility(frames[0], d, s)  # not timed: the first after the other count
                for i in range(repeats):
                    clock: dict[str, float] = {}
                    c0 = time.process_time()
                    r.visibility(frames[i % len(frames)], d, s, StageClock(clock))
                    cpu.setdefault((kind, z), []).append((time.process_time() - c0) * 1e3)
                    ms.setdefault((kind, z), []).append(sum(clock.get(k, 0.0) for k in STAGES_1_4))
    med = {k: float(np.median(v)) for k, v in ms.items()}
    one, five = med["still", 1], med["still", 5]
    return {"target": "zones", "what": f"stages 1-4, 5 zones / 1 zone, {scene_name}, "
            f"{size[0]}x{size[1]}, medians", "ms_1": round(one, 3), "ms_5": round(five, 3),
            "ms_1_min": round(min(ms["still", 1]), 3), "ms_5_min": round(min(ms["still", 5]), 3),
            "ratio_min": round(min(ms["still", 5]) / min(ms["still", 1]), 3),
            "ratio_cpu": round(float(np.median(cpu["still", 5]) / np.median(cpu["still", 1])), 3),
            "ms_1_moving": round(med["moving", 1], 3), "ms_5_moving": round(med["moving", 5], 3),
            "ratio_moving": round(med["moving", 5] / med["moving", 1], 3),
            "ratio_moving_cpu": round(float(np.median(cpu["moving", 5])
                                            / np.median(cpu["moving", 1])), 3),
            "figure": round(five / one, 3), "goal": 2.0, "met": five / one <= 2.0}


def update_target(size: tuple[int, int], repeats: int, scene_name: str = "game",
                  rounds: int = 3) -> list[dict]:
    """``render_with_motion`` (a Galilean update) over ``Renderer.render``, side by side.

    The game scene (moving, as the game shows it), 5 zones, Blinn light per polygon:
    each round times ``repeats`` triples, a render then the G(2) update (velocity and
    acceleration maps) then the G(3) update (and jerk) of the same scene and time,
    in turn.  Per order a row: ``figure`` the ratio of the medians over all rounds,
    ``ratio_min`` that of the best calls, ``ratio_cpu`` that of the median process
    CPU time (goals 2 for G(2), 2.5 for G(3)).
    """
    scene = builtin_scene(scene_name)
    display = DisplaySettings(zones=5, cols=size[0], rows=size[1])
    r, s = Renderer(), RenderSettings(light=LightSettings("blinn"))
    calls = {"render": lambda sc: r.render(sc, display, s),
             2: lambda sc: render_with_motion(r, sc, display, 0.0, HZ, s, order=2),
             3: lambda sc: render_with_motion(r, sc, display, 0.0, HZ, s, order=3)}
    for f in calls.values():  # compiled and warm before timing
        f(scene)
    ms: dict = {k: [] for k in calls}
    cpu: dict = {k: [] for k in calls}
    for i in range(rounds * repeats):
        moved = advance_scene(scene, (i % 16) / 30)
        for k, f in calls.items():
            c0, t0 = time.process_time(), time.perf_counter()
            f(moved)
            ms[k].append((time.perf_counter() - t0) * 1e3)
            cpu[k].append((time.process_time() - c0) * 1e3)
    med = {k: float(np.median(v)) for k, v in ms.items()}
    rows = []
    for order, goal in ((2, 2.0), (3, 2.5)):
        ratio = med[order] / med["render"]
        rows.append({
            "target": "update" if order == 2 else "update-g3",
            "what": f"render_with_motion (G({order})) / Renderer.render, {scene_name} scene, "
                    f"5 zones, {size[0]}x{size[1]}, Blinn, ms, median",
            "ms_render": round(med["render"], 3), "ms_update": round(med[order], 3),
            "ratio_min": round(min(ms[order]) / min(ms["render"]), 3),
            "ratio_cpu": round(float(np.median(cpu[order]) / np.median(cpu["render"])), 3),
            "figure": round(ratio, 3), "goal": goal, "met": ratio <= goal})
    return rows


def _regraft(st: GalileanStage, up, head: bool) -> None:
    """Graft ``up`` at the next refresh (untimed), then the head turn if ``head``."""
    st.update(up, st.index)
    st.refresh()
    if head:  # after the graft: a viewer motion handed in before it is replaced by it
        st.viewer(head_turn())
        st.refresh()


def _refresh_stages(size: tuple[int, int]) -> tuple:
    """The rotating cube's update and two G(2) stages that grafted it: still and head turn.

    Returns ``(update, {False: still stage, True: head-turn stage})``.
    """
    display = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    up = render_with_motion(Renderer(), bench_scene("rotating-cube"), display, 0.0, HZ,
                            RenderSettings(light=LightSettings("blinn")))
    stages = {}
    for head in (False, True):
        # no order guard: the same update grafted again would look to it like a
        # scene that stood still, and it would fall back to G(0)
        st = GalileanStage(display, GalileanSettings(order=2, refresh_hz=HZ, threads=0,
                                                     order_guard=False))
        _regraft(st, up, head)
        stages[head] = st
    return up, stages


def refresh_target(size: tuple[int, int], repeats: int) -> dict:
    """G(2) refresh ms with every galpixel moving (head turn) and without, interleaved.

    Both stages get the update again (untimed) every :data:`REFRESHES_PER_UPDATE`
    refreshes, as ``holo-bench galilean`` and the premise steps time them: the
    timed refreshes are 1-15 refreshes old, within the rated propagation time
    (``n_prop`` 16).  A map left to age past it (45 refreshes, as this target
    once timed) costs more each refresh, 6.5 -> 10 ms CPU from age 2 to 48 after
    a head turn: the holes it leaves grow into debris and expansions.
    """
    up, stages = _refresh_stages(size)
    ms: dict[bool, list[float]] = {False: [], True: []}
    cpu: dict[bool, list[float]] = {False: [], True: []}
    for i in range(repeats):
        for head, st in stages.items():
            if i and i % REFRESHES_PER_UPDATE == 0:
                _regraft(st, up, head)
            c0, t0 = time.process_time(), time.perf_counter()
            st.refresh()
            ms[head].append((time.perf_counter() - t0) * 1e3)
            cpu[head].append((time.process_time() - c0) * 1e3)
    moving, still = float(np.median(ms[True])), float(np.median(ms[False]))
    return {"target": "refresh", "what": f"G(2) refresh, every galpixel moving, "
            f"{size[0]}x{size[1]}, ms, median", "ms_still": round(still, 3),
            "ms_moving": round(moving, 3), "ms_still_min": round(min(ms[False]), 3),
            "ms_moving_min": round(min(ms[True]), 3),
            "cpu_ms_moving": round(float(np.median(cpu[True])), 3),
            "cpu_ms_still": round(float(np.median(cpu[False])), 3), "figure": round(moving, 3),
            "goal": 4.0, "met": moving <= 4.0}


def _map_arrays(gp) -> list[np.ndarray]:
    """The arrays of a galpixmap (every field that is one)."""
    return [a for a in (getattr(gp, f.name) for f in fields(gp)) if isinstance(a, np.ndarray)]


def _copy_and_refreshes(stages: dict, up, src: list[np.ndarray], repeats: int) -> tuple:
    """Median wall and CPU ms of a copy of ``src`` and of each stage's refresh, in turn.

    Returns
    -------
    ms, cpu_ms : dict
        Keyed ``"copy"`` and each key of ``stages`` (head turn or not).
    """
    dst = [np.empty_like(a) for a in src]

    def copy() -> None:
        for d, a in zip(dst, src, strict=True):
            np.copyto(d, a)

    ms: dict = {k: [] for k in ("copy", *stages)}
    cpu: dict = {k: [] for k in ms}
    for i in range(repeats):
        for head, st in stages.items():
            if i and i % REFRESHES_PER_UPDATE == 0:
                _regraft(st, up, head)
            for key, call in (("copy", copy), (head, st.refresh)):
                c0, t0 = time.process_time(), time.perf_counter()
                call()
                ms[key].append((time.perf_counter() - t0) * 1e3)
                cpu[key].append((time.process_time() - c0) * 1e3)
    return ({k: float(np.median(v)) for k, v in ms.items()},
            {k: float(np.median(v)) for k, v in cpu.items()})


def floor_target(size: tuple[int, int], repeats: int) -> list[dict]:
    """Each G(2) refresh of :func:`refresh_target` over a plain copy of its galpixmap.

    A refresh reads the old map and writes the new one, so a copy of the map (every
    array, ``np.copyto`` into a map of the same shape, one thread) is about the least
    it can cost.  The copy, the still refresh, the copy again and the head-turn
    refresh are timed in turn, ``repeats`` times; each refresh's ratio is its median
    ms over the copy's median ms (CPU time beside it).

    Returns
    -------
    list of dict
        ``floor-head-turn`` (goal <= 2) and ``floor-still`` (goal <= 1.2).
    """
    up, stages = _refresh_stages(size)
    src = _map_arrays(stages[True].map)
    med, cmed = _copy_and_refreshes(stages, up, src, repeats)
    mb = sum(a.nbytes for a in src) / 1e6
    rows = []
    for head, name, goal, case in ((True, "floor-head-turn", 2.0, "after a head turn"),
                                   (False, "floor-still", 1.2, "of a still scene")):
        ratio = med[head] / med["copy"]
        rows.append({"target": name, "what": f"G(2) refresh {case} / np.copyto of its "
                     f"{mb:.1f} MB galpixmap, {size[0]}x{size[1]}, medians",
                     "ms_refresh": round(med[head], 3), "ms_copy": round(med["copy"], 3),
                     "cpu_ms_refresh": round(cmed[head], 3), "cpu_ms_copy": round(cmed["copy"], 3),
                     "ratio_cpu": round(cmed[head] / cmed["copy"], 3), "map_mb": round(mb, 2),
                     "figure": round(ratio, 3), "goal": goal, "met": ratio <= goal})
    return rows


def premise_target(size: tuple[int, int], repeats: int,
                   counts: tuple[int, ...] = (1_000, 100_000, 1_000_000)) -> list[dict]:
    """Refresh ms flat in triangles, and render_with_motion / refresh at >= 100k."""
    display = DisplaySettings(zones=1, cols=size[0], rows=size[1])
    settings = RenderSettings(light=LightSettings("blinn"))
    r, steps = Renderer(), []
    for extra in counts:
        scene = complexity_scene(extra, display)
        print(f"targets: premise, {extra} triangles", file=sys.stderr, flush=True)
        steps.append(_complexity_step(r, scene, display, settings, repeats))
    first, last = steps[0], steps[-1]
    flat = last["refresh_ms"] / first["refresh_ms"]
    # steps asked for 100k triangles or more (the scene's grid lands a little short)
    big = [s for s, extra in zip(steps, counts, strict=True) if extra >= 100_000]
    worst = min(s["update_ratio"] for s in big) if big else None
    where = f"{size[0]}x{size[1]}, one zone"
    # the same ratios of the best calls and of the CPU time (a loaded machine)
    over = {k: lambda s, k=k: s[f"render_with_motion_{k}"] / s[f"refresh_{k}"]
            for k in ("ms_min", "cpu_ms")}
    return [
        {"target": "premise-flat", "what": f"G(2) refresh ms at {last['triangles']} / "
         f"{first['triangles']} triangles, {where}",
         "refresh_ms": [round(s["refresh_ms"], 3) for s in steps],
         "refresh_ms_min": [round(s["refresh_ms_min"], 3) for s in steps],
         "refresh_cpu_ms": [round(s["refresh_cpu_ms"], 3) for s in steps],
         "moving_pct": [round(s["moving_pct"], 1) for s in steps],
         "ratio_min": round(last["refresh_ms_min"] / first["refresh_ms_min"], 3),
         "ratio_cpu": round(last["refresh_cpu_ms"] / first["refresh_cpu_ms"], 3),
         "triangles": [s["triangles"] for s in steps], "figure": round(flat, 3),
         "goal": 1.2, "met": flat <= 1.2},
        {"target": "premise-10x", "what": f"render_with_motion / G(2) refresh, worst of the "
         f"steps of 100k triangles and more, {where}",
         "update_ms": [round(s["render_with_motion_ms"], 3) for s in big],
         "refresh_ms": [round(s["refresh_ms"], 3) for s in big],
         "update_cpu_ms": [round(s["render_with_motion_cpu_ms"], 3) for s in big],
         "refresh_cpu_ms": [round(s["refresh_cpu_ms"], 3) for s in big],
         "ratio_min": round(min(map(over["ms_min"], big)), 3) if big else None,
         "ratio_cpu": round(min(map(over["cpu_ms"], big)), 3) if big else None,
         "triangles": [s["triangles"] for s in big],
         "figure": None if worst is None else round(worst, 3), "goal": 10.0,
         "met": worst is not None and worst >= 10.0},
    ]


def median_round(rounds: list[list[dict]]) -> list[dict]:
    """Of each target's rows from several rounds, the row of its median figure.

    Parameters
    ----------
    rounds : list of list of dict
        One list of target rows per round, the same targets in the same order.

    Returns
    -------
    list of dict
        Per target, the row of the round whose figure is the median (the lower of
        the two middle ones for an even count; rounds without a figure last), with
        ``rounds``: every round's figure, in the order run.  The row's other keys
        are that round's, so they agree with its figure.
    """
    out = []
    for rows in zip(*rounds, strict=True):
        ranked = sorted(rows, key=lambda r: (r["figure"] is None, r["figure"] or 0.0))
        pick = ranked[(len(ranked) - 1) // 2]
        out.append({**pick, "rounds": [r["figure"] for r in rows]})
    return out


def write(rows: list[dict], out: Path) -> None:
    """``targets.json`` (everything) and ``targets.csv`` (name, figure, goal, met, what)."""
    (out / "targets.json").write_text(json.dumps(rows, indent=1))
    with (out / "targets.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["target", "figure", "goal", "met", "what"])
        for r in rows:
            w.writerow([r["target"], r["figure"], r["goal"], r["met"], r["what"]])


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The options of ``holo-bench targets``."""
    p = argparse.ArgumentParser(
        prog="holo-bench targets",
        description="The open speed targets (zones, update, G(2) refresh, Galilean premise), "
        "each a ratio measured side by side in one run; writes targets.json and targets.csv.",
        epilog=exit_rule_epilog(),
    )
    p.add_argument("--out", metavar="DIR", default="bench-out",
                   help="output folder (default bench-out)")
    p.add_argument("--only", choices=TARGETS, action="append",
                   help="run just these targets (repeatable; default all)")
    add_size_option(p, (640, 480), "display of the refresh and premise targets")
    add_size_option(p, (320, 240), "display of the zones target", flag="--zone-size")
    add_size_option(p, (240, 180), "display of the update target", flag="--update-size")
    p.add_argument("--repeats", metavar="N", type=int_range(1, 1000), default=15,
                   help="interleaved repeats per target (default 15)")
    p.add_argument("--rounds", metavar="N", type=int_range(1, 100), default=3,
                   help="rounds of the refresh and premise targets (default 3; --quick: "
                   "1); each figure is the median round's, every round's in the JSON: "
                   "a shared host's speed drifts between seconds")
    p.add_argument("--quick", action="store_true",
                   help="premise up to 100k triangles only, 7 repeats, one round")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the targets; print one line each."""
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warm_up(RenderSettings())
    reps = 7 if args.quick else args.repeats
    only = set(args.only or TARGETS)
    rows: list[dict] = []
    if "zones" in only:
        rows.append(zones_target(args.zone_size, reps))
    rounds = 1 if args.quick else args.rounds
    if "update" in only:
        rows += update_target(args.update_size, reps, rounds=rounds)
    if "refresh" in only:
        rows += median_round([[refresh_target(args.size, reps * 3)] for _ in range(rounds)])
    if "floor" in only:
        rows += median_round([floor_target(args.size, reps * 3) for _ in range(rounds)])
    if "premise" in only:
        counts = (1_000, 100_000) if args.quick else (1_000, 100_000, 1_000_000)
        rows += median_round([premise_target(args.size, reps, counts) for _ in range(rounds)])
    write(rows, out)
    for r in rows:
        print(summary(r))
    return 0


def summary(r: dict) -> str:
    """One line for a target row: its figure, the side figures it has, goal, met."""
    extra = ""
    if "ratio_min" in r:
        extra = f" (best frames {r['ratio_min']}, CPU time {r['ratio_cpu']}"
        if "ratio_moving" in r:
            extra += f"; scene moving {r['ratio_moving']}, CPU time {r['ratio_moving_cpu']}"
        extra += ")"
    if "ms_copy" in r:
        extra += (f" (refresh {r['ms_refresh']} ms, copy {r['ms_copy']} ms; CPU time "
                  f"{r['ratio_cpu']})")
    if "ms_moving_min" in r:
        extra += f" (best {r['ms_moving_min']} ms, CPU {r['cpu_ms_moving']} ms)"
    if len(r.get("rounds", ())) > 1:
        extra += f" (rounds {', '.join(str(x) for x in r['rounds'])})"
    return (f"{r['target']:13s} {r['figure']}{extra} (goal {r['goal']}) "
            f"{'met' if r['met'] else 'NOT met'}: {r['what']}")
