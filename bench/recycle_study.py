#!/usr/bin/env python3
# Krylov recycling for block-Jacobi PCG across a static run's Newton iterations (docs/static.md,
# "Cost", levers): each solve is deflated by the K lowest Ritz vectors of D^-1 H found so far (a
# Rayleigh-Ritz step over the last recycled space and the first STORE preconditioned residuals of
# the last solve, on the matrix of that solve), against plain block-Jacobi PCG, each to the
# forcing term the run used.
#
# Reproduce (numpy and scipy from python/requirements.txt):
#   ZONA_EXPORT_HESSIAN=/tmp/h ZONA_NEWTON_TRACE=1 ./build-cpu/apps/zona run mouse_oocyte \
#       --solver static --set needle.max_travel=3um --set puncture.criterion=none \
#       --headless --no-frames --quiet --out /tmp/o 2> /tmp/h.trace
#   .venv/bin/python bench/recycle_study.py /tmp/h /tmp/h.trace [--k 10] [--store 60]
# The export writes one STEM_H.mtx / STEM_xg.txt pair per Newton iteration in trace order (a
# projected Hessian only where an iteration redid its solve on it: then the pairing with the
# trace's forcing terms is off, and the script says so). Prints one CSV row per matrix and the
# totals.
import argparse
import glob
import os
import re
import sys

import numpy as np
import scipy.linalg
import scipy.sparse as sp


def load(stem):
    with open(stem + "_H.mtx") as f:
        f.readline()
        n = int(f.readline().split()[0])
        entries = np.loadtxt(f)
    i = entries[:, 0].astype(np.int64) - 1
    j = entries[:, 1].astype(np.int64) - 1
    lower = sp.csr_matrix((entries[:, 2], (i, j)), shape=(n, n))
    a = (lower + lower.T - sp.diags(lower.diagonal())).tocsr()
    b = -np.loadtxt(stem + "_xg.txt")[:, 3:6].ravel()
    return a, b


def diagonal_blocks(a):
    n = a.shape[0] // 3
    d = np.zeros((n, 3, 3))
    rows = np.arange(n) * 3
    for r in range(3):
        for c in range(3):
            d[:, r, c] = np.asarray(a[rows + r, rows + c]).ravel()
    return d


def block_apply(blocks, x):
    return np.einsum("nij,nj->ni", blocks, x.reshape(-1, 3)).ravel()


def pcg(a, b, dinv, tol, w=None, store=None, max_iter=20000):
    """Block-Jacobi PCG from zero (deflated by the columns of w where given); returns the
    iterations. store: a list that takes the normalised preconditioned residuals."""
    bn = np.linalg.norm(b)
    if w is not None:
        aw = a @ w
        e_inv = np.linalg.inv(w.T @ aw)
        x = w @ (e_inv @ (w.T @ b))
    else:
        x = np.zeros_like(b)
    r = b - a @ x
    z = block_apply(dinv, r)
    p = z if w is None else z - w @ (e_inv @ (aw.T @ z))
    rz = r @ z
    if store is not None:
        store.append(z / np.sqrt(rz))
    it = 0
    while np.linalg.norm(r) > tol * bn and it < max_iter:
        q = a @ p
        pq = p @ q
        if pq <= 0:
            break
        alpha = rz / pq
        x = x + alpha * p
        r = r - alpha * q
        z = block_apply(dinv, r)
        rz_next = r @ z
        p = z + (rz_next / rz) * p
        if w is not None:
            p = p - w @ (e_inv @ (aw.T @ z))
        rz = rz_next
        if store is not None:
            store.append(z / np.sqrt(rz))
        it += 1
    return it


def lowest_ritz(a, blocks, columns, k):
    q, _ = np.linalg.qr(np.column_stack(columns))
    t = q.T @ (a @ q)
    m = q.T @ np.einsum("nij,njk->nik", blocks, q.reshape(-1, 3, q.shape[1])).reshape(q.shape)
    values, vectors = scipy.linalg.eigh(0.5 * (t + t.T), 0.5 * (m + m.T))
    return q @ vectors[:, :k], values[:k]


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("folder")
    ap.add_argument("trace")
    ap.add_argument("--k", type=int, default=10, help="recycled Ritz vectors")
    ap.add_argument("--store", type=int, default=60, help="residuals kept per solve")
    args = ap.parse_args()
    stems = sorted({re.sub(r"_(H\.mtx|xg\.txt)$", "", f)
                    for f in glob.glob(os.path.join(args.folder, "step*"))})
    etas = [float(e) for e in re.findall(r"^newton iteration .* eta (\S+)",
                                         open(args.trace).read(), re.M)]
    if len(etas) != len(stems):
        sys.exit(f"{len(stems)} matrices against {len(etas)} traced Newton iterations")
    print("matrix,forcing,jacobi_cg,recycled_cg,lowest_ritz_value")
    w = None
    totals = [0, 0]
    for stem, eta in zip(stems, etas):
        a, b = load(stem)
        blocks = diagonal_blocks(a)
        dinv = np.linalg.inv(blocks)
        plain = pcg(a, b, dinv, eta)
        kept = []
        recycled = pcg(a, b, dinv, eta, w=w, store=kept)
        columns = ([w[:, c] for c in range(w.shape[1])] if w is not None else []) + kept[:args.store]
        w, values = lowest_ritz(a, blocks, columns, args.k)
        totals[0] += plain
        totals[1] += recycled
        print(f"{os.path.basename(stem)},{eta:.3g},{plain},{recycled},{values[0]:.3g}", flush=True)
    print(f"total,,{totals[0]},{totals[1]},")


if __name__ == "__main__":
    main()
