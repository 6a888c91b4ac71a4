#!/usr/bin/env python3
"""Converged 3D references for scalpel's validation bodies (issue 46).

Solves the benchmark bodies of `scalpel validate` with 27-node (triquadratic) hexahedra in
linear elasticity at several resolutions, and extrapolates to zero element size (Richardson,
with the order measured from the three finest levels). The bodies, loads and read-outs are the
ones in server/sim/src/validate:

* cantilever (B5): L = 40 mm, b = 10 mm square, E = 5 kPa, nu = 0.45, root face clamped, tip
  load 0.1 mN along -z as a uniform traction on the tip face; the read-out is the tip face's
  area-mean downward displacement (scalpel's point-volume-weighted face mean).
* slender cantilever (B5b): the same at L = 100 mm.
* punch (B14): the quarter of a block 8 punch radii wide and deep (a = 6 mm) on a fixed base,
  rollers on its two cut planes, a rigid frictionless flat punch pressed 2 % of a into it; the
  read-out is the whole punch's stiffness (N/mm). The grid is warped so a ring of nodes lies on
  the punch's rim; the rim's stress singularity keeps the observed order near 0.85.
* uniaxial (B3): a 20 x 10 x 10 mm block with sliding ends stretched by 1e-3; the read-outs are
  the end reaction and the Poisson ratio from the lateral strain. A homogeneous stretch lies in
  the element space, so the answer must be E*eps*A and nu at every level: this case proves the
  pipeline, not the physics.

Linear elasticity is the right reference for these loads: the cantilever's tip turns by about
1/80 rad, so the geometric nonlinearity it leaves out is below 1e-4 of the deflection.

Usage:
  fem_reference.py --out tools/reference/reference.json            # the full run (10 min, 7 GB)
  fem_reference.py --check tools/reference/reference.json --small  # CI: rerun the coarse
                                                                    # levels, compare
"""

import argparse
import json
import platform
import sys
import time

import numpy as np
import scipy
import skfem
from skfem import (
    Basis,
    ElementHex2,
    ElementVector,
    FacetBasis,
    LinearForm,
    MeshHex,
    asm,
    condense,
    solve,
)
from skfem.models.elasticity import lame_parameters, linear_elasticity

# The script's version: bump it when a body, a read-out or the extrapolation changes, so a
# stored result says which script made it.
SCRIPT_VERSION = 1

E_PA = 5000.0
NU = 0.45
LOAD_N = 1e-4
SIDE_M = 0.010
STRAIN = 1e-3

# Elements across the short side at each level. The full run goes to 10 across (a 40 x 10 x 10
# triquadratic mesh, 107 k unknowns, about 90 s and 4 GB); --small reruns the coarsest for CI.
FULL_LEVELS = [2, 3, 4, 6, 8, 10]
SMALL_LEVELS = [2, 3]
SLENDER_LEVELS = [1, 2, 3, 4, 6]
SMALL_SLENDER_LEVELS = [1, 2]
PUNCH_LEVELS = [1, 2, 3, 4]
SMALL_PUNCH_LEVELS = [1]


def box_mesh(lengths, per_axis):
    """A hex mesh of the box [0, Lx] x [-Ly/2, Ly/2] x [-Lz/2, Lz/2], triquadratic."""
    lx, ly, lz = lengths
    nx, ny, nz = per_axis
    mesh = MeshHex.init_tensor(
        np.linspace(0.0, lx, nx + 1),
        np.linspace(-0.5 * ly, 0.5 * ly, ny + 1),
        np.linspace(-0.5 * lz, 0.5 * lz, nz + 1),
    )
    return mesh


def stiffness(basis):
    lam, mu = lame_parameters(E_PA, NU)
    return asm(linear_elasticity(lam, mu), basis)


def solid(mesh):
    """The mesh's triquadratic vector basis, its stiffness matrix, the dofs of its three
    displacement components, and `where(component, test)`: a component's dofs whose place
    passes `test`."""
    basis = Basis(mesh, ElementVector(ElementHex2()), intorder=4)
    x = basis.doflocs

    def where(component, test):
        return component[test(x[:, component])]

    return basis, stiffness(basis), basis.split_indices(), where


