#!/usr/bin/env python3
"""XPBD FEM peer (NVIDIA Warp's warp.sim, CPU) for scalpel's cantilever accuracy bench.

Same body, load, damping and read-out as mujoco_cantilever.py (see there and README.md).
What Warp does with it:
- ModelBuilder.add_soft_grid splits every grid cube into 5 linear tetrahedra (alternating
  per cell), not MuJoCo's 6; the node count is the same grid.
- add_soft_grid gives every particle mass = density x cell volume, which over-counts the
  body; density is chosen so each particle gets total/nodes (as flexcomp does). fix_left
  sets the root face's mass to 0 (inverse mass 0): XPBD never moves them, an exact clamp.
- warp.sim's XPBDIntegrator launches `solve_tetrahedra`, which in 1.9.1 ignores the
  element's material (its k_mu/k_lambda lines are commented out; the compliance is the
  relaxation factor 0.9 whatever E is). The module's own `solve_tetrahedra2` is Macklin &
  Mueller's stable neo-Hookean constraint pair (deviatoric sqrt(tr F^T F), hydrostatic
  J - 1 - mu/lambda') with compliances 1/(mu V) and 1/(lambda' V); it is swapped in. Its
  lambda' = lambda + mu makes the small-strain limit linear elasticity with (E, nu).
- Neither kernel accumulates the XPBD multiplier across iterations, so extra iterations
  push towards rigid; one iteration per substep ("small steps") is the sound setting.
- damping: no particle damping exists in the XPBD integrator, so a small kernel writes
  f_i = f_ext,i - 28 m_i v_i into particle_f before each substep (explicit, exact force).
- float32 throughout (Warp's vec3).
"""
import argparse
import contextlib
import gc
import math
import sys
import time

import numpy as np
import warp as wp

wp.config.quiet = True
with contextlib.redirect_stdout(sys.stderr):  # its deprecation notice goes to stdout
    import warp.sim  # deprecated in 1.9, removed in 1.10: hence warp-lang 1.9.1
    import warp.sim.integrator_xpbd as xpbd

from common import BLOWUP, DAMPING, DENSITY, LENGTH, LOAD, POISSON, SIDE, TICK, YOUNG
from common import largest_stable, report

# The material-aware tet constraint (see the module doc); simulate() looks the name up at
# call time, so rebinding the module global is enough.
xpbd.solve_tetrahedra = xpbd.solve_tetrahedra2


@wp.kernel
def load_and_damp(v: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float),
                  f_ext: wp.array(dtype=wp.vec3), c: float, f: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    w = inv_mass[i]
    if w > 0.0:
        f[i] = f_ext[i] - v[i] * (c / w)
    else:
        f[i] = wp.vec3(0.0)


def build(m_across):
    nx = 4 * (m_across - 1) + 1
    s = SIDE / (m_across - 1)
    nodes = nx * m_across * m_across
    mu = YOUNG / (2 * (1 + POISSON))
    lam = YOUNG * POISSON / ((1 + POISSON) * (1 - 2 * POISSON))
    builder = wp.sim.ModelBuilder(up_vector=(0.0, 0.0, 1.0), gravity=0.0)
    builder.default_particle_radius = 0.0  # no particle-particle contacts
    builder.add_soft_grid(
        pos=wp.vec3(0.0), rot=wp.quat_identity(), vel=wp.vec3(0.0),
        dim_x=nx - 1, dim_y=m_across - 1, dim_z=m_across - 1, cell_x=s, cell_y=s, cell_z=s,
        density=DENSITY * LENGTH * SIDE * SIDE / nodes / s**3,  # -> total/nodes per particle
        k_mu=mu, k_lambda=lam + mu, k_damp=0.0, fix_left=True,
        tri_ke=0.0, tri_ka=0.0, tri_kd=0.0, tri_drag=0.0, tri_lift=0.0)
    model = builder.finalize(device="cpu")
    model.ground = False
    # particle id = nx*M*z + nx*y + x (add_soft_grid's grid_index); tip face is x = nx-1.
    edge = np.ones(m_across)
    edge[[0, -1]] = 0.5
    weights = np.outer(edge, edge).ravel()  # (z, y) order; symmetric anyway
    weights /= weights.sum()
    tip = np.array([nx * m_across * z + nx * y + nx - 1
                    for z in range(m_across) for y in range(m_across)])
    return model, tip, weights, nodes


def run(m_across, ticks, dt, iterations, relaxation):
    model, tip, weights, nodes = build(m_across)
    integrator = wp.sim.XPBDIntegrator(iterations=iterations, soft_body_relaxation=relaxation)
    a, b = model.state(), model.state()
    f_ext = np.zeros((model.particle_count, 3), dtype=np.float32)
    f_ext[tip, 2] = -LOAD * weights
    f_ext = wp.array(f_ext, dtype=wp.vec3, device="cpu")
    z0 = a.particle_q.numpy()[tip, 2].astype(np.float64)
    substeps = round(TICK / dt)
    # Warm-up on throwaway states: the first launch loads Warp's compiled kernel modules.
    scratch = model.state(), model.state()
    wp.launch(load_and_damp, dim=model.particle_count,
              inputs=[scratch[0].particle_qd, model.particle_inv_mass, f_ext, DAMPING],
              outputs=[scratch[0].particle_f], device="cpu")
    integrator.simulate(model, scratch[0], scratch[1], dt)
    # A full collection of the set-up objects would land in the timed loop (~0.1 s once).
    gc.freeze()
    history, ok, wall = [], True, 0.0
    for _ in range(ticks):
        start = time.perf_counter()
        for _ in range(substeps):
            wp.launch(load_and_damp, dim=model.particle_count,
                      inputs=[a.particle_qd, model.particle_inv_mass, f_ext, DAMPING],
                      outputs=[a.particle_f], device="cpu")
            integrator.simulate(model, a, b, dt)
            a, b = b, a
        wall += time.perf_counter() - start  # stepping only, not the read-out
        sag = -float(weights @ (a.particle_q.numpy()[tip, 2] - z0))
        history.append(sag)
        if not math.isfinite(sag) or abs(sag) > BLOWUP:
            ok = False
            break
    return model, ok, wall, history, substeps, nodes


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--across", type=int, default=5)
    p.add_argument("--ticks", type=int, default=1000, help="1 ms ticks to simulate")
    p.add_argument("--iterations", type=int, default=1, help="XPBD iterations per substep")
    p.add_argument("--relaxation", type=float, default=1.0, help="Jacobi delta scaling")
    p.add_argument("--dt", type=float, help="substep (s); default: largest stable 1 ms / k")
    p.add_argument("--json", action="store_true")
    a = p.parse_args()

    def attempt(dt):
        model, ok, wall, history, substeps, nodes = run(a.across, a.ticks, dt, a.iterations,
                                                        a.relaxation)
        return ok, (model, wall, history, substeps, nodes)

    dt, (model, wall, history, substeps, nodes) = largest_stable(attempt, a.dt)
    fields = {
        "peer": "xpbd-warp",
        "version": wp.config.version,
        "integrator": f"XPBD, {a.iterations} iteration(s)/substep, relaxation {a.relaxation}",
        "damping": "explicit particle force -28 m_i v_i",
        "across": a.across,
        "nodes": nodes,
        "elements": int(model.tet_count),
        "timestep_s": dt,
        "substeps_per_ms": substeps,
    }
    report(fields, history, wall, a.ticks, a.json)


if __name__ == "__main__":
    main()
