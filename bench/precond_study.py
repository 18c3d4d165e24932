#!/usr/bin/env python3
# The preconditioner study of docs/static.md ("Preconditioner: the measurements"): PCG iteration
# counts and times on exported Newton Hessians for block Jacobi, smoothed-aggregation AMG with
# the six rigid-body modes, geometric multigrid with a lattice embedding, and affine-mode
# aggregation, each with a Chebyshev-Jacobi or a symmetric block Gauss-Seidel smoother.
#
# Reproduce (numpy, scipy and pyamg from python/requirements.txt):
#   ZONA_EXPORT_HESSIAN=/tmp/h ./build-cpu/apps/zona run mouse_oocyte --solver static \
#       --set mesh.generate.vertices=6000 --set needle.max_travel=6um --out /tmp/o --no-frames
#   .venv/bin/python bench/precond_study.py /tmp/h/step0000_iter000 /tmp/h/step0005_iter020 ...
# Each argument is a stem: STEM_H.mtx (the masked projected Hessian, 3 dofs per vertex) and
# STEM_xg.txt (per vertex: x y z gx gy gz fixed); the right-hand side is -g. Prints one CSV row
# per (matrix, method, smoother). The hierarchies are built here, in Python; pyamg is used only
# for the smoothed-aggregation prolongators and the block Gauss-Seidel sweep.
import argparse
import sys
import time

import numpy as np
import scipy.io
import scipy.linalg
import scipy.sparse as sp
import pyamg
from pyamg.relaxation.relaxation import block_gauss_seidel
from pyamg.aggregation import fit_candidates


def load(stem):
    a = scipy.io.mmread(stem + "_H.mtx")
    a = sp.csr_matrix(a)
    xg = np.loadtxt(stem + "_xg.txt")
    return a, xg[:, 0:3].copy(), -xg[:, 3:6].ravel(), xg[:, 6].astype(bool)


def block_diag_inverse(a):
    n = a.shape[0] // 3
    d = np.zeros((n, 3, 3))
    ab = sp.bsr_matrix(a, blocksize=(3, 3))
    ab.sort_indices()
    for i in range(n):
        lo, hi = ab.indptr[i], ab.indptr[i + 1]
        k = lo + np.searchsorted(ab.indices[lo:hi], i)
        d[i] = ab.data[k]
    return np.linalg.inv(d)


def apply_blocks(dinv, r):
    return np.einsum("nij,nj->ni", dinv, r.reshape(-1, 3)).ravel()


def lambda_max(a, dinv, iters=20, seed=0):
    # Power iteration on D^-1 A (self-adjoint in the A inner product).
    rng = np.random.default_rng(seed)
    v = rng.standard_normal(a.shape[0])
    lam = 0.0
    for _ in range(iters):
        w = apply_blocks(dinv, a @ v)
        lam = np.linalg.norm(w) / np.linalg.norm(v)
        v = w / np.linalg.norm(w)
    return lam


class Level:
    pass


class Chebyshev:
    """Chebyshev polynomial of degree k in D^-1 A on [lmax/ratio, 1.1 lmax] (D: 3x3 blocks)."""

    def __init__(self, a, degree=2, ratio=30.0):
        self.a, self.k = a, degree
        self.dinv = block_diag_inverse(a)
        lmax = 1.1 * lambda_max(a, self.dinv)
        self.lmin, self.lmax = lmax / ratio, lmax

    def smooth(self, x, b):
        # The classical three-term Chebyshev iteration (Saad, Alg. 12.1).
        theta, delta = 0.5 * (self.lmax + self.lmin), 0.5 * (self.lmax - self.lmin)
        sigma = theta / delta
        rho = 1.0 / sigma
        r = apply_blocks(self.dinv, b - self.a @ x)
        d = r / theta
        for _ in range(self.k):
            x = x + d
            r = r - apply_blocks(self.dinv, self.a @ d)
            rho_next = 1.0 / (2.0 * sigma - rho)
            d = rho_next * rho * d + 2.0 * rho_next / delta * r
            rho = rho_next
        return x

    pre = post = smooth


class BlockGaussSeidel:
    """One forward sweep before, one backward after: the V-cycle stays symmetric."""

    def __init__(self, a, sweeps=1):
        self.a = sp.bsr_matrix(a, blocksize=(3, 3))
        self.sweeps = sweeps
        self.dinv = block_diag_inverse(a)

    def pre(self, x, b):
        x = x.copy()
        block_gauss_seidel(self.a, x, b, iterations=self.sweeps, sweep="forward", blocksize=3,
                           Dinv=self.dinv)
        return x

    def post(self, x, b):
        x = x.copy()
        block_gauss_seidel(self.a, x, b, iterations=self.sweeps, sweep="backward", blocksize=3,
                           Dinv=self.dinv)
        return x