def cantilever(length, across):
    """Tip face's mean downward displacement (m) with `across` elements on the short side."""
    along = int(round(across * length / SIDE_M))
    mesh = box_mesh((length, SIDE_M, SIDE_M), (along, across, across))
    basis = Basis(mesh, ElementVector(ElementHex2()), intorder=4)
    k = stiffness(basis)
    tip = mesh.facets_satisfying(lambda x: x[0] > length - 1e-12)
    tip_basis = FacetBasis(mesh, basis.elem, facets=tip, intorder=4)
    traction = -LOAD_N / (SIDE_M * SIDE_M)

    @LinearForm
    def load(v, w):
        return traction * v[2]

    f = asm(load, tip_basis)
    clamped = basis.get_dofs(lambda x: x[0] < 1e-12).all()
    u = solve(*condense(k, f, D=clamped))

    @LinearForm
    def mean_uz(v, w):
        return v[2]

    # Integral of u_z over the tip face, divided by its area.
    uz_integral = asm(mean_uz, tip_basis).dot(u)
    return -uz_integral / (SIDE_M * SIDE_M), basis.N


def uniaxial(across):
    """End reaction (N) and Poisson ratio of the sliding-end block stretched by STRAIN."""
    length = 2.0 * SIDE_M
    mesh = box_mesh((length, SIDE_M, SIDE_M), (2 * across, across, across))
    basis, k, (ux, uy, uz), where = solid(mesh)

    low = where(ux, lambda p: p[0] < 1e-12)
    high = where(ux, lambda p: p[0] > length - 1e-12)
    u_prescribed = np.zeros(basis.N)
    u_prescribed[high] = STRAIN * length
    # Rigid modes left by sliding ends: y and z at the low face's centre, z at its +y edge.
    centre = lambda p: (p[0] < 1e-12) & (np.abs(p[1]) < 1e-12) & (np.abs(p[2]) < 1e-12)
    edge = lambda p: (p[0] < 1e-12) & (p[1] > 0.5 * SIDE_M - 1e-12) & (np.abs(p[2]) < 1e-12)
    fixed = np.unique(
        np.concatenate([low, high, where(uy, centre), where(uz, centre), where(uz, edge)])
    )
    u = solve(*condense(k, np.zeros(basis.N), x=u_prescribed, D=fixed))
    reaction = (k @ u)[high].sum()
    # Lateral strain from the y faces' mean displacement.
    top = where(uy, lambda p: p[1] > 0.5 * SIDE_M - 1e-12)
    bottom = where(uy, lambda p: p[1] < -0.5 * SIDE_M + 1e-12)
    lateral = (u[top].mean() - u[bottom].mean()) / SIDE_M
    return reaction, -lateral / STRAIN, basis.N


PUNCH_RADIUS_M = 0.006
PUNCH_INDENTATION = 0.02


