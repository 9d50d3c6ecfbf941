"""Shared helpers for the scene build scripts (geometry I/O, frames, OpenSim parsing).

Everything here is in SI units unless a name says otherwise (``_mm``).
Frames:
  * VHF:  Visible Human Female scan frame, millimetres, +X subject right,
          +Y anterior, +Z superior.
  * OS:   OpenSim body frames, metres, +X anterior, +Y superior, +Z right.
  * ROS:  REP 103, metres, +X forward (anterior), +Y left, +Z up.
"""

import os
import xml.etree.ElementTree as ET

import numpy as np
import vtk
from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy

# Raw data location; override with the SCENE_RAW environment variable.
RAW = os.environ.get("SCENE_RAW", "/work/shared/data/raw")
VHF_DIR = os.path.join(RAW, "visible_human_female")
OSIM_DIR = os.path.join(RAW, "opensim")
GAIT2392 = os.path.join(OSIM_DIR, "gait2392_millard2012muscle.osim")

# Package root = two levels above this file (tools/scene/ -> package).
PKG = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))

# --- frame conversions -------------------------------------------------------

# VHF axes -> ROS axes: ROS x = VHF +Y (anterior), ROS y = VHF -X (left), ROS z = VHF +Z.
R_VHF_TO_ROS = np.array([[0.0, 1.0, 0.0],
                         [-1.0, 0.0, 0.0],
                         [0.0, 0.0, 1.0]])
# OpenSim axes -> ROS axes: ROS x = OS x, ROS y = -OS z (OS z points right), ROS z = OS y.
R_OS_TO_ROS = np.array([[1.0, 0.0, 0.0],
                        [0.0, 0.0, -1.0],
                        [0.0, 1.0, 0.0]])


def vhf_mm_to_ros(p_mm):
    """VHF points (N,3) in mm -> ROS-axis points in metres (same origin as VHF, scaled)."""
    return (np.asarray(p_mm, float) * 1e-3) @ R_VHF_TO_ROS.T


def os_to_ros(p):
    return np.asarray(p, float) @ R_OS_TO_ROS.T


# --- polydata <-> numpy ------------------------------------------------------

def pd_points(pd):
    return vtk_to_numpy(pd.GetPoints().GetData()).astype(float)


def pd_triangles(pd):
    """Triangle connectivity (M,3); the mesh must contain triangles only."""
    polys = pd.GetPolys()
    conn = vtk_to_numpy(polys.GetConnectivityArray()).astype(np.int64)
    offs = vtk_to_numpy(polys.GetOffsetsArray()).astype(np.int64)
    if not np.all(np.diff(offs) == 3):
        raise ValueError("mesh has non-triangle polygons")
    return conn.reshape(-1, 3)


def make_pd(points, tris):
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=True))
    tris = np.ascontiguousarray(tris, dtype=np.int64)
    offs = np.arange(0, 3 * len(tris) + 1, 3, dtype=np.int64)
    cells = vtk.vtkCellArray()
    cells.SetData(numpy_to_vtkIdTypeArray(offs, deep=True),
                  numpy_to_vtkIdTypeArray(tris.ravel(), deep=True))
    pd = vtk.vtkPolyData()
    pd.SetPoints(pts)
    pd.SetPolys(cells)
    return pd


# --- readers / writers -------------------------------------------------------

def read_stl(path):
    """STL (ASCII or binary) with coincident vertices merged, as triangles."""
    r = vtk.vtkSTLReader()
    r.SetFileName(path)
    r.MergingOn()  # STL stores every triangle's corners separately
    r.Update()
    return clean(r.GetOutput())


def read_vtp(path):
    r = vtk.vtkXMLPolyDataReader()
    r.SetFileName(path)
    r.Update()
    t = vtk.vtkTriangleFilter()  # OpenSim .vtp may hold quads/polygons
    t.SetInputData(r.GetOutput())
    t.Update()
    return clean(t.GetOutput())


def clean(pd, tol=0.0):
    c = vtk.vtkCleanPolyData()
    c.SetInputData(pd)
    c.SetTolerance(tol)
    c.PointMergingOn()
    c.Update()
    out = vtk.vtkPolyData()
    out.DeepCopy(c.GetOutput())
    # keep only geometry: normals and scalars are recomputed by consumers
    out.GetPointData().Initialize()
    out.GetCellData().Initialize()
    return out


