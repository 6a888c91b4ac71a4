"""What the peer scripts share: the cantilever's constants, the timestep search and the
report (one JSON object a run)."""

import json
import sys
from pathlib import Path

LENGTH, SIDE = 0.040, 0.010  # m
YOUNG, POISSON, DENSITY = 5000.0, 0.45, 1060.0  # Pa, -, kg/m^3
LOAD = 1e-4  # N, total, along -z
DAMPING = 28.0  # 1/s, mass-proportional (about twice the first bending mode's 14 rad/s)
TICK = 1e-3  # s; scalpel's bench ticks
# m, the converged 3D answer (tools/reference/fem_reference.py's stored result).
REFERENCE_TIP = json.loads(
    (Path(__file__).resolve().parents[2] / "reference" / "reference.json").read_text()
)["cantilever"]["tip_m"]
BLOWUP = 3.0 * 0.52e-3  # m: a tip beyond this (or NaN) means the timestep is unstable


def largest_stable(run, forced_dt):
    """Calls `run(dt)` -> (ok, result) at 1 ms / k for k = 1, 2, 3, ... (any whole number of
    sub-steps a tick, as scalpel takes) until a run stays stable; returns (dt, result)."""
    candidates = [forced_dt] if forced_dt else [TICK / k for k in range(1, 33)]
    for dt in candidates:
        ok, result = run(dt)
        if ok:
            return dt, result
        print(f"# dt = {dt * 1e3:g} ms unstable, trying a smaller one", file=sys.stderr)
    sys.exit("no stable timestep found")


def report(fields, history, wall, ticks, as_json):
    """Prints the run: `fields` (peer, version, sizes...), then its cost and its tip."""
    simulated = ticks * TICK
    tip = history[-1]
    ref = history[int(0.9 * len(history)) - 1]  # tip at 90 % of the run
    out = dict(fields)
    out.update(
        {
            "simulated_s": simulated,
            "wall_s": wall,
            "wall_s_per_simulated_s": wall / simulated,
            "tip_m": tip,
            "tip_over_reference": tip / REFERENCE_TIP,
            "tip_change_last_10pct": (tip - ref) / tip if tip else None,
            "settled": abs(tip - ref) < 1e-3 * abs(tip),  # moved < 0.1 % over the last 10 %
        }
    )
    if as_json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:>24}: {v}")
