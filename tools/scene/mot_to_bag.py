#!/usr/bin/env python3
"""Convert an OpenSim motion (.mot, gait2392 coordinates) into a rosbag of
sensor_msgs/JointState on /joint_states for urdf/right_hip_thigh.urdf.

  PYENV_VERSION=system /usr/bin/python3 tools/scene/mot_to_bag.py IN.mot OUT.bag \
      [--t0 1.0] [--keep-pelvis-translation] [--urdf urdf/right_hip_thigh.urdf]

What is written, per row of the motion:
  * header.stamp = t0 + trial time (s). The trial's time column (rounded to ms in
    some files) is put back on the exact grid of the trial's rate (60 Hz here).
  * name = every movable joint of the URDF, in URDF order; position in radians
    (revolute) or metres (prismatic); velocity and effort left empty.
  * Rotations: the gait2392 coordinate values, degrees -> radians. The frame
    change OpenSim (Y up) -> ROS (Z up) lives in the URDF joint axes, so the
    values are unchanged.
  * pelvis_tx / pelvis_ty / pelvis_tz: the gait2392 values (metres, along the
    OpenSim ground axes X forward, Y up, Z right, which the URDF joints carry as
    ROS +X, +Z, -Y) minus their mean over the trial, so the skeleton walks in
    place around the world origin (the trials are treadmill-like). With
    --keep-pelvis-translation the raw values are kept (pelvis about 1 m up).
  * knee_tx_r / knee_ty_r: gait2392's tibia translation splines of knee_angle_r
    (SimmSpline, scripts' own implementation), minus their value at knee angle 0
    (the URDF zero is the VHF posture) and scaled with the registered femur
    (factors in tools/scene/build_params.json written by build_scene.py).
Joints of the motion that the URDF lacks (ankle, left leg, lumbar) are dropped.
"""

import argparse
import json
import os
import sys
import xml.etree.ElementTree as ET

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scenelib as sl  # noqa: E402


def read_mot(path):
    """(column names, data array, in_degrees) of an OpenSim .mot/.sto file."""
    with open(path) as f:
        lines = f.read().splitlines()
    in_deg = True  # SIMM-style headers lack the flag; their angles are degrees
    for i, ln in enumerate(lines):
        s = ln.strip().lower()
        if s.startswith("indegrees="):
            in_deg = s.split("=")[1].strip() == "yes"
        if s == "endheader":
            body = lines[i + 1:]
            break
    else:
        raise ValueError("no endheader in %s" % path)
    body = [b for b in body if b.strip()]
    names = body[0].split()
    data = np.array([[float(v) for v in b.split()] for b in body[1:]])
    return names, data, in_deg


def urdf_joints(path):
    root = ET.parse(path).getroot()
    return [(j.get("name"), j.get("type")) for j in root.findall("joint") if j.get("type") != "fixed"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mot")
    ap.add_argument("bag")
    ap.add_argument("--t0", type=float, default=1.0, help="ROS time (s) of trial time 0")
    ap.add_argument("--keep-pelvis-translation", action="store_true")
    ap.add_argument("--urdf", default=os.path.join(sl.PKG, "urdf", "right_hip_thigh.urdf"))
    ap.add_argument("--params", default=os.path.join(sl.PKG, "tools", "scene", "build_params.json"))
    ap.add_argument("--topic", default="/joint_states")
    a = ap.parse_args()

    import genpy
    import rosbag
    from sensor_msgs.msg import JointState

    names, data, in_deg = read_mot(a.mot)
    col = {n: data[:, i] for i, n in enumerate(names)}
    t = col["time"]
    rate = round((len(t) - 1) / (t[-1] - t[0]))  # mean rate, robust to ms rounding
    i0 = int(round(t[0] * rate))
    if np.abs(t - (i0 + np.arange(len(t))) / rate).max() > 1e-3:
        raise SystemExit("time column is not uniformly sampled")
    ticks = i0 + np.arange(len(t))  # exact sample grid, in samples
    params = json.load(open(a.params))
    tx, ty = sl.knee_splines(sl.load_osim())
    ang = np.pi / 180.0 if in_deg else 1.0

    values = {}
    for n in ("pelvis_tilt", "pelvis_list", "pelvis_rotation",
              "hip_flexion_r", "hip_adduction_r", "hip_rotation_r", "knee_angle_r"):
        values[n] = col[n] * ang
    for n in ("pelvis_tx", "pelvis_ty", "pelvis_tz"):
        values[n] = col[n] if a.keep_pelvis_translation else col[n] - col[n].mean()
    q = values["knee_angle_r"]
    ks, k0 = params["knee_spline_scale"], params["knee_spline_at_zero"]
    values["knee_tx_r"] = ks["tx"] * (tx(q) - k0["tx"])
    values["knee_ty_r"] = ks["ty"] * (ty(q) - k0["ty"])

    joints = urdf_joints(a.urdf)
    missing = [j for j, _ in joints if j not in values]
    if missing:
        raise SystemExit("no values for URDF joints: %s" % missing)
    os.makedirs(os.path.dirname(os.path.abspath(a.bag)), exist_ok=True)
    with rosbag.Bag(a.bag, "w") as bag:
        for i in range(len(t)):
            msg = JointState()
            # integer nanoseconds from the sample index: no float drift in stamps
            ns = int(round(a.t0 * 1e9)) + (int(ticks[i]) * 10 ** 9) // rate
            stamp = genpy.Time(ns // 10 ** 9, ns % 10 ** 9)
            msg.header.seq = i
            msg.header.stamp = stamp
            msg.name = [j for j, _ in joints]
            msg.position = [float(values[j][i]) for j, _ in joints]
            bag.write(a.topic, msg, stamp)
    print("%s: %d JointState messages, %d joints, %g Hz, %.3f..%.3f s trial time"
          % (a.bag, len(t), len(joints), rate, ticks[0] / rate, ticks[-1] / rate))


if __name__ == "__main__":
    main()