def write_stl(pd, path):
    """Binary STL, vertex coordinates as stored (metres for this package)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    w = vtk.vtkSTLWriter()
    w.SetFileName(path)
    w.SetFileTypeToBinary()
    w.SetHeader("muscle_deformation scene, metres")  # fixed header: reproducible bytes
    w.SetInputData(pd)
    w.Write()


# --- mesh quality ------------------------------------------------------------

def open_edges(pd):
    """(boundary edges, non-manifold edges) counted by vtkFeatureEdges."""
    counts = []
    for boundary in (True, False):
        fe = vtk.vtkFeatureEdges()
        fe.SetInputData(pd)
        fe.FeatureEdgesOff()
        fe.ManifoldEdgesOff()
        fe.SetBoundaryEdges(boundary)
        fe.SetNonManifoldEdges(not boundary)
        fe.Update()
        counts.append(fe.GetOutput().GetNumberOfCells())
    return tuple(counts)


def nonmanifold_vertices(pd):
    """Vertices whose triangle fan is not a single disc (bow-tie vertices).

    vtkFeatureEdges only sees edges; two sheets touching in one vertex pass that
    test but break 2-manifoldness, so check the link of every vertex too.
    """
    tris = pd_triangles(pd)
    n = pd.GetNumberOfPoints()
    bad = 0
    # for every vertex collect the opposite edges of its triangles and count the
    # connected components of that edge graph: a closed disc has exactly one cycle.
    opp = [[] for _ in range(n)]
    for a, b, c in tris:
        opp[a].append((b, c))
        opp[b].append((c, a))
        opp[c].append((a, b))
    for v in range(n):
        es = opp[v]
        if not es:
            continue
        parent = {}

        def find(x):
            while parent.setdefault(x, x) != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x
        for a, b in es:
            ra, rb = find(a), find(b)
            if ra != rb:
                parent[ra] = rb
        roots = {find(a) for a, _ in es}
        if len(roots) != 1:
            bad += 1
    return bad


def consistently_oriented(pd):
    """True when every interior edge is used once in each direction."""
    tris = pd_triangles(pd)
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    key = e[:, 0] * (pd.GetNumberOfPoints() + 1) + e[:, 1]
    return len(np.unique(key)) == len(key)


def self_intersections(pd):
    """Pairs of triangles sharing no vertex of which an edge of one crosses the other."""
    from scipy.spatial import cKDTree
    P, T = pd_points(pd), pd_triangles(pd)
    A, B, C = P[T[:, 0]], P[T[:, 1]], P[T[:, 2]]
    centre = (A + B + C) / 3
    rad = np.max(np.stack([np.linalg.norm(X - centre, axis=1) for X in (A, B, C)]), axis=0)
    cand = cKDTree(centre).query_pairs(2 * rad.max(), output_type="ndarray")
    if not len(cand):
        return 0
    a, b = cand[:, 0], cand[:, 1]
    keep = np.linalg.norm(centre[a] - centre[b], axis=1) <= rad[a] + rad[b]
    keep &= ~(T[a][:, :, None] == T[b][:, None, :]).any((1, 2))
    a, b = a[keep], b[keep]

    def edge_hits(s, t):
        # does an edge of triangle s cross triangle t (Moller-Trumbore, segment parameter in [0, 1])
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


def volume(pd):
    m = vtk.vtkMassProperties()
    m.SetInputData(pd)
    m.Update()
    return m.GetVolume()


def signed_volume(pd):
    """Divergence-theorem volume: positive when triangles wind outward (CCW seen from outside)."""
    P = pd_points(pd)
    T = pd_triangles(pd)
    a, b, c = P[T[:, 0]], P[T[:, 1]], P[T[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def n_components(pd):
    cf = vtk.vtkPolyDataConnectivityFilter()
    cf.SetInputData(pd)
    cf.SetExtractionModeToAllRegions()
    cf.Update()
    return cf.GetNumberOfExtractedRegions()


def largest_component(pd):
    cf = vtk.vtkPolyDataConnectivityFilter()
    cf.SetInputData(pd)
    cf.SetExtractionModeToLargestRegion()
    cf.Update()
    return clean(cf.GetOutput())


def decimate(pd, target_tris):
    """Quadric decimation to about target_tris triangles, keeping the mesh closed.

    Quadric edge collapse on a closed 2-manifold input normally stays closed;
    boundary/volume preservation keeps thin muscles from collapsing. The result
    is checked by the caller (open_edges / nonmanifold_vertices).
    """
    n = pd.GetNumberOfCells()
    if n <= target_tris:
        return clean(pd)
    d = vtk.vtkQuadricDecimation()
    d.SetInputData(pd)
    d.SetTargetReduction(1.0 - target_tris / float(n))
    d.VolumePreservationOn()
    d.AttributeErrorMetricOff()
    d.Update()
    return clean(d.GetOutput())


def repair(pd):
    """Fallback for a decimated mesh that came out open: fill holes, keep the
    largest piece, re-orient normals consistently outward."""
    f = vtk.vtkFillHolesFilter()
    f.SetInputData(pd)
    f.SetHoleSize(1e9)
    f.Update()
    out = largest_component(f.GetOutput())
    return orient_outward(out)


def orient_outward(pd):
    n = vtk.vtkPolyDataNormals()
    n.SetInputData(pd)
    n.ConsistencyOn()
    n.AutoOrientNormalsOn()
    n.SplittingOff()
    n.ComputeCellNormalsOff()
    n.Update()
    return clean(n.GetOutput())


def flip_winding(pd):
    T = pd_triangles(pd)[:, [0, 2, 1]]
    return make_pd(pd_points(pd), T)


def transform_pd(pd, fn):
    """Apply fn: (N,3)->(N,3) to every vertex; connectivity unchanged."""
    return make_pd(fn(pd_points(pd)), pd_triangles(pd))


# --- fitting -----------------------------------------------------------------

def sphere_fit(P):
    """Least-squares sphere: |p|^2 = 2 c.p + (r^2 - |c|^2), linear in (c, k)."""
    P = np.asarray(P, float)
    A = np.hstack([2 * P, np.ones((len(P), 1))])
    b = (P ** 2).sum(1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    r = np.sqrt(sol[3] + c @ c)
    return c, r


def rotvec_to_matrix(w):
    th = np.linalg.norm(w)
    if th < 1e-12:
        return np.eye(3)
    k = w / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def matrix_to_rpy(R):
    """URDF rpy (fixed-axis X, then Y, then Z: R = Rz(y) Ry(p) Rx(r))."""
    p = np.arcsin(-np.clip(R[2, 0], -1, 1))
    r = np.arctan2(R[2, 1], R[2, 2])
    y = np.arctan2(R[1, 0], R[0, 0])
    return np.array([r, p, y])


# --- signed distance grids and similarity transforms (registrations) -----------

class SDFGrid:
    """Signed distance to a closed mesh (negative inside) sampled on a grid."""

    def __init__(self, pd, spacing=0.0015, margin=0.02):
        b = np.array(pd.GetBounds()).reshape(3, 2)
        lo, hi = b[:, 0] - margin, b[:, 1] + margin
        dims = np.ceil((hi - lo) / spacing).astype(int) + 1
        f = vtk.vtkImplicitPolyDataDistance()
        f.SetInput(pd)
        s = vtk.vtkSampleFunction()
        s.SetImplicitFunction(f)
        s.SetModelBounds(lo[0], lo[0] + (dims[0] - 1) * spacing,
                         lo[1], lo[1] + (dims[1] - 1) * spacing,
                         lo[2], lo[2] + (dims[2] - 1) * spacing)
        s.SetSampleDimensions(*dims)
        s.ComputeNormalsOff()
        s.SetOutputScalarTypeToDouble()
        s.Update()
        v = vtk_to_numpy(s.GetOutput().GetPointData().GetScalars())
        self.vol = v.reshape(dims[2], dims[1], dims[0]).transpose(2, 1, 0).copy()
        self.lo, self.h = lo, spacing

    def __call__(self, P):
        idx = ((P - self.lo) / self.h).T
        # outside the grid: far away, count as outside (large positive)
        from scipy.ndimage import map_coordinates
        return map_coordinates(self.vol, idx, order=1, mode="constant", cval=1.0)


def sim_apply(x, P):
    """Similarity with per-axis scale: T(p) = R (s * p) + t, x = (rotvec, t, log s)."""
    R = rotvec_to_matrix(x[:3])
    return (P * np.exp(x[6:9])) @ R.T + x[3:6]


def sim_inverse(x, Q):
    R = rotvec_to_matrix(x[:3])
    return ((Q - x[3:6]) @ R) / np.exp(x[6:9])


def rotvec_from_matrix(R):
    ang = np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))
    if ang < 1e-12:
        return np.zeros(3)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return w / (2 * np.sin(ang)) * ang


def body_fixed_zxy(R_ros):
    """Angles (a, b, c) with R = Rz(a) Rx(b) Ry(c) in OpenSim axes (gait2392 order)."""
    R = R_OS_TO_ROS.T @ R_ros @ R_OS_TO_ROS
    b = np.arcsin(np.clip(R[2, 1], -1, 1))
    a = np.arctan2(-R[0, 1], R[1, 1])
    c = np.arctan2(-R[2, 0], R[2, 2])
    return np.array([a, b, c])


# --- OpenSim model parsing ---------------------------------------------------

def fmm_spline(x, y):
    """Cubic interpolating spline with the end conditions of Forsythe, Malcolm &
    Moler (third derivative at each end equal to that of the cubic through the
    four end points), the scheme OpenSim's SimmSpline uses. Returns a callable.
    Falls back to linear for 2 points and to natural ends for 3."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    n = len(x)
    if n == 2:
        return lambda q: np.interp(q, x, y)
    h = np.diff(x)
    A = np.zeros((n, n))
    rhs = np.zeros(n)
    # interior rows: continuity of the first derivative, unknowns = second derivatives M
    for i in range(1, n - 1):
        A[i, i - 1] = h[i - 1]
        A[i, i] = 2 * (h[i - 1] + h[i])
        A[i, i + 1] = h[i]
        rhs[i] = 6 * ((y[i + 1] - y[i]) / h[i] - (y[i] - y[i - 1]) / h[i - 1])

    def third_dd(xs, ys):  # third divided difference of four points
        d1 = np.diff(ys) / np.diff(xs)
        d2 = np.diff(d1) / (xs[2:] - xs[:-2])
        return (d2[1] - d2[0]) / (xs[3] - xs[0])
    if n >= 4:
        # spline third derivative on the end interval = 6 * third divided difference
        A[0, 0], A[0, 1] = -1 / h[0], 1 / h[0]
        rhs[0] = 6 * third_dd(x[:4], y[:4])
        A[-1, -2], A[-1, -1] = -1 / h[-1], 1 / h[-1]
        rhs[-1] = 6 * third_dd(x[-4:], y[-4:])
    else:
        A[0, 0] = A[-1, -1] = 1.0
    M = np.linalg.solve(A, rhs)

    def ev(q):
        q = np.asarray(q, float)
        i = np.clip(np.searchsorted(x, q) - 1, 0, n - 2)
        t0, t1 = q - x[i], x[i + 1] - q
        hi = h[i]
        return (M[i] * t1 ** 3 + M[i + 1] * t0 ** 3) / (6 * hi) \
            + (y[i] / hi - M[i] * hi / 6) * t1 + (y[i + 1] / hi - M[i + 1] * hi / 6) * t0
    return ev


