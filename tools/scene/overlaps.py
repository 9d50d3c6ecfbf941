#!/usr/bin/env python3
"""Muscle / bone overlaps of the built scene at rest: how deep muscle surface
vertices and fibre points lie inside each bone mesh of the URDF.

Used by report.py (the data/README.md tables) and runnable on its own:

  PYENV_VERSION=system /usr/bin/python3 tools/scene/overlaps.py [--json out.json]

Inside = exact parity test against the closed bone surface
(vtkSelectEnclosedPoints); depth = distance of such a point to that bone's
surface (vtkImplicitPolyDataDistance). Fibres are sampled every 0.25 mm along
their polylines, so the depth bounds that of every particle the model builder
places on them (particles lie on the polylines, at any arc length).
"""

import argparse
import json
import os
import sys
import xml.etree.ElementTree as ET

import numpy as np
import vtk
import yaml
from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scenelib as sl  # noqa: E402

PKG = sl.PKG
FIBRE_STEP = 0.25e-3  # m, sampling step along the fibre polylines


def bone_meshes_scene(pkg=PKG):
    """Every <collision> mesh of the URDF, moved to the scene frame of the zero
    configuration (all link frames are parallel to world at zero, so a link's
    pose is the sum of the joint origins on its chain): {mesh: (link, pd)}."""
    root = ET.parse(os.path.join(pkg, "urdf", "right_hip_thigh.urdf")).getroot()
    parent = {}
    for j in root.findall("joint"):
        xyz = np.array([float(v) for v in j.find("origin").get("xyz").split()])
        if j.find("origin").get("rpy").split() != ["0", "0", "0"]:
            raise ValueError("overlaps.py assumes joint origins without rotation")
        parent[j.find("child").get("link")] = (j.find("parent").get("link"), xyz)

    def pos(link):
        p = np.zeros(3)
        while link in parent:
            link, xyz = parent[link]
            p += xyz
        return p
    out = {}
    for link in root.findall("link"):
        for c in link.findall("collision"):
            fn = c.find("geometry/mesh").get("filename").replace("package://muscle_deformation/", "")
            pd = sl.read_stl(os.path.join(pkg, fn))
            o = pos(link.get("name"))
            out[os.path.basename(fn)[:-4]] = (link.get("name"), sl.transform_pd(pd, lambda P, o=o: P + o))
    return out


def read_polylines(path):
    """Fibre polylines of a VTK legacy file, as a list of (n, 3) arrays."""
    r = vtk.vtkPolyDataReader()
    r.SetFileName(path)
    r.Update()
    pd = r.GetOutput()
    P = vtk_to_numpy(pd.GetPoints().GetData()).astype(float)
    lines = pd.GetLines()
    conn = vtk_to_numpy(lines.GetConnectivityArray()).astype(np.int64)
    offs = vtk_to_numpy(lines.GetOffsetsArray()).astype(np.int64)
    return [P[conn[a:b]] for a, b in zip(offs[:-1], offs[1:])]


def densify(line, step=FIBRE_STEP):
    """Points along a polyline no further than `step` apart (its vertices included)."""
    out = [line[:1]]
    for a, b in zip(line[:-1], line[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        t = (np.arange(1, n + 1) / n)[:, None]
        out.append(a + t * (b - a))
    return np.concatenate(out)


def inside_flags(surface_pd, P):
    """Exact parity inside test of points P against a closed surface."""
    probe = vtk.vtkPolyData()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(P, dtype=np.float64), deep=True))
    probe.SetPoints(pts)
    sel = vtk.vtkSelectEnclosedPoints()
    sel.SetInputData(probe)
    sel.SetSurfaceData(surface_pd)
    sel.SetTolerance(1e-6)
    sel.Update()
    return vtk_to_numpy(sel.GetOutput().GetPointData().GetArray("SelectedPoints")).astype(bool)


def unsigned_distance(surface_pd, P):
    f = vtk.vtkImplicitPolyDataDistance()
    f.SetInput(surface_pd)
    a = numpy_to_vtk(np.ascontiguousarray(P, dtype=np.float64), deep=True)
    d = vtk.vtkDoubleArray()
    f.FunctionValue(a, d)
    return np.abs(vtk_to_numpy(d).astype(float))


def depths_in(surface_pd, P, pad=1e-3):
    """Depth (m) of every point of P inside the closed surface, 0 outside."""
    out = np.zeros(len(P))
    lo, hi = np.array(surface_pd.GetBounds()).reshape(3, 2).T
    near = np.all((P > lo - pad) & (P < hi + pad), axis=1)
    if near.any():
        idx = np.flatnonzero(near)
        flags = inside_flags(surface_pd, P[idx])
        if flags.any():
            out[idx[flags]] = unsigned_distance(surface_pd, P[idx[flags]])
    return out


def load_muscles(pkg=PKG):
    scene = yaml.safe_load(open(os.path.join(pkg, "config", "scenes", "right_hip_thigh.yaml")))
    out = []
    for m in scene["muscles"]:
        surf = sl.read_stl(os.path.join(pkg, "config", "scenes", m["surface"]))
        fpath = os.path.join(pkg, "config", "scenes", m["fibres"])
        fibres = read_polylines(fpath) if os.path.exists(fpath) else []
        out.append((m["name"], surf, fibres))
    return out


def measure(pkg=PKG, bones=None):
    """{muscle: {"surface": {bone: (count, max depth m)}, "fibres": {...}, "surface_max": (m, bone), ...}}"""
    bones = bone_meshes_scene(pkg) if bones is None else bones
    result = {}
    for name, surf, fibres in load_muscles(pkg):
        V = sl.pd_points(surf)
        F = np.concatenate([densify(f) for f in fibres]) if fibres else np.zeros((0, 3))
        r = {"surface": {}, "fibres": {}}
        inside_any = np.zeros(len(V), bool)
        for b, (_, bpd) in bones.items():
            for key, P in (("surface", V), ("fibres", F)):
                d = depths_in(bpd, P)
                if (d > 0).any():
                    r[key][b] = (int((d > 0).sum()), float(d.max()))
                    if key == "surface":
                        inside_any |= d > 0
        for key in ("surface", "fibres"):
            worst = max(r[key].items(), key=lambda kv: kv[1][1], default=("-", (0, 0.0)))
            r[key + "_max"] = (worst[1][1], worst[0])
        r["surface_inside_fraction"] = float(inside_any.mean())
        result[name] = r
    return result


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", help="write the measurement to this file")
    ap.add_argument("--package-dir", default=PKG)
    a = ap.parse_args()
    res = measure(a.package_dir)
    print("%-26s %8s %8s %-10s %8s %-10s" % ("muscle", "inside%", "surf mm", "bone", "fibre mm", "bone"))
    for n, r in res.items():
        print("%-26s %8.2f %8.2f %-10s %8.2f %-10s" % (n, 100 * r["surface_inside_fraction"],
                                                         r["surface_max"][0] * 1e3, r["surface_max"][1],
                                                         r["fibres_max"][0] * 1e3, r["fibres_max"][1]))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1, sort_keys=True)


if __name__ == "__main__":
    main()
