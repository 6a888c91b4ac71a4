#!/usr/bin/env python3
"""MuJoCo flex peer for scalpel's cantilever accuracy bench (docs/BENCHMARKS.md, B5 body).

Same body as scalpel: box 40 x 10 x 10 mm, M nodes across the 10 mm sides, 4(M-1)+1 along x,
E = 5 kPa, nu = 0.45, rho = 1060 kg/m^3, root face (x = min) pinned, 0.1 mN along -z on the
tip face by tributary area, mass-proportional damping 28 1/s, 1 ms ticks, 1 s simulated.
Read-out: area-weighted mean downward displacement of the tip face. SI units throughout
(MuJoCo has none of its own, so metres / kg / s / N go in and come out unchanged).

What MuJoCo does with it (see the report in tools/bench/peers/README.md):
- flexcomp type="grid" dim="3" splits every grid cube into 6 linear tetrahedra (all sharing
  one body diagonal) and applies StVK elasticity on them;
- flexcomp gives every point the same mass, total/points, pinned points included (their share
  is lost; the moving mass is total x (1 - M^2/nodes));
- pinned points are not bodies at all: their flex vertices sit on the world body, so the clamp
  is exact;
- damping: MuJoCo refuses joint damping on flex vertex bodies ("cannot have joint damping; use
  flex elasticity or edge damping instead"), and those two are stiffness-proportional. So the
  mass-proportional damping comes from the global fluid viscosity with the inertia-box model:
  each node body feels -3 pi d mu v (d = its equivalent inertia box's mean side). Every node
  has the same mass and inertia box, so mu = 28 m / (3 pi d) gives exactly -28 m_i v_i per
  node (fluid density 0: no quadratic drag). Explicit under Euler; in the implicit metric
  under discrete.
- MuJoCo 4.0.0 fixed 3D StVK using 2x the Lame lambda; older releases are stiffer still.
"""
import argparse
import gc
import math
import sys
import time

import mujoco
import numpy as np

from common import BLOWUP, DAMPING, DENSITY, LENGTH, LOAD, POISSON, SIDE, TICK, YOUNG
from common import largest_stable, report

# MuJoCo's default warning handler also appends to MUJOCO_LOG.TXT in the working directory.
mujoco.set_mju_user_warning(lambda msg: print("MuJoCo warning:", msg, file=sys.stderr))


def build(m_across, integrator, solver, dt):
    """Compile the beam; returns (model, tip point ids, tip weights)."""
    nx = 4 * (m_across - 1) + 1
    s = SIDE / (m_across - 1)
    mass = DENSITY * LENGTH * SIDE * SIDE
    xml = f"""
<mujoco>
  <option timestep="{dt}" gravity="0 0 0" integrator="{integrator}" solver="{solver}">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <flexcomp name="beam" type="grid" dim="3" dof="full" count="{nx} {m_across} {m_across}"
              spacing="{s} {s} {s}" mass="{mass}" radius="{s / 20}">
      <elasticity young="{YOUNG}" poisson="{POISSON}"/>
      <pin gridrange="0 0 0 0 {m_across - 1} {m_across - 1}"/>
    </flexcomp>
  </worldbody>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    # Mass-proportional damping through linear fluid viscosity (see the module doc): the
    # equivalent box of a node body, as mj_inertiaBoxFluidModel computes it.
    node = model.flex_vertbodyid[-1]
    moving = model.flex_vertbodyid[model.flex_vertbodyid > 0]
    assert np.allclose(model.body_mass[moving], model.body_mass[node])  # one mu fits all
    mass_i, inertia = model.body_mass[node], model.body_inertia[node]
    box = [math.sqrt(max(1e-15, inertia.sum() - 2 * inertia[k]) / mass_i * 6) for k in range(3)]
    model.opt.viscosity = DAMPING * mass_i / (3 * math.pi * sum(box) / 3)
    model.opt.density = 0.0
    # point id = ix*M*M + iy*M + iz (user_flexcomp.cc MakeGrid); tip face is ix = nx-1.
    edge = np.ones(m_across)
    edge[[0, -1]] = 0.5  # tributary length: half at the face's edges, so corners get 1/4
    weights = np.outer(edge, edge).ravel()
    weights /= weights.sum()
    tip = (nx - 1) * m_across * m_across + np.arange(m_across * m_across)
    return model, tip, weights


def tip_sag(data, tip, weights, z0):
    """Area-weighted mean downward (-z) displacement of the tip face (m)."""
    return -float(weights @ (data.flexvert_xpos[tip, 2] - z0))


def run(m_across, ticks, integrator, solver, dt):
    model, tip, weights = build(m_across, integrator, solver, dt)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    z0 = data.flexvert_xpos[tip, 2].copy()  # rest heights of the tip nodes
    bodies = model.flex_vertbodyid[tip]
    data.xfrc_applied[bodies, 2] = -LOAD * weights  # constant tip load, by tributary area
    substeps = round(TICK / dt)
    # A full collection of the set-up objects would land in the timed loop (~0.1 s once).
    gc.freeze()
    history = []
    ok = True
    wall = 0.0
    for _ in range(ticks):
        start = time.perf_counter()
        mujoco.mj_step(model, data, nstep=substeps)  # one call a tick: no per-step overhead
        wall += time.perf_counter() - start  # time the stepping only, not the read-out
        sag = tip_sag(data, tip, weights, z0)
        history.append(sag)
        # MuJoCo resets the state (and warns) on a bad qpos/qvel/qacc rather than giving NaN.
        if not math.isfinite(sag) or abs(sag) > BLOWUP or any(
                data.warning[w].number for w in (mujoco.mjtWarning.mjWARN_BADQPOS,
                                                  mujoco.mjtWarning.mjWARN_BADQVEL,
                                                  mujoco.mjtWarning.mjWARN_BADQACC)):
            ok = False
            break
    return model, ok, wall, history, substeps


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--across", type=int, default=5)
    p.add_argument("--ticks", type=int, default=1000, help="1 ms ticks to simulate")
    # MuJoCo >= 4.0 refuses flex elasticity under implicit/implicitfast; "discrete" treats it
    # implicitly (effective metric M + hD + h^2 K, stable at 1 ms) but costs 1.5-2x Euler's
    # wall time at M = 3..9 even at Euler's 4-8 substeps per ms; RK4 is 3.7x Euler at M = 5.
    p.add_argument("--integrator", default="Euler", choices=["Euler", "discrete", "RK4"])
    p.add_argument("--solver", default="Newton", choices=["Newton", "CG"],
                   help="discrete needs a primal solver (CG or Newton); unused by Euler/RK4")
    p.add_argument("--dt", type=float, help="timestep (s); default: largest stable 1 ms / k")
    p.add_argument("--json", action="store_true")
    a = p.parse_args()

    def attempt(dt):
        model, ok, wall, history, substeps = run(a.across, a.ticks, a.integrator, a.solver, dt)
        return ok, (model, wall, history, substeps)

    dt, (model, wall, history, substeps) = largest_stable(attempt, a.dt)
    fields = {
        "peer": "mujoco-flex",
        "version": mujoco.__version__,
        "integrator": a.integrator,
        "solver": a.solver,
        "damping": "fluid viscosity, inertia-box model: -28 m_i v_i per node",
        "across": a.across,
        "nodes": a.across**2 * (4 * (a.across - 1) + 1),
        "elements": int(model.nflexelem),
        "timestep_s": dt,
        "substeps_per_ms": substeps,
    }
    report(fields, history, wall, a.ticks, a.json)


if __name__ == "__main__":
    main()
