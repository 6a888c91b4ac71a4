#!/usr/bin/env python3
"""Static linear-elastic P1 (4-node tet) FEM of the peers' cantilever, on each peer's own mesh.

Tells the discretisation (locking of linear tets at nu = 0.45, and the mesh's diagonal
pattern) apart from the dynamics: the peers' settled tips should match these numbers.
  --mesh kuhn6: MuJoCo flexcomp grid, 6 tets per cube sharing diagonal 0-7 (user_flexcomp.cc)
  --mesh warp5: warp.sim add_soft_grid, 5 tets per cube, alternating with cell parity
Dense solve: M = 9 needs ~0.5 GB and ~30 s.
"""
import argparse

import numpy as np

p = argparse.ArgumentParser()
p.add_argument("--across", type=int, default=5)
p.add_argument("--mesh", choices=["kuhn6", "warp5"], default="kuhn6")
a = p.parse_args()
M, E, nu = a.across, 5000.0, 0.45
nx, s = 4 * (M - 1) + 1, 0.010 / (M - 1)
lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def idx(x, y, z):
    return x * M * M + y * M + z  # x-major, as flexcomp numbers its points


X = np.array([[x * s, y * s, z * s] for x in range(nx) for y in range(M) for z in range(M)])
tets = []
for x in range(nx - 1):
    for y in range(M - 1):
        for z in range(M - 1):
            if a.mesh == "kuhn6":
                v = [idx(x, y, z), idx(x + 1, y, z), idx(x + 1, y + 1, z), idx(x, y + 1, z),
                     idx(x, y, z + 1), idx(x + 1, y, z + 1), idx(x + 1, y + 1, z + 1),
                     idx(x, y + 1, z + 1)]
                pattern = [[0, 3, 1, 7], [0, 1, 4, 7], [1, 3, 2, 7], [1, 2, 6, 7], [1, 5, 4, 7],
                           [1, 6, 5, 7]]
            else:  # add_soft_grid's corner order and its two 5-tet patterns
                v = [idx(x, y, z), idx(x + 1, y, z), idx(x + 1, y, z + 1), idx(x, y, z + 1),
                     idx(x, y + 1, z), idx(x + 1, y + 1, z), idx(x + 1, y + 1, z + 1),
                     idx(x, y + 1, z + 1)]
                pattern = ([[0, 1, 4, 3], [2, 3, 6, 1], [5, 4, 1, 6], [7, 6, 3, 4], [4, 1, 6, 3]]
                           if (x & 1) ^ (y & 1) ^ (z & 1) else
                           [[1, 2, 5, 0], [3, 0, 7, 2], [4, 7, 0, 5], [6, 5, 2, 7], [5, 2, 7, 0]])
            tets += [[v[k] for k in t] for t in pattern]

n = len(X)
K = np.zeros((3 * n, 3 * n))
D = np.zeros((6, 6))
D[:3, :3] = lam
D[range(3), range(3)] += 2 * mu
D[range(3, 6), range(3, 6)] = mu
for t in tets:
    A = np.hstack([np.ones((4, 1)), X[t]])
    g = np.linalg.inv(A)[1:, :]  # shape-function gradients, 3 x 4
    B = np.zeros((6, 12))
    for k in range(4):
        gx, gy, gz = g[:, k]
        B[:, 3 * k:3 * k + 3] = [[gx, 0, 0], [0, gy, 0], [0, 0, gz], [gy, gx, 0], [0, gz, gy],
                                 [gz, 0, gx]]
    dofs = np.array([[3 * i, 3 * i + 1, 3 * i + 2] for i in t]).ravel()
    K[np.ix_(dofs, dofs)] += abs(np.linalg.det(A)) / 6 * B.T @ D @ B

edge = np.ones(M)
edge[[0, -1]] = 0.5
w = np.outer(edge, edge).ravel()
w /= w.sum()
tip = (nx - 1) * M * M + np.arange(M * M)
f = np.zeros(3 * n)
f[3 * tip + 2] = -1e-4 * w
free = np.arange(3 * M * M, 3 * n)  # root face (x = 0) is the first M*M points
u = np.zeros(3 * n)
u[free] = np.linalg.solve(K[np.ix_(free, free)], f[free])
sag = -w @ u[3 * tip + 2]
print(f"{a.mesh} M={M} nodes={n} tets={len(tets)} tip_m={sag:.6e} "
      f"ratio to the 3D reference 0.5192 mm={sag / 0.5192e-3:.4f}")
