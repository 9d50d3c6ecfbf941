#!/usr/bin/env python3
"""The conditioning measurements behind docs/realtime.md, on a frame exported by hessian_export.

  hessian_spectrum.py FRAME.bin            the slowest modes of the projected Hessian relative to each particle's own
                                           3 x 3 block, and what moves in each
  hessian_spectrum.py FRAME.bin --newton   the exact Newton step from the exported state (how far it is from the
                                           minimum), and how much of it two-level cycles (Gauss-Seidel plus a coarse
                                           correction by slabs along the fibres) recover

The Hessian is the one block descent uses: each spring's k [u u^T + max(0, 1 - l0/l) (I - u u^T)], touching bone
contacts and muscle pairs as stiff one-sided springs (100 x the particle's summed spring stiffness). Needs numpy and
scipy (Debian: python3-numpy, python3-scipy)."""
import argparse
import struct

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla


def load(path):
    data = open(path, "rb").read()
    offset = 0
    particles, springs = struct.unpack_from("<qq", data, offset)
    offset += 16
    particle_type = np.dtype([("fixed", "u1"), ("muscle", "<i4"), ("fibre", "<i4"), ("sample", "<i4"),
                              ("x", "<f8", 3), ("rest", "<f8", 3), ("radius", "<f8")])
    p = np.frombuffer(data, particle_type, particles, offset)
    offset += particles * particle_type.itemsize
    spring_type = np.dtype([("a", "<i4"), ("b", "<i4"), ("k", "<f8"), ("l", "<f8")])
    s = np.frombuffer(data, spring_type, springs, offset)
    offset += springs * spring_type.itemsize
    count, = struct.unpack_from("<q", data, offset)
    offset += 8
    half_type = np.dtype([("p", "<i4"), ("n", "<f8", 3)])
    half_spaces = np.frombuffer(data, half_type, count, offset)
    offset += count * half_type.itemsize
    count, = struct.unpack_from("<q", data, offset)
    offset += 8
    pairs = np.frombuffer(data, np.dtype([("a", "<i4"), ("b", "<i4"), ("d", "<f8")]), count, offset)
    return p, s, half_spaces, pairs


class Frame:
    def __init__(self, path):
        self.p, self.s, half_spaces, pairs = load(path)
        x = self.p["x"]
        self.free = self.p["fixed"] == 0
        self.index = -np.ones(len(x), int)
        self.index[self.free] = np.arange(self.free.sum())
        a, b, k, rest = self.s["a"], self.s["b"], self.s["k"], self.s["l"]
        d = x[a] - x[b]
        length = np.linalg.norm(d, axis=1)
        u = d / length[:, None]
        transverse = np.maximum(0.0, 1.0 - rest / length)
        blocks = k[:, None, None] * ((1 - transverse)[:, None, None] * u[:, :, None] * u[:, None, :]
                                     + transverse[:, None, None] * np.eye(3)[None])
        spring_sum = np.zeros(len(x))
        np.add.at(spring_sum, a, k)
        np.add.at(spring_sum, b, k)
        contact_k = 100.0 * spring_sum
        self.rows, self.cols, self.vals = [], [], []
        self._pair(a, b, blocks)
        if len(half_spaces):
            n = half_spaces["n"]
            q = half_spaces["p"]
            self._add(q, q, contact_k[q][:, None, None] * n[:, :, None] * n[:, None, :], 1.0)
        if len(pairs):
            qa, qb = pairs["a"], pairs["b"]
            dd = x[qa] - x[qb]
            uu = dd / np.linalg.norm(dd, axis=1)[:, None]
            kk = np.maximum(contact_k[qa], contact_k[qb])
            self._pair(qa, qb, kk[:, None, None] * uu[:, :, None] * uu[:, None, :])
        n = 3 * int(self.free.sum())
        self.hessian = sp.csr_matrix((np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))),
                                     shape=(n, n))
        # Net spring force on every free particle (contacts balance only where they touch).
        f = (k * (length - rest) / length)[:, None] * d
        force = np.zeros_like(x)
        np.add.at(force, a, -f)
        np.add.at(force, b, f)
        self.force = force[self.free].ravel()
        self.x = x[self.free]
        self.muscle = self.p["muscle"][self.free]
        self.sample = self.p["sample"][self.free].astype(float)

    def _add(self, i, j, blocks, sign):
        keep = (self.index[i] >= 0) & (self.index[j] >= 0)
        rows, cols, b = self.index[i][keep], self.index[j][keep], blocks[keep]
        for r in range(3):
            for c in range(3):
                self.rows.append(3 * rows + r)
                self.cols.append(3 * cols + c)
                self.vals.append(sign * b[:, r, c])

    def _pair(self, a, b, blocks):
        self._add(a, a, blocks, 1.0)
        self._add(b, b, blocks, 1.0)
        self._add(a, b, blocks, -1.0)
        self._add(b, a, blocks, -1.0)

    def block_diagonal(self):
        n = self.hessian.shape[0] // 3
        blocks = np.zeros((n, 3, 3))
        for r in range(3):
            for c in range(3):
                blocks[:, r, c] = np.asarray(self.hessian[np.arange(n) * 3 + r, np.arange(n) * 3 + c]).ravel()
        return sp.block_diag(list(blocks), format="csc")

    def block_lower(self):
        """The block lower triangle (Gauss-Seidel in particle order)."""
        lower = sp.tril(self.hessian, format="coo")
        upper = sp.triu(self.hessian, k=1).tocoo()
        inside = (upper.row // 3) == (upper.col // 3)
        return (lower + sp.coo_matrix((upper.data[inside], (upper.row[inside], upper.col[inside])),
                                      shape=self.hessian.shape)).tocsc()

    def slabs(self, nodes, rigid):
        """Prolongation of `nodes` slabs per muscle along the fibres, linear in between: each node moves its slab by a
        translation (and with `rigid` a small rotation about the slab's centre)."""
        along = self.sample / self.sample.max() * (nodes - 1)
        low = np.clip(np.floor(along).astype(int), 0, nodes - 2)
        t = along - low
        per = 6 if rigid else 3
        muscles = self.muscle.max() + 1
        node_low = self.muscle * nodes + low
        centres = np.zeros((muscles * nodes, 3))
        weights = np.zeros(muscles * nodes)
        for node, w in ((node_low, 1 - t), (node_low + 1, t)):
            np.add.at(centres, node, w[:, None] * self.x)
            np.add.at(weights, node, w)
        centres /= np.maximum(weights, 1e-12)[:, None]
        rows, cols, vals = [], [], []
        dof = 3 * np.arange(len(self.x))
        for node, w in ((node_low, 1 - t), (node_low + 1, t)):
            for c in range(3):
                rows.append(dof + c)
                cols.append(per * node + c)
                vals.append(w)
            if rigid:
                r = self.x - centres[node]
                rows += [dof + 1, dof + 2, dof + 0, dof + 2, dof + 0, dof + 1]
                cols += [per * node + 3] * 2 + [per * node + 4] * 2 + [per * node + 5] * 2
                vals += [-w * r[:, 2], w * r[:, 1], w * r[:, 2], -w * r[:, 0], -w * r[:, 1], w * r[:, 0]]
        prolongation = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                     shape=(3 * len(self.x), per * muscles * nodes))
        return prolongation[:, np.diff(prolongation.indptr) > 0].tocsr()