class Multigrid:
    def __init__(self, a, prolongators, smoother):
        self.levels = []
        for p in prolongators:
            lv = Level()
            lv.a, lv.p = a, sp.csr_matrix(p)
            lv.s = smoother(a)
            self.levels.append(lv)
            a = sp.csr_matrix(lv.p.T @ a @ lv.p)
        self.coarse = scipy.linalg.cho_factor(a.toarray())
        self.coarse_rows = a.shape[0]
        fine = self.levels[0].a.nnz if self.levels else a.nnz
        self.complexity = (sum(lv.a.nnz for lv in self.levels) + a.nnz) / fine

    def cycle(self, b, level=0):
        if level == len(self.levels):
            return scipy.linalg.cho_solve(self.coarse, b)
        lv = self.levels[level]
        x = lv.s.pre(np.zeros_like(b), b)
        x = x + lv.p @ self.cycle(lv.p.T @ (b - lv.a @ x), level + 1)
        return lv.s.post(x, b)


def pcg(a, b, apply, tols=(1e-2, 1e-6), max_iter=5000):
    x = np.zeros_like(b)
    r = b.copy()
    bn = np.linalg.norm(b)
    z = apply(r)
    p = z.copy()
    rz = r @ z
    hits = {}
    it = 0
    while it < max_iter:
        rn = np.linalg.norm(r) / bn
        for t in tols:
            if t not in hits and rn <= t:
                hits[t] = it
        if rn <= min(tols):
            break
        q = a @ p
        alpha = rz / (p @ q)
        x += alpha * p
        r -= alpha * q
        z = apply(r)
        rz_next = r @ z
        p = z + (rz_next / rz) * p
        rz = rz_next
        it += 1
    return [hits.get(t, -1) for t in tols], x


def _centred(x):
    """Positions about their centroid, scaled into [-1, 1]."""
    d = x - x.mean(axis=0)
    return d / np.abs(d).max()


def rigid_modes(x, fixed):
    d = _centred(x)
    n = x.shape[0]
    b = np.zeros((n, 3, 6))
    for k in range(3):
        b[:, k, k] = 1.0
    # Rotations: e_k x d.
    b[:, 1, 3], b[:, 2, 3] = -d[:, 2], d[:, 1]
    b[:, 0, 4], b[:, 2, 4] = d[:, 2], -d[:, 0]
    b[:, 0, 5], b[:, 1, 5] = -d[:, 1], d[:, 0]
    b[fixed] = 0.0
    return b.reshape(3 * n, 6)


def affine_modes(x, fixed):
    d = _centred(x)
    n = x.shape[0]
    b = np.zeros((n, 3, 12))
    for k in range(3):
        b[:, k, 4 * k] = 1.0
        b[:, k, 4 * k + 1:4 * k + 4] = d
    b[fixed] = 0.0
    return b.reshape(3 * n, 12)


def edge_length(a, x):
    ab = sp.coo_matrix(sp.bsr_matrix(a, blocksize=(3, 3)).tocsr()[::3, ::3])
    m = ab.row != ab.col
    return np.linalg.norm(x[ab.row[m]] - x[ab.col[m]], axis=1).mean()


def sa_prolongators(a, x, fixed, max_coarse):
    ml = pyamg.smoothed_aggregation_solver(
        sp.bsr_matrix(a, blocksize=(3, 3)), B=rigid_modes(x, fixed), symmetry="symmetric",
        strength=("symmetric", {"theta": 0.0}), aggregate="standard",
        smooth=("jacobi", {"omega": 4.0 / 3.0}), improve_candidates=None,
        max_coarse=max_coarse, max_levels=12, keep=False)
    return [lv.P for lv in ml.levels[:-1]]