def _floats(text):
    return np.array([float(v) for v in text.split()])


def load_osim(path=GAIT2392):
    return ET.parse(path).getroot()


def knee_splines(root, joint="knee_r"):
    """(tx(q), ty(q)) callables: tibia-frame origin in the femur frame (OS axes, m)."""
    j = root.find(".//CustomJoint[@name='%s']" % joint)
    out = {}
    for ta in j.find("SpatialTransform"):
        name = ta.get("name")
        sp = ta.find("SimmSpline")
        if name in ("translation1", "translation2") and sp is not None:
            out[name] = fmm_spline(_floats(sp.find("x").text), _floats(sp.find("y").text))
    return out["translation1"], out["translation2"]


def joint_offset(root, joint, which):
    """translation of a joint's parent (which=0) or child (1) offset frame (OS m)."""
    j = root.find(".//CustomJoint[@name='%s']" % joint)
    frames = j.find("frames").findall("PhysicalOffsetFrame")
    return _floats(frames[which].find("translation").text)


def muscle_bodies(root, muscle):
    """Bodies of the first and last path points of a musculotendon path."""
    m = root.find(".//*[@name='%s']" % muscle)
    pts = m.find(".//PathPointSet/objects")
    frames = [p.find("socket_parent_frame").text.split("/")[-1] for p in pts]
    return frames[0], frames[-1]
