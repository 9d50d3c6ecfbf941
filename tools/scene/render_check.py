#!/usr/bin/env python3
"""Offscreen sanity picture of the scene (bones posed through the URDF chain,
muscles at rest). Not part of the product; for eyeballing the build.

  PYENV_VERSION=system /usr/bin/python3 tools/scene/render_check.py OUT.png [joint=value ...]

Bones follow the joint values given (radians / metres); muscle surfaces are
drawn at rest in the pelvis frame, or, with --pose-muscles, rigidly moved with
their insertion bone's link (crude, only to see where they would go).
"""

import os
import sys
import xml.etree.ElementTree as ET

import numpy as np
import vtk
import yaml

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scenelib as sl  # noqa: E402


def forward_kinematics(urdf, q):
    """World pose (R, p) of every link for joint values q (dict)."""
    root = ET.parse(urdf).getroot()
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    cache = {"world": (np.eye(3), np.zeros(3))}

    def pose(link):
        if link in cache:
            return cache[link]
        j = joints[link]
        R, p = pose(j.find("parent").get("link"))
        o = j.find("origin")
        xyz = np.array([float(v) for v in o.get("xyz").split()])
        rpy = [float(v) for v in o.get("rpy", "0 0 0").split()]
        Ro = (sl.rotvec_to_matrix([0, 0, rpy[2]]) @ sl.rotvec_to_matrix([0, rpy[1], 0])
              @ sl.rotvec_to_matrix([rpy[0], 0, 0]))
        p = p + R @ xyz
        R = R @ Ro
        mimic = j.find("mimic")
        if mimic is not None:   # a joint that follows another (the patella's slide with the knee)
            v = float(mimic.get("multiplier", 1.0)) * q.get(mimic.get("joint"), 0.0) + float(mimic.get("offset", 0.0))
        else:
            v = q.get(j.get("name"), 0.0)
        if j.get("type") in ("revolute", "continuous", "prismatic"):
            ax = np.array([float(a) for a in j.find("axis").get("xyz").split()])
            if j.get("type") == "prismatic":
                p = p + R @ (ax * v)
            else:
                R = R @ sl.rotvec_to_matrix(ax * v)
        cache[link] = (R, p)
        return cache[link]
    out = {}
    for link in root.findall("link"):
        out[link.get("name")] = pose(link.get("name"))
    return root, out


def actor(pd, rgba):
    m = vtk.vtkPolyDataMapper()
    n = vtk.vtkPolyDataNormals()
    n.SetInputData(pd)
    m.SetInputConnection(n.GetOutputPort())
    a = vtk.vtkActor()
    a.SetMapper(m)
    a.GetProperty().SetColor(*rgba[:3])
    a.GetProperty().SetOpacity(rgba[3])
    return a


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    pose_muscles = "--pose-muscles" in sys.argv
    out = args[0]
    q = {k: float(v) for k, v in (a.split("=") for a in args[1:])}
    urdf = os.path.join(sl.PKG, "urdf", "right_hip_thigh.urdf")
    root, poses = forward_kinematics(urdf, q)
    actors = []
    for link in root.findall("link"):
        R, p = poses[link.get("name")]
        for c in link.findall("visual"):
            fn = c.find("geometry/mesh").get("filename").replace("package://muscle_deformation/", "")
            pd = sl.read_stl(os.path.join(sl.PKG, fn))
            actors.append(actor(sl.transform_pd(pd, lambda P, R=R, p=p: P @ R.T + p), (0.92, 0.88, 0.78, 1)))
    scene = yaml.safe_load(open(os.path.join(sl.PKG, "config", "scenes", "right_hip_thigh.yaml")))
    _, rest = forward_kinematics(urdf, {})
    for m in scene["muscles"]:
        pd = sl.read_stl(os.path.join(sl.PKG, "config", "scenes", m["surface"]))
        if pose_muscles:
            # rigid move with the insertion link relative to its rest pose
            R1, p1 = poses[m["insertion_bone"]]
            R0, p0 = rest[m["insertion_bone"]]
            pd = sl.transform_pd(pd, lambda P: (P - p0) @ R0 @ R1.T + p1)
        actors.append(actor(pd, m["color"][:3] + [0.55]))
    ren = vtk.vtkRenderer()
    ren.SetBackground(1, 1, 1)
    for a in actors:
        ren.AddActor(a)
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetSize(1200, 900)
    win.AddRenderer(ren)
    views = [((1, 0, 0), "front"), ((0, -1, 0), "right side"), ((0.3, -0.6, 0.2), "oblique")]
    ren.RemoveAllViewProps()
    # three viewports side by side
    win.RemoveRenderer(ren)
    for i, (d, name) in enumerate(views):
        r = vtk.vtkRenderer()
        r.SetViewport(i / 3.0, 0, (i + 1) / 3.0, 1)
        r.SetBackground(1, 1, 1)
        for a in actors:
            r.AddActor(a)
        cam = r.GetActiveCamera()
        cam.SetFocalPoint(0, 0, -0.25)
        cam.SetPosition(*(np.array([0, 0, -0.25]) + 2.0 * np.array(d) / np.linalg.norm(d)))
        cam.SetViewUp(0, 0, 1)
        r.ResetCamera()
        t = vtk.vtkTextActor()
        t.SetInput(name + (" " + " ".join(args[1:]) if len(args) > 1 else " rest"))
        t.GetTextProperty().SetColor(0, 0, 0)
        r.AddActor2D(t)
        win.AddRenderer(r)
    win.Render()
    w2i = vtk.vtkWindowToImageFilter()
    w2i.SetInput(win)
    w2i.Update()
    wr = vtk.vtkPNGWriter()
    wr.SetFileName(out)
    wr.SetInputConnection(w2i.GetOutputPort())
    wr.Write()


if __name__ == "__main__":
    main()
