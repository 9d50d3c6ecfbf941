"""Rest overlaps of VHF muscles with the bones, resolved on the muscle side.

The substituted generic hip bone is thicker than the room the VHF muscles
leave it in places (iliac fossa, greater sciatic notch, obturator region), so
after the registration and the capped bone adjustment (build_scene.deform_out)
some muscle surfaces still dip into a bone (and, with the VHF sacrum, the
piriformis: two VHF segmentations overlap after decimation). Particles on
fibres that start inside a bone stay there (collision keeps a particle no
deeper than it lay at rest), so the overlap is solved out of the muscles once,
at build time:

push_out_of_bones moves a muscle's surface vertices with one smooth
displacement field until no vertex lies inside any bone and no bone vertex
inside the muscle. Each round finds the vertices inside a bone (exact parity
test) and asks each to move to the bone surface plus `margin` (along the
direction to its closest bone surface point, i.e. out of the bone), and for
every bone vertex inside the muscle (a bone edge or corner poking between
muscle vertices) asks the closest muscle triangle's corners to move past it;
the pushes are soft targets of a least-squares problem
for the displacement D of every vertex:

  sum_pushed |D_i - t_i|^2 + smooth * sum_{|v_i - v_j| < radius} k_ij |D_i - D_j|^2 + tether * sum_i |D_i|^2

(k_ij a Gaussian of the rest distance; pairs are joined in space, not along
the surface, so the face of a thin muscle sheet that does not touch the bone
moves with the face that does instead of the sheet being squeezed). A vertex
pushed once keeps a target (where it is now) in later rounds, so spreading
does not let it fall back in. Topology is unchanged (the surface stays a closed
2-manifold); a round that would turn a triangle over (its normal by more than
90 degrees) or make the surface intersect itself is halved (up to four
times) or, still folding, not taken, and the pushing stops there. A muscle no vertex of which is inside a bone is returned
unchanged. Sparse direct solves and VTK queries only: deterministic.
"""

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import vtk
from scipy.spatial import cKDTree
from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

import scenelib as sl


def inside_flags(surface_pd, P):
    """Exact parity inside test (vtkSelectEnclosedPoints) of points P."""
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(P, dtype=np.float64), deep=True))
    probe = vtk.vtkPolyData()
    probe.SetPoints(pts)
    sel = vtk.vtkSelectEnclosedPoints()
    sel.SetInputData(probe)
    sel.SetSurfaceData(surface_pd)
    sel.SetTolerance(1e-6)
    sel.Update()
    return vtk_to_numpy(sel.GetOutput().GetPointData().GetArray("SelectedPoints")).astype(bool)


class Bone:
    """A closed bone surface with a closest-point locator."""

    def __init__(self, name, pd):
        self.name, self.pd = name, pd
        self.loc = vtk.vtkStaticCellLocator()
        self.loc.SetDataSet(pd)
        self.loc.BuildLocator()
        b = np.array(pd.GetBounds()).reshape(3, 2).T
        self.lo, self.hi = b[0], b[1]

    def closest(self, Q):
        C = np.zeros((len(Q), 3))
        c = [0.0, 0.0, 0.0]
        cell, sub, d2 = vtk.reference(0), vtk.reference(0), vtk.reference(0.0)
        for k, q in enumerate(Q):
            self.loc.FindClosestPoint(q, c, cell, sub, d2)
            C[k] = c
        return C

    def closest_cell(self, q):
        c = [0.0, 0.0, 0.0]
        cell, sub, d2 = vtk.reference(0), vtk.reference(0), vtk.reference(0.0)
        self.loc.FindClosestPoint(q, c, cell, sub, d2)
        return int(cell)

    def depths(self, Q, pad=1e-3):
        """(depth of every point inside the bone, 0 outside; closest surface points of those inside)."""
        d = np.zeros(len(Q))
        C = np.zeros((len(Q), 3))
        idx = np.flatnonzero(np.all((Q > self.lo - pad) & (Q < self.hi + pad), axis=1))
        if len(idx):
            idx = idx[inside_flags(self.pd, Q[idx])]
        if len(idx):
            C[idx] = self.closest(Q[idx])
            d[idx] = np.linalg.norm(C[idx] - Q[idx], axis=1)
        return d, C


def pushes(V, T, bones, margin):
    """{vertex: push} taking the muscle surface (vertices V, triangles T) out of the bones.

    Every vertex inside a bone goes to that bone's surface plus margin; where a
    bone vertex lies inside the muscle (the bone pokes between muscle
    vertices), the corners of the muscle triangle closest to it go past it by
    margin. A vertex asked twice keeps the larger push."""
    out = {}

    def add(i, u):
        if i not in out or np.linalg.norm(u) > np.linalg.norm(out[i]):
            out[i] = u
    for bone in bones:
        d, C = bone.depths(V)
        for i in np.flatnonzero(d > 0):
            add(i, (C[i] - V[i]) / d[i] * (d[i] + margin))
    muscle = None
    lo, hi = V.min(0), V.max(0)
    for bone in bones:
        B = sl.pd_points(bone.pd)
        near = np.flatnonzero(np.all((B > lo - margin) & (B < hi + margin), axis=1))
        if not len(near):
            continue
        if muscle is None:
            muscle = Bone("muscle", sl.make_pd(V, T))
        d, C = muscle.depths(B[near])
        for k in np.flatnonzero(d > 0):
            p, c = B[near[k]], C[k]
            u = (p - c) / d[k] * (d[k] + margin)
            tri = T[muscle.closest_cell(p)]
            for i in tri:
                add(int(i), u)
    return out