def spectrum(frame, count):
    values, vectors = sla.eigsh(frame.hessian.tocsc(), k=count, M=frame.block_diagonal(), sigma=-1e-9, which="LM")
    print(f"{frame.hessian.shape[0]} unknowns; the {count} slowest modes relative to each particle's own block:")
    for j in np.argsort(values):
        v = vectors[:, j].reshape(-1, 3)
        weight = (v ** 2).sum(1)
        share = np.bincount(frame.muscle, weights=weight) / weight.sum()
        main = int(share.argmax())
        chosen = frame.muscle == main
        # How much of the mode, on its main muscle, is a rigid motion (least squares fit of t + w x r).
        r = frame.x[chosen] - frame.x[chosen].mean(0)
        fit = np.zeros((3 * len(r), 6))
        for c in range(3):
            fit[c::3, c] = 1
        fit[0::3, 4], fit[0::3, 5] = r[:, 2], -r[:, 1]
        fit[1::3, 3], fit[1::3, 5] = -r[:, 2], r[:, 0]
        fit[2::3, 3], fit[2::3, 4] = r[:, 1], -r[:, 0]
        target = v[chosen].ravel()
        residual = target - fit @ np.linalg.lstsq(fit, target, rcond=None)[0]
        rigid = 1 - (residual ** 2).sum() / (target ** 2).sum()
        samples = frame.sample[chosen].astype(int)
        profile = np.bincount(samples, weights=np.linalg.norm(v[chosen], axis=1)) / np.maximum(np.bincount(samples), 1)
        print(f"  lambda {values[j]:.2e}: muscle {main} holds {share[main]:.0%}, {rigid:.1%} a rigid motion; "
              f"|v| along the fibres " + " ".join(f"{x:.1f}" for x in profile / profile.max()))


def newton(frame, cycles):
    exact = sla.splu(frame.hessian.tocsc()).solve(frame.force)
    step = np.linalg.norm(exact.reshape(-1, 3), axis=1)
    print(f"Newton step from the exported state: {1e3 * np.sqrt((step ** 2).mean()):.2f} mm RMS, "
          f"{1e3 * step.max():.1f} mm at the farthest particle")
    sweep = sla.splu(frame.block_lower(), permc_spec="NATURAL")

    def run(prolongation):
        coarse = sla.splu((prolongation.T @ frame.hessian @ prolongation).tocsc()) if prolongation is not None else None
        d = np.zeros_like(frame.force)
        for _ in range(cycles):
            if coarse is not None:
                d = d + prolongation @ coarse.solve(prolongation.T @ (frame.force - frame.hessian @ d))
            d = d + sweep.solve(frame.force - frame.hessian @ d)
        error = np.linalg.norm((d - exact).reshape(-1, 3), axis=1)
        return 1e3 * np.sqrt((error ** 2).mean())

    print(f"after {cycles} cycles, RMS distance to the Newton step (mm):")
    print(f"  Gauss-Seidel alone: {run(None):.2f}")
    for nodes in (3, 5, 8, 20):
        for rigid in (False, True):
            prolongation = frame.slabs(nodes, rigid)
            print(f"  {nodes} slabs per muscle, {'rigid' if rigid else 'translating'} "
                  f"({prolongation.shape[1]} coarse unknowns): {run(prolongation):.2f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("frame")
    parser.add_argument("--modes", type=int, default=12)
    parser.add_argument("--newton", action="store_true")
    parser.add_argument("--cycles", type=int, default=30)
    arguments = parser.parse_args()
    frame = Frame(arguments.frame)
    if arguments.newton:
        newton(frame, arguments.cycles)
    else:
        spectrum(frame, arguments.modes)


if __name__ == "__main__":
    main()
