#!/usr/bin/python3
"""A user's own hip, made from the raw data the bundled scene comes from, with the defects segmentations have, to run
`prepare_scene` on as a user would (README, "Your own anatomy").

What it writes into OUT:
- muscles/: four VHF muscles in millimetres, in the frame of the skeleton's pelvis at rest (the bundled scene frame),
  each in another format and each with defects: psoas major (PLY) with a fin of three triangles on one edge (one on
  it, a strip beyond: the local repair cannot undo it), iliacus (STL) with a fold through itself (one vertex dragged
  across its neighbours) and a hole, gluteus medius (OBJ) with a
  flipped and a degenerate triangle and a loose speck, pectineus (STL) as segmented;
- hip.urdf: the bundled skeleton (its joints, its sacrum, coccyx, left hip bone, tibia, patella) with the raw OpenSim
  right hip bone and femur in place of the bundled, carved ones, placed by the bundled build's registration through
  the URDF's <mesh scale> and <origin> (tools/scene/build_params.json): unadjusted bones that the measured muscles
  overlap at rest, with the OpenSim meshes' own holes and non-manifold edges.
It then prints the prepare_scene command to run (or runs it with --run).

Needs numpy and VTK's Python module: Debian's python3-numpy and python3-vtk9 (/usr/bin/python3, as the scene tools). The raw
data: ../shared/data/raw by default.
"""
import argparse
import json
import math
import os
import subprocess
import sys

import numpy as np
import vtk
from vtk.util.numpy_support import vtk_to_numpy

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
R_VHF_TO_ROS = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
R_OS_TO_ROS = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
MUSCLES = [  # name, raw VHF stem, written as, origin link, insertion link
    ("psoas_major", "PsoasMajor", "ply", "pelvis", "femur_r"),
    ("iliacus", "Illiacus", "stl", "pelvis", "femur_r"),
    ("gluteus_medius", "GluteusMedius", "obj", "pelvis", "femur_r"),
    ("pectineus", "Pectineus", "stl", "pelvis", "femur_r"),
]


def rotvec_to_matrix(w):
    th = np.linalg.norm(w)
    if th < 1e-12:
        return np.eye(3)
    k = np.asarray(w) / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def rpy_of(R):
    """URDF rpy (fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll))."""
    pitch = math.asin(-max(-1.0, min(1.0, R[2, 0])))
    roll = math.atan2(R[2, 1], R[2, 2])
    yaw = math.atan2(R[1, 0], R[0, 0])
    return roll, pitch, yaw