def punch_mesh(per_radius):
    """The quarter block of B14 (4a x 4a x 8a, the punch's axis on the x = y = 0 edge, its
    face at z = 0), `per_radius` elements per punch radius across, half as many per radius
    in depth. The grid is warped in x-y so that a ring of nodes lies on r = a: inside the
    max-norm square of side a, points move radially by max(x, y)/r, and the warp fades
    linearly to nothing at the block's sides."""
    a = PUNCH_RADIUS_M
    n = per_radius
    mesh = MeshHex.init_tensor(
        np.linspace(0.0, 4 * a, 4 * n + 1),
        np.linspace(0.0, 4 * a, 4 * n + 1),
        np.linspace(-8 * a, 0.0, 4 * n + 1),
    )
    p = mesh.p.copy()
    xy = p[:2]
    r = np.hypot(xy[0], xy[1])
    m = np.maximum(xy[0], xy[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        full = np.where(r > 0, m / r, 1.0)
    weight = np.clip((4 * a - np.maximum(m, a)) / (3 * a), 0.0, 1.0)
    weight = np.where(m <= a, 1.0, weight)
    p[:2] = xy * (weight * full + (1.0 - weight))
    return MeshHex(p, mesh.t)


def punch(per_radius):
    """The block's stiffness under the whole flat punch (N/mm): four times the quarter's
    reaction over the indentation. Frictionless: only u_z is prescribed under the punch."""
    a = PUNCH_RADIUS_M
    mesh = punch_mesh(per_radius)
    basis, k, (ux, uy, uz), where = solid(mesh)

    depth = PUNCH_INDENTATION * a
    base = np.concatenate([where(c, lambda q: q[2] < -8 * a + 1e-12) for c in (ux, uy, uz)])
    rollers = np.concatenate(
        [where(ux, lambda q: q[0] < 1e-12), where(uy, lambda q: q[1] < 1e-12)]
    )
    under = where(uz, lambda q: (q[2] > -1e-12) & (np.hypot(q[0], q[1]) < a * (1 + 1e-9)))
    u_prescribed = np.zeros(basis.N)
    u_prescribed[under] = -depth
    fixed = np.unique(np.concatenate([base, rollers, under]))
    u = solve(*condense(k, np.zeros(basis.N), x=u_prescribed, D=fixed))
    reaction = -(k @ u)[under].sum()
    return 4.0 * reaction / (depth * 1e3), basis.N


def richardson(levels, values):
    """Extrapolates values(h) to h = 0 from the three finest levels (h = 1/level).

    Returns (extrapolated, observed order, estimated error of the finest level)."""
    h = 1.0 / np.asarray(levels, dtype=float)
    v = np.asarray(values, dtype=float)
    (h1, h2, h3), (v1, v2, v3) = h[-3:], v[-3:]
    # Solve v = v0 + c h^p through the three points: p by bisection on the ratio.
    ratio = (v1 - v2) / (v2 - v3)

    def g(p):
        return (h1**p - h2**p) / (h2**p - h3**p) - ratio

    lo, hi = 0.2, 8.0
    if g(lo) * g(hi) > 0:
        raise ValueError(
            f"levels {levels[-3:]} give {values[-3:]}: no order in [{lo}, {hi}] fits, so "
            "they are not converging monotonically; add a finer level"
        )
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if g(lo) * g(mid) <= 0:
            hi = mid
        else:
            lo = mid
    p = 0.5 * (lo + hi)
    c = (v2 - v3) / (h2**p - h3**p)
    v0 = v3 - c * h3**p
    return v0, p, abs(v3 - v0) / abs(v0)


def extrapolated(sizes, values, key):
    """The extrapolated value under `key`, its order, the finest level's error, and the
    extrapolation's own uncertainty: how far the answer from the three levels before the
    finest lies from it (with four levels or more)."""
    v0, p, err = richardson(sizes, values)
    spread = None
    if len(sizes) >= 4:
        spread = abs(richardson(sizes[:-1], values[:-1])[0] / v0 - 1.0)
    return {
        key: v0,
        "observed_order": p,
        "finest_level_error": err,
        "extrapolation_spread": spread,
    }


def describe(fit):
    spread = fit["extrapolation_spread"] or 0.0
    return (
        f"order {fit['observed_order']:.2f}, finest level "
        f"{100 * fit['finest_level_error']:.3f} % off, spread {100 * spread:.3f} %"
    )


def timoshenko(length):
    inertia = SIDE_M**4 / 12.0
    area = SIDE_M * SIDE_M
    shear = E_PA / (2.0 * (1.0 + NU))
    kappa = 10.0 * (1.0 + NU) / (12.0 + 11.0 * NU)
    return LOAD_N * length**3 / (3.0 * E_PA * inertia) + LOAD_N * length / (
        kappa * shear * area
    )


def run_cantilever(name, length, levels, log):
    rows = []
    for n in levels:
        start = time.perf_counter()
        d, dofs = cantilever(length, n)
        wall = time.perf_counter() - start
        rows.append({"across": n, "unknowns": int(dofs), "tip_m": d, "wall_s": wall})
        log(f"{name}: {n} across, {dofs} unknowns, tip {d * 1e3:.6f} mm ({wall:.1f} s)")
    out = {
        "length_m": length,
        "side_m": SIDE_M,
        "load_n": LOAD_N,
        "levels": rows,
        "timoshenko_m": timoshenko(length),
    }
    if len(levels) >= 3:
        fit = extrapolated([r["across"] for r in rows], [r["tip_m"] for r in rows], "tip_m")
        v0 = fit["tip_m"]
        out.update(fit)
        out["timoshenko_over_reference"] = timoshenko(length) / v0
        log(
            f"{name}: extrapolated {v0 * 1e3:.6f} mm ({describe(fit)}), Timoshenko "
            f"{timoshenko(length) * 1e3:.6f} mm ({100 * (timoshenko(length) / v0 - 1):+.2f} %)"
        )
    return out


def run_uniaxial(levels, log):
    rows = []
    for n in levels:
        reaction, nu, dofs = uniaxial(n)
        rows.append({"across": n, "unknowns": int(dofs), "reaction_n": reaction, "nu": nu})
        log(f"uniaxial: {n} across, reaction {reaction:.9e} N, nu {nu:.9f}")
    expected = E_PA * STRAIN * SIDE_M * SIDE_M
    return {
        "strain": STRAIN,
        "levels": rows,
        "reaction_n": rows[-1]["reaction_n"],
        "nu": rows[-1]["nu"],
        "linear_reaction_n": expected,
        "note": "a homogeneous stretch is exact at every level: E*eps*A and nu",
    }


def run_punch(levels, log):
    rows = []
    for n in levels:
        start = time.perf_counter()
        k, dofs = punch(n)
        wall = time.perf_counter() - start
        rows.append({"per_radius": n, "unknowns": int(dofs), "stiffness_n_per_mm": k})
        log(f"punch: {n} per radius, {dofs} unknowns, {k:.6f} N/mm ({wall:.1f} s)")
    half_space = 2 * PUNCH_RADIUS_M * E_PA / (1 - NU**2) / 1e3
    out = {
        "radius_m": PUNCH_RADIUS_M,
        "indentation": PUNCH_INDENTATION,
        "block_radii": [4, 4, 8],
        "levels": rows,
        "half_space_n_per_mm": half_space,
    }
    if len(levels) >= 3:
        sizes = [r["per_radius"] for r in rows]
        ks = [r["stiffness_n_per_mm"] for r in rows]
        fit = extrapolated(sizes, ks, "stiffness_n_per_mm")
        v0 = fit["stiffness_n_per_mm"]
        out.update(fit)
        out["over_half_space"] = v0 / half_space
        log(
            f"punch: extrapolated {v0:.6f} N/mm ({describe(fit)}), half-space {half_space:.6f} N/mm "
            f"({100 * (v0 / half_space - 1):+.2f} %)"
        )
    return out


def compute(small, log):
    levels = SMALL_LEVELS if small else FULL_LEVELS
    slender = SMALL_SLENDER_LEVELS if small else SLENDER_LEVELS
    return {
        "script": "tools/reference/fem_reference.py",
        "script_version": SCRIPT_VERSION,
        "skfem": skfem.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "python": platform.python_version(),
        "element": "27-node hexahedron (ElementHex2), linear elasticity",
        "youngs_modulus_pa": E_PA,
        "poisson_ratio": NU,
        "cantilever": run_cantilever("cantilever", 0.040, levels, log),
        "slender_cantilever": run_cantilever("slender cantilever", 0.100, slender, log),
        "uniaxial": run_uniaxial([1, 2] if small else [1, 2, 3], log),
        "punch": run_punch(SMALL_PUNCH_LEVELS if small else PUNCH_LEVELS, log),
    }


def check(stored, fresh):
    """Every fresh level must match the stored level with the same size to 1e-8."""
    failures = []
    for case in ["cantilever", "slender_cantilever"]:
        by_level = {r["across"]: r for r in stored[case]["levels"]}
        for r in fresh[case]["levels"]:
            s = by_level.get(r["across"])
            if s is None:
                failures.append(f"{case}: level {r['across']} is not in the stored result")
            elif abs(r["tip_m"] / s["tip_m"] - 1.0) > 1e-8:
                failures.append(
                    f"{case}: level {r['across']} gives {r['tip_m']:.9e} m, stored "
                    f"{s['tip_m']:.9e} m"
                )
    by_level = {r["per_radius"]: r for r in stored["punch"]["levels"]}
    for r in fresh["punch"]["levels"]:
        s = by_level.get(r["per_radius"])
        k = r["stiffness_n_per_mm"]
        if s is None or abs(k / s["stiffness_n_per_mm"] - 1.0) > 1e-8:
            failures.append(f"punch: level {r['per_radius']} gives {k:.9e} N/mm, stored {s}")
    u = fresh["uniaxial"]
    if abs(u["reaction_n"] / u["linear_reaction_n"] - 1.0) > 1e-8 or abs(u["nu"] - NU) > 1e-8:
        failures.append(f"uniaxial: reaction {u['reaction_n']} N, nu {u['nu']}")
    if stored["script_version"] != SCRIPT_VERSION:
        failures.append(
            f"stored result is from script version {stored['script_version']}, "
            f"this is {SCRIPT_VERSION}: rerun the full script"
        )
    return failures


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", help="write the result (JSON) here")
    parser.add_argument("--check", help="compare with a stored result (JSON)")
    parser.add_argument("--small", action="store_true", help="the coarse levels only")
    args = parser.parse_args()

    def log(line):
        print(line, file=sys.stderr, flush=True)

    result = compute(args.small, log)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=2)
            f.write("\n")
        log(f"wrote {args.out}")
    if args.check:
        with open(args.check) as f:
            stored = json.load(f)
        failures = check(stored, result)
        for line in failures:
            log(f"MISMATCH {line}")
        if failures:
            sys.exit(1)
        log(f"the coarse levels match {args.check}")
    if not args.out and not args.check:
        json.dump(result, sys.stdout, indent=2)


if __name__ == "__main__":
    main()