def trilinear(points, origin, h, keep):
    # Interpolation from the lattice (origin, spacing h) to points: (points x lattice nodes).
    g = (points - origin) / h
    i0 = np.floor(g).astype(np.int64)
    f = g - i0
    dims = i0.max(axis=0) + 2
    rows, cols, vals = [], [], []
    for corner in range(8):
        o = np.array([(corner >> k) & 1 for k in range(3)])
        w = np.prod(np.where(o == 1, f, 1.0 - f), axis=1)
        idx = i0 + o
        lin = (idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]
        rows.append(np.arange(points.shape[0]))
        cols.append(lin)
        vals.append(w)
    rows, cols, vals = map(np.concatenate, (rows, cols, vals))
    m = (vals > 1e-12) & keep[rows]
    p = sp.csr_matrix((vals[m], (rows[m], cols[m])), shape=(points.shape[0], int(np.prod(dims))))
    used = np.unique(p.indices)
    p = p[:, used]
    # The coordinates of the kept lattice nodes.
    iz = used % dims[2]
    iy = (used // dims[2]) % dims[1]
    ix = used // (dims[1] * dims[2])
    nodes = origin + h * np.stack([ix, iy, iz], axis=1)
    return p, nodes


def lattice_prolongators(a, x, fixed, factor, max_coarse):
    h = factor * edge_length(a, x)
    points, keep = x, ~fixed
    ps = []
    while True:
        origin = points.min(axis=0) - 1e-9 * h
        p, nodes = trilinear(points, origin, h, keep)
        ps.append(sp.kron(p, sp.identity(3), format="csr"))
        points, keep = nodes, np.ones(nodes.shape[0], dtype=bool)
        if 3 * nodes.shape[0] <= max_coarse:
            return ps
        h *= 2.0


def voxel_aggregates(points, keep, size, min_members):
    # Vertices binned in cubes of side `size`; bins with fewer than min_members points join the
    # nearest bin that has enough.
    key = np.floor((points - points.min(axis=0)) / size).astype(np.int64)
    _, agg = np.unique(key, axis=0, return_inverse=True)
    agg = agg.ravel()
    agg[~keep] = -1
    counts = np.bincount(agg[agg >= 0])
    centres = np.stack([np.bincount(agg[agg >= 0], weights=points[agg >= 0, k])
                        for k in range(3)], axis=1) / np.maximum(counts, 1)[:, None]
    big = np.flatnonzero(counts >= min_members)
    small = np.isin(agg, np.flatnonzero(counts < min_members))
    if small.any():
        d = np.linalg.norm(points[small][:, None, :] - centres[big][None, :, :], axis=2)
        agg[small] = big[d.argmin(axis=1)]
    used, agg_k = np.unique(agg[agg >= 0], return_inverse=True)
    out = -np.ones_like(agg)
    out[agg >= 0] = agg_k
    m = out >= 0
    op = sp.csr_matrix((np.ones(m.sum()), (np.flatnonzero(m), out[m])),
                       shape=(points.shape[0], used.size))
    centres = (op.T @ points) / np.asarray(op.sum(axis=0)).ravel()[:, None]
    return op, centres


def affine_prolongators(a, x, fixed, factor, max_coarse):
    # Xian et al. 2019: vertices aggregated in space, 12 affine modes per aggregate,
    # unsmoothed; coarser levels aggregate the aggregates and keep the affine modes (the
    # candidates carried down by the per-aggregate QR).
    size = factor * edge_length(a, x)
    b = affine_modes(x, fixed)
    points, keep = x, ~fixed
    ps = []
    while True:
        agg, centres = voxel_aggregates(points, keep, size, 5)
        aggb = sp.csr_matrix(sp.kron(agg, np.ones((3, 1)), format="csr"))
        # fit_candidates wants (dofs x aggregates) with 3 dofs per node and blocks of 12.
        t, b = fit_candidates(sp.csr_matrix(aggb), b)
        ps.append(t)
        points, keep = centres, np.ones(centres.shape[0], dtype=bool)
        if t.shape[1] <= max_coarse:
            return ps
        size *= 2.0


def run_one(a, b, make, repeat_solve=False):
    t0 = time.perf_counter()
    pre = make()
    t1 = time.perf_counter()
    apply = pre if callable(pre) else pre.cycle
    its, x = pcg(a, b, apply)
    t2 = time.perf_counter()
    return pre, its, t1 - t0, t2 - t1, np.linalg.norm(a @ x - b) / np.linalg.norm(b)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("stems", nargs="+")
    ap.add_argument("--methods", default="jacobi,sa6,lattice,affine")
    ap.add_argument("--smoothers", default="cheb2,bgs")
    ap.add_argument("--max-coarse", type=int, default=600)
    ap.add_argument("--label", default="")
    args = ap.parse_args()
    print("matrix,label,vertices,method,smoother,levels,coarse_rows,complexity,"
          "setup_s,solve_s,iters_1e-2,iters_1e-6,final_rel_residual", flush=True)
    smoothers = {"cheb2": lambda m: Chebyshev(m, 2), "cheb3": lambda m: Chebyshev(m, 3),
                 "bgs": lambda m: BlockGaussSeidel(m, 1)}
    for stem in args.stems:
        a, x, b, fixed = load(stem)
        n = x.shape[0]
        builders = {
            "sa6": lambda: sa_prolongators(a, x, fixed, args.max_coarse),
            "lattice": lambda: lattice_prolongators(a, x, fixed, 2.0, args.max_coarse),
            "affine": lambda: affine_prolongators(a, x, fixed, 3.0, args.max_coarse),
        }
        for method in args.methods.split(","):
            if method == "jacobi":
                def make():
                    d = block_diag_inverse(a)
                    return lambda r: apply_blocks(d, r)
                _, its, ts, tv, res = run_one(a, b, make)
                print(f"{stem},{args.label},{n},jacobi,-,1,-,1.00,{ts:.2f},{tv:.2f},"
                      f"{its[0]},{its[1]},{res:.2e}", flush=True)
                continue
            t0 = time.perf_counter()
            ps = builders[method]()
            tp = time.perf_counter() - t0
            for sm in args.smoothers.split(","):
                mg, its, ts, tv, res = run_one(a, b, lambda: Multigrid(a, ps, smoothers[sm]))
                print(f"{stem},{args.label},{n},{method},{sm},{len(ps) + 1},{mg.coarse_rows},"
                      f"{mg.complexity:.2f},{tp + ts:.2f},{tv:.2f},{its[0]},{its[1]},{res:.2e}",
                      flush=True)


if __name__ == "__main__":
    sys.exit(main())
