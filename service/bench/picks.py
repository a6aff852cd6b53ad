"""What the benchmark report recommends, from the run's own numbers.

Plain functions over the rows the benchmarks wrote (no timing of their own):

* per occlusion case (scene, zone count) and light case: the **fastest exact**
  method (error 0 against the reference: ray casting, per-point Blinn) and the
  **cheapest within** :data:`BUDGET_PCT` % error;
* **when the Galilean stage pays**: one update (a render with motion, ``U`` ms) and
  ``k - 1`` refreshes (``F`` ms each) cost less than ``k`` plain renders (``R`` ms)
  once ``k > (U - F) / (R - F)``; never while a refresh costs as much as a render.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from service.bench.rows import zones_label

#: The error budget of "cheapest within": % of pixels (occlusion) or of full intensity.
BUDGET_PCT = 0.5
#: A benchmark that got less CPU than this share of its wall time ran on a busy machine.
BUSY_SHARE = 0.5


def busy_caveat(bench: str, seconds: float, cpu_s: float) -> str:
    """A sentence when ``bench`` ran on a busy machine (its timings then mislead), else "".

    Its process got under :data:`BUSY_SHARE` of the wall time on a CPU: other
    programs (or compiling) had the cores, and its milliseconds are not its own.
    """
    if seconds <= 0 or cpu_s >= BUSY_SHARE * seconds:
        return ""
    return (f" Caution: holo-bench {bench} got {cpu_s:.0f} s of CPU in {seconds:.0f} s of "
            "wall time (the machine was busy), so these speed picks may be wrong; run it "
            "again on a quiet machine before trusting them.")


@dataclass(frozen=True)
class Pick:
    """The two recommendations for one case of one stage.

    Attributes
    ----------
    stage, case : str
        E.g. ``"occlusion"``, ``"game, 5 zones"``.
    exact : tuple of (str, float) or None
        The fastest method with no error, and its ms; None when none was exact.
    within : tuple of (str, float, float) or None
        The cheapest method within the budget, its ms and error %; None when none was.
    """

    stage: str
    case: str
    exact: tuple[str, float] | None
    within: tuple[str, float, float] | None


def pick_case(stage: str, case: str, rows: list[dict], name: Callable[[dict], str],
              error_pct: Callable[[dict], float]) -> Pick:
    """The fastest exact and the cheapest within :data:`BUDGET_PCT` among ``rows`` (``ms``)."""
    scored = sorted(((r["ms"], name(r), error_pct(r)) for r in rows
                     if r.get("ms") is not None and r.get("ms") == r.get("ms")),
                    key=lambda t: t[0])
    exact = next(((n, ms) for ms, n, err in scored if err == 0.0), None)
    within = next(((n, ms, err) for ms, n, err in scored if err <= BUDGET_PCT), None)
    return Pick(stage, case, exact, within)


def _cases(rows: Iterable[dict], key: Callable[[dict], tuple]) -> dict[tuple, list[dict]]:
    out: dict[tuple, list[dict]] = {}
    for r in rows:
        out.setdefault(key(r), []).append(r)
    return out


def occlusion_picks(rows: list[dict]) -> list[Pick]:
    """One :class:`Pick` per (scene, zones) of ``holo-bench render``'s rows.

    Error: % of pixels whose visible polygon differs from ray casting (``pct_differ``).
    """
    return [pick_case("occlusion", f"{scene}, {zones_label(zones)}", group,
                      lambda r: r["method"], lambda r: float(r["pct_differ"]))
            for (scene, zones), group in _cases(rows, lambda r: (r["scene"], r["zones"])).items()]


def light_picks(rows: list[dict]) -> list[Pick]:
    """One :class:`Pick` per (scene, zones) of ``holo-bench light``'s rows.

    Error: mean absolute intensity difference from per-point Blinn, in % of full
    intensity (``100 * error``).
    """
    return [pick_case("light", f"{scene}, {zones_label(zones)}", group,
                      lambda r: f"{r['model']} per {r['evaluation']}",
                      lambda r: 100.0 * float(r["error"]))
            for (scene, zones), group in _cases(rows, lambda r: (r["scene"], r["zones"])).items()]


def tally(picks: list[Pick]) -> str:
    """One sentence per stage: which method wins each recommendation, in how many cases."""
    def count(items: list[str | None]) -> str:
        seen = [i for i in items if i is not None]
        if not seen:
            return f"none in any of {len(items)} cases"
        wins = sorted({i: seen.count(i) for i in seen}.items(), key=lambda kv: -kv[1])
        return ", ".join(f"{m} in {n}" for m, n in wins) + f" of {len(items)} cases"

    exact = count([p.exact[0] if p.exact else None for p in picks])
    within = count([p.within[0] if p.within else None for p in picks])
    return (f"{picks[0].stage.capitalize()}: the fastest exact method is {exact}; the "
            f"cheapest within {BUDGET_PCT:g} % error is {within}.")


def break_even_refreshes(step: dict) -> float:
    """Refreshes one update must serve for the Galilean stage to cost less than renders.

    ``(U - F) / (R - F)`` with ``U`` the update (``render_with_motion_ms``), ``F``
    a refresh and ``R`` a plain render; ``inf`` when a refresh costs a render or more.
    """
    render, refresh = step["render_ms"], step["refresh_ms"]
    if render <= refresh:
        return math.inf
    return max(1.0, (step["render_with_motion_ms"] - refresh) / (render - refresh))


def galilean_pays(complexity: dict, sweep: list[dict], order: int = 2) -> list[str]:
    """Sentences: from how many refreshes per update the stage pays, per scene size.

    Parameters
    ----------
    complexity : dict
        ``galilean_complexity.json`` (``steps`` of triangles and medians, ``size``,
        ``refresh_hz``).
    sweep : list of dict
        ``galilean_sweep.json``'s rows (order, interval, psnr): the image quality
        G(``order``) keeps at each interval, the price of reusing renders.
    """
    hz = float(complexity.get("refresh_hz", 60.0))
    steps = complexity.get("steps", [])
    if not steps:
        return []
    ks = [break_even_refreshes(s) for s in steps]
    parts = [f"with {s['triangles']:,} triangles "
             + ("never (a refresh costs as much as a render)" if math.isinf(k) else
                f"from {math.ceil(k)} refreshes per update")
             for s, k in zip(steps, ks, strict=True)]
    soonest = min(range(len(ks)), key=ks.__getitem__)
    lead = ("The Galilean stage does not pay at any size measured: a refresh costs as much "
            "as a render" if math.isinf(ks[soonest]) else
            f"The Galilean stage pays soonest with {steps[soonest]['triangles']:,} triangles: "
            f"one update serving {math.ceil(ks[soonest])} refreshes or more (an update every "
            f"{math.ceil(ks[soonest]) / hz:.2f} s at {hz:g} Hz) costs less than a render at "
            "each refresh")
    lines = [f"{lead}. G(2), {complexity.get('size', '?')}, one zone: " + "; ".join(parts)
             + "."]
    quality = psnr_by_interval(sweep, order)
    if quality:
        lines.append(f"What reuse costs in image quality: G({order})'s median PSNR over the "
                     "sweep's motions is " + ", ".join(f"{p:.1f} dB with an update every "
                                                      f"{i} refreshes" for i, p in quality)
                     + " (higher is better; a render at each refresh is exact).")
    return lines


def psnr_by_interval(sweep: list[dict], order: int) -> list[tuple[int, float]]:
    """(interval, median PSNR over the motions) of one order, intervals > 1 with a PSNR."""
    out = []
    for interval in sorted({r["interval"] for r in sweep if r["order"] == order}):
        ps = sorted(r["psnr"] for r in sweep if r["order"] == order
                    and r["interval"] == interval and r.get("psnr") is not None)
        if ps and interval > 1:
            out.append((interval, ps[len(ps) // 2]))
    return out