def read_polydata(path):
    reader = vtk.vtkSTLReader() if path.endswith(".stl") else vtk.vtkXMLPolyDataReader()
    reader.SetFileName(path)
    reader.Update()
    pd = reader.GetOutput()
    points = vtk_to_numpy(pd.GetPoints().GetData()).astype(float)
    cells = vtk_to_numpy(pd.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    return points, cells


def write_mesh(path, vertices, triangles):
    if path.endswith(".obj"):
        with open(path, "w") as out:
            for v in vertices:
                out.write("v %.5f %.5f %.5f\n" % tuple(v))
            for t in triangles:
                out.write("f %d %d %d\n" % tuple(int(i) + 1 for i in t))
        return
    points = vtk.vtkPoints()
    for v in vertices:
        points.InsertNextPoint(*v)
    polys = vtk.vtkCellArray()
    for t in triangles:
        polys.InsertNextCell(3)
        for i in t:
            polys.InsertCellPoint(int(i))
    pd = vtk.vtkPolyData()
    pd.SetPoints(points)
    pd.SetPolys(polys)
    writer = vtk.vtkPLYWriter() if path.endswith(".ply") else vtk.vtkSTLWriter()
    writer.SetFileName(path)
    writer.SetInputData(pd)
    writer.SetFileTypeToBinary()
    writer.Write()


def normal_of(vertices, triangle):
    a, b, c = (vertices[i] for i in triangle)
    n = np.cross(b - a, c - a)
    return n / np.linalg.norm(n)


def with_strip_fin(vertices, triangles):
    """A fin of three triangles on one edge a-b: one on the edge, two more a strip beyond it. The local repair removes
    the one on the edge and fills the hole, but the strip stays joined at a vertex: only a rebuild closes it."""
    k = len(triangles) // 3
    a, b, c = triangles[k]
    n = normal_of(vertices, triangles[k])
    if np.dot(n, 0.5 * (vertices[a] + vertices[b]) - vertices.mean(0)) < 0:
        n = -n
    edge = np.linalg.norm(vertices[b] - vertices[a])
    middle = 0.5 * (vertices[a] + vertices[b])
    base = len(vertices)
    vertices = np.vstack([vertices, [middle + edge * n, vertices[b] + edge * n, middle + 1.7 * edge * n]])
    t1, t2, t3 = base, base + 1, base + 2
    return vertices, np.vstack([triangles, [(a, b, t1), (b, t2, t1), (t1, t2, t3)]])


def with_fold_and_hole(vertices, triangles):
    """One vertex dragged two and a half edges sideways and a fifth of one in: its fan of triangles folds over the
    ring around it and crosses it, as a smoothed segmentation can. And a triangle removed elsewhere (a hole)."""
    v = len(vertices) // 2
    ring = [t for t in triangles if v in t]
    normal = np.mean([normal_of(vertices, t) for t in ring], axis=0)
    normal /= np.linalg.norm(normal)
    sideways = np.cross(normal, [0.0, 0.0, 1.0])
    sideways /= np.linalg.norm(sideways)
    neighbours = sorted({int(i) for t in ring for i in t if i != v})
    edge = np.mean([np.linalg.norm(vertices[n] - vertices[v]) for n in neighbours])
    vertices = vertices.copy()
    vertices[v] += 2.5 * edge * sideways - 0.2 * edge * normal
    far = max(range(len(triangles)), key=lambda k: np.linalg.norm(vertices[triangles[k][0]] - vertices[v]))
    return vertices, np.delete(triangles, far, axis=0)


def with_flip_degenerate_and_speck(vertices, triangles):
    triangles = triangles.copy()
    triangles[10] = triangles[10][[0, 2, 1]]  # flipped
    a, b, _ = triangles[20]
    triangles = np.vstack([triangles, [(a, b, b)]])  # degenerate
    speck = vertices.min(0) - 15.0 + np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    base = len(vertices)
    vertices = np.vstack([vertices, speck])
    tetra = np.array([(0, 2, 1), (0, 1, 3), (1, 2, 3), (0, 3, 2)]) + base
    return vertices, np.vstack([triangles, tetra])


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out")
    parser.add_argument("--raw", default=os.path.join(REPO, "..", "shared", "data", "raw"))
    parser.add_argument("--run", metavar="PREPARE_SCENE", help="run this prepare_scene binary with the options below")
    parser.add_argument("--rest-overlaps", default="carve-bones")
    args = parser.parse_args()
    raw = os.path.abspath(args.raw)
    out = os.path.abspath(args.out)
    os.makedirs(os.path.join(out, "muscles"), exist_ok=True)
    params = json.load(open(os.path.join(REPO, "tools", "scene", "build_params.json")))
    pelvis, femur = params["pelvis_registration"], params["femur_registration"]
    origin = np.asarray(pelvis["translation_vhf_ros"])  # the scene frame's origin in VHF ROS axes (m)

    for name, stem, kind, _, _ in MUSCLES:
        vertices, triangles = read_polydata(
            os.path.join(raw, "visible_human_female", "VHF_Right_Muscle_%s_smooth.stl" % stem))
        vertices = 1e3 * ((1e-3 * vertices) @ R_VHF_TO_ROS.T - origin)  # millimetres, scene frame
        if name == "psoas_major":
            vertices, triangles = with_strip_fin(vertices, triangles)
        elif name == "iliacus":
            vertices, triangles = with_fold_and_hole(vertices, triangles)
        elif name == "gluteus_medius":
            vertices, triangles = with_flip_degenerate_and_speck(vertices, triangles)
        write_mesh(os.path.join(out, "muscles", "%s.%s" % (name, kind)), vertices, triangles)

    # Raw OpenSim bones through the registration: scene = R (s * (A p)) + t - origin = R A (s' * p) + t - origin, with A
    # the OpenSim-to-ROS axes and s' the registration's ROS-axis scales in OpenSim's axes.
    def placement(registration, scale_key, link_origin):
        R = rotvec_to_matrix(registration["rotvec"]) @ R_OS_TO_ROS
        s = registration[scale_key]  # ROS axes: x, y, z
        scale_os = (s[0], s[2], s[1])  # OpenSim x = ROS x, OpenSim y = ROS z, OpenSim z = -ROS y
        xyz = np.asarray(registration["translation_vhf_ros"]) - origin - link_origin
        return xyz, rpy_of(R), scale_os

    urdf = open(os.path.join(REPO, "urdf", "right_hip_thigh.urdf")).read()
    hip_centre = np.array([-0.0737727, -0.0992777, -0.0591175])  # the femur link's origin (the bundled hip joint)
    for mesh, registration, key, link_origin, raw_name in [
            ("hip_r", pelvis, "scale_ap_ml_si", np.zeros(3), "pelvis"),
            ("femur_r", femur, "scale_ap_ml_long", hip_centre, "femur_r")]:
        xyz, rpy, scale = placement(registration, key, link_origin)
        old = ('<origin xyz="0 0 0" rpy="0 0 0"/>\n      <geometry>\n        <mesh filename="package://muscle_deformation/'
               'data/meshes/bones/%s.stl" scale="1 1 1"/>' % mesh)
        new = ('<origin xyz="%.6f %.6f %.6f" rpy="%.6f %.6f %.6f"/>\n      <geometry>\n        <mesh filename="file://%s" '
               'scale="%.6f %.6f %.6f"/>' % (tuple(xyz) + tuple(rpy) + (
                   os.path.join(raw, "opensim", "Geometry", raw_name + ".vtp"),) + tuple(scale)))
        if urdf.count(old) != 2:
            sys.exit("the bundled URDF's %s meshes are not where this script expects them" % mesh)
        urdf = urdf.replace(old, new)
    urdf = urdf.replace("package://muscle_deformation/", "file://%s/" % REPO)
    with open(os.path.join(out, "hip.urdf"), "w") as f:
        f.write(urdf)

    command = ["--urdf", os.path.join(out, "hip.urdf"), "--scale", "0.001", "--out", os.path.join(out, "scene"),
               "--rest-overlaps", args.rest_overlaps]
    for name, _, kind, origin_link, insertion_link in MUSCLES:
        command += ["--muscle", "%s:%s:%s:%s" % (name, os.path.join(out, "muscles", "%s.%s" % (name, kind)),
                                                 origin_link, insertion_link)]
    print("prepare_scene " + " ".join(command))
    if args.run:
        sys.exit(subprocess.run([args.run] + command).returncode)


if __name__ == "__main__":
    main()