def push_out_of_bones(muscle_pd, bones, margin=0.4e-3, radius=6e-3, smooth=0.2, tether=0.01, rounds=100):
    """Smoothly displaced copy of muscle_pd with no vertex inside any of `bones` (Bone objects).

    Returns (polydata, displacement (n,3), rounds used, vertices still inside)."""
    V0 = sl.pd_points(muscle_pd)
    T = sl.pd_triangles(muscle_pd)
    n = len(V0)
    first = pushes(V0, T, bones, margin)
    if not first:
        return muscle_pd, np.zeros((n, 3)), 0, 0
    pairs = cKDTree(V0).query_pairs(radius, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    w = np.exp(-(np.linalg.norm(V0[i] - V0[j], axis=1) / (0.5 * radius)) ** 2)
    L = sp.coo_matrix((np.r_[w, w, -w, -w], (np.r_[i, j, i, j], np.r_[i, j, j, i])), shape=(n, n)).tocsr()
    base = smooth * L + tether * sp.identity(n)
    D = np.zeros((n, 3))
    held = {}
    pv, used = first, 0
    for used in range(1, rounds + 1):
        for v in held:
            held[v] = D[v].copy()
        for v, u in pv.items():
            held[v] = D[v] + u
        hv = np.array(sorted(held), dtype=np.int64)
        S = sp.coo_matrix((np.ones(len(hv)), (hv, hv)), shape=(n, n))
        rhs = np.zeros((n, 3))
        rhs[hv] = np.array([held[v] for v in hv])
        lu = spla.splu((base + S).tocsc())
        D_next = np.column_stack([lu.solve(rhs[:, k]) for k in range(3)])
        # a step that folds the surface (a bone plate through the muscle pushes its two sides towards each
        # other) is halved, up to four times; if it still folds, the last unfolded state is kept
        for _ in range(5):
            moved = sl.make_pd(V0 + D_next, T)
            if normal_flips(muscle_pd, moved) >= 0 and not self_intersections(moved):
                break
            D_next = 0.5 * (D + D_next)
        else:
            used -= 1
            break
        D = D_next
        pv = pushes(V0 + D, T, bones, margin)
        if not pv:
            break
    return sl.make_pd(V0 + D, T), D, used, len(pushes(V0 + D, T, bones, margin))


def normal_flips(before_pd, after_pd):
    """Smallest cosine between a triangle's normal before and after (1 = none turned)."""
    def normals(pd):
        P, T = sl.pd_points(pd), sl.pd_triangles(pd)
        nrm = np.cross(P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]])
        return nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    return float((normals(before_pd) * normals(after_pd)).sum(1).min())


def self_intersections(pd):
    """Number of pairs of triangles sharing no vertex that intersect (an edge of one crosses the other)."""
    P, T = sl.pd_points(pd), sl.pd_triangles(pd)
    A, B, C = P[T[:, 0]], P[T[:, 1]], P[T[:, 2]]
    centre = (A + B + C) / 3
    rad = np.max(np.stack([np.linalg.norm(X - centre, axis=1) for X in (A, B, C)]), axis=0)
    tree = cKDTree(centre)
    cand = tree.query_pairs(2 * rad.max(), output_type="ndarray")
    if not len(cand):
        return 0
    a, b = cand[:, 0], cand[:, 1]
    keep = np.linalg.norm(centre[a] - centre[b], axis=1) <= rad[a] + rad[b]
    keep &= ~(T[a][:, :, None] == T[b][:, None, :]).any((1, 2))
    a, b = a[keep], b[keep]

    def edge_hits(s, t):
        # does any edge of triangles s cross triangles t (Moller-Trumbore, segment parameter in [0, 1])
        hit = np.zeros(len(s), bool)
        o, e1, e2 = A[t], B[t] - A[t], C[t] - A[t]
        for p, q in ((A[s], B[s]), (B[s], C[s]), (C[s], A[s])):
            d = q - p
            h = np.cross(d, e2)
            det = (e1 * h).sum(1)
            ok = np.abs(det) > 1e-18
            f = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
            sv = p - o
            u = f * (sv * h).sum(1)
            qv = np.cross(sv, e1)
            v = f * (d * qv).sum(1)
            tt = f * (e2 * qv).sum(1)
            hit |= ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (tt >= 0) & (tt <= 1)
        return hit
    return int((edge_hits(a, b) | edge_hits(b, a)).sum())
