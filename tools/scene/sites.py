#!/usr/bin/env python3
"""Anatomical attachment sites of the bundled muscles, from gait2392's path points.

For every muscle of the scene this writes, from the path points of its gait2392
counterpart (all bundles of a broad muscle, e.g. glut_max1/2/3_r, averaged point
by point):

  origin_path        the origin site on the bone, then the via points the tendon
                     passes on its way to the belly ({link, point}: m, link frame)
  insertion_path     the via points from the belly towards the insertion, then
                     the insertion site
  belly_path         the via points the belly covers, in path order (left out of
                     the tendons' paths; the line the belly's fibres follow, which
                     the belly's tone measures its span along)
  reference_muscles  the gait2392 counterpart(s), for length comparisons
  sites_source       how each point was obtained

and the scene-level `reference_model` (the gait2392 model and the per-body scale
factors that make it match this skeleton).

Mapping. pelvis and femur_r points: the registrations of the scene build
(build_params.json), i.e. where the generic bones were put. tibia_r points: the
way the URDF builds the knee, through the femur registration and gait2392's knee
at knee_angle_r = KNEE_REST (its translation functions scaled with the femur), the
point scaled by the tibia's size, one factor fitted here (fit_tibia: gait2392's
tibia and fibula onto the VHF ones). The same fit shows the VHF tibia turned about
30 deg outward about its long axis against gait2392's alignment under the femur;
the sites keep gait2392's alignment (and so its knee moment arms) and are moved
onto the VHF bone instead (below). The quadriceps' MovingPathPoints (gait2392's
stand-in for the patella, evaluated at KNEE_REST) lie on our patella: they become
patella_r points, moved onto its surface, and the insertion continues to the
tibial tuberosity (a landmark of the VHF tibia; gait2392 has none). The patella
slides along the tibia with the knee as those points do (patella_track: the
line build_scene.py gives the URDF's patella_slide_r, checked here).

Selection. ConditionalPathPoints stay when active over more than half of the
bundled gait's range of their coordinate. The fibre ends of the muscle are
projected onto the registered path: via points between the belly's two ends
(or inside the muscle surface) are covered by the belly and left out. A site
inside the belly, passed by it, or far off a bone the fibres end on gives way to
the fleshy site: the bone point nearest the fibre ends' centroid. Every other
site is moved onto the nearest surface of its link's bones (the distance is
reported). Muscles without a counterpart (the obturators) get fleshy sites, the
obturator internus the gemelli's insertion.

  PYENV_VERSION=system /usr/bin/python3 tools/scene/sites.py [--check]

rewrites just these keys of config/scenes/right_hip_thigh.yaml (the rest stays
byte-identical) from build_params.json, the committed bones, fibres, URDF and
gait, and the raw gait2392 model and trial; it also writes
tools/scene/sites_report.json (read by readme_text.py for data/README.md): per
point its distance to its link's bones, per muscle the length of the path
site -> via points -> fibre-end centroid -> centroid -> via points -> site over
the bundled one-cycle gait against gait2392's musculotendon length over the same
trial. build_scene.py calls the same code from write_yaml; run this after
generate_fibres, whose fibres it reads. --check writes nothing and exits 1 when
the scene file is not up to date. About 1.5 min on one core.
"""

import argparse
import io
import json
import os
import re
import sys

import numpy as np
import yaml
from scipy.optimize import least_squares

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import overlaps  # noqa: E402
import scenelib as sl  # noqa: E402

PKG = sl.PKG
SCENE_YAML = os.path.join(PKG, "config", "scenes", "right_hip_thigh.yaml")
PARAMS_JSON = os.path.join(PKG, "tools", "scene", "build_params.json")
REPORT_JSON = os.path.join(PKG, "tools", "scene", "sites_report.json")
URDF = os.path.join(PKG, "urdf", "right_hip_thigh.urdf")
GAIT_CSV = os.path.join(PKG, "data", "gait", "gait_1cycle.csv")
GAIT_MOT = os.path.join(sl.OSIM_DIR, "subject01_walk1_ik_1cycle.mot")
# the scene file's path of the gait2392 model (relative to config/scenes/, like every scene path)
OSIM_IN_SCENE = "../../data/opensim/gait2392_millard2012muscle.osim"

BODIES = ("pelvis", "femur_r", "tibia_r")          # the gait2392 bodies the bundled muscles' paths use
BODY_TO_LINK = {"pelvis": "pelvis", "femur_r": "femur_r", "tibia_r": "tibia_r"}
KNEE_REST = 0.0            # knee_angle_r of the zero configuration (gait2392 coordinate, rad; see fit_tibia)
ACTIVE_SHARE = 0.5         # a ConditionalPathPoint stays when active over more than this share of the gait's range
DIGITS = 5                 # significant digits of the written coordinates (m)
# the quadriceps' MovingPathPoints stand in for the patella (gait2392 has no patella body)
PATELLA_STAND_IN = "patella_r"
# muscles without a gait2392 counterpart whose tendon joins another's: the obturator internus tendon
# leaves the pelvis through the lesser sciatic foramen and inserts with the gemelli on the medial
# surface of the greater trochanter (gait2392's gem_r insertion)
SHARED_INSERTION = {"obturator_internus": ("gem_r", "P2")}
# why a site is not on a bone of the scene
OFF_BONE = {"psoas_major": "the psoas arises from the bodies and transverse processes of T12-L4, which the "
                           "scene lacks (the lumbar spine moves with the pelvis link here); the VHF belly reaches "
                           "them, above gait2392's lumbar origin P1"}


# ---------------------------------------------------------------------------
# gait2392 path points
# ---------------------------------------------------------------------------

def _function(el):
    """An OpenSim scalar function element -> callable of one coordinate value."""
    if el.tag == "SimmSpline":
        return sl.fmm_spline(sl._floats(el.find("x").text), sl._floats(el.find("y").text))
    if el.tag == "Constant":
        v = float(el.find("value").text)
        return lambda q: v + 0.0 * np.asarray(q, float)
    if el.tag == "LinearFunction":
        a, b = sl._floats(el.find("coefficients").text)
        return lambda q: a * np.asarray(q, float) + b
    raise ValueError("unsupported OpenSim function %s" % el.tag)


class PathPoint:
    """One gait2392 path point: fixed, conditional (active in a coordinate range) or moving
    (location = functions of a coordinate)."""

    def __init__(self, el):
        self.name = el.get("name")
        self.kind = {"PathPoint": "fixed", "ConditionalPathPoint": "conditional",
                     "MovingPathPoint": "moving"}[el.tag]
        self.body = el.find("socket_parent_frame").text.split("/")[-1]
        if self.kind == "moving":
            self.coord = el.find("socket_x_coordinate").text.split("/")[-1]
            for axis in "yz":
                if el.find("socket_%s_coordinate" % axis).text.split("/")[-1] != self.coord:
                    raise ValueError("%s: moving point with several coordinates" % self.name)
            self.funcs = [_function(el.find("%s_location" % a)[0]) for a in "xyz"]
        else:
            self.loc = sl._floats(el.find("location").text)
        if self.kind == "conditional":
            self.coord = el.find("socket_coordinate").text.split("/")[-1]
            self.range = tuple(sl._floats(el.find("range").text))

    def location(self, coords):
        """Location in its body's frame (OpenSim axes, m) for coordinate values {name: rad}."""
        if self.kind == "moving":
            q = coords[self.coord]
            return np.array([float(f(q)) for f in self.funcs])
        return self.loc

    def active(self, coords):
        if self.kind != "conditional":
            return True
        return self.range[0] <= coords[self.coord] <= self.range[1]


def path_points(root, muscle):
    m = root.find(".//*[@name='%s']" % muscle)
    if m is None:
        raise KeyError("gait2392 has no muscle %s" % muscle)
    return [PathPoint(el) for el in m.find(".//PathPointSet/objects")]


def bundles(root, counterpart):
    """All bundles of a gait2392 muscle: glut_max2_r -> glut_max1_r, glut_max2_r, glut_max3_r."""
    if counterpart is None:
        return []
    m = re.fullmatch(r"(.*?)\d(_[lr])", counterpart)
    if not m:
        return [counterpart]
    names = [el.get("name") for el in root.iter() if el.tag.endswith("Muscle") and el.get("name")]
    pattern = re.compile(re.escape(m.group(1)) + r"\d" + re.escape(m.group(2)))
    return sorted(n for n in names if pattern.fullmatch(n))


# ---------------------------------------------------------------------------
# gait2392 kinematics (right leg, pelvis frame, OpenSim axes) and musculotendon lengths
# ---------------------------------------------------------------------------

def _rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


class Gait2392:
    """Poses of pelvis, femur_r and tibia_r in the pelvis frame for gait2392 coordinates, with the
    model scaled per body the way OpenSim's scale tool does it: a body's path points and its joint's
    child-side offset scale with that body, the parent-side offset and the knee's translation
    functions with the parent body (scales = {body: 3 factors in the body's OpenSim axes}).
    hip_rest: hip angles (flexion, adduction, rotation) composed after the coordinates' rotation, as
    our skeleton applies a trial's hip angles to the VHF posture."""

    def __init__(self, root, scales=None, hip_rest=None):
        self.root = root
        self.R_rest = np.eye(3) if hip_rest is None else _rot("z", hip_rest[0]) @ _rot("x", hip_rest[1]) @ _rot(
            "y", hip_rest[2])
        self.scales = {b: np.asarray((scales or {}).get(b, (1.0, 1.0, 1.0)), float) for b in BODIES}
        self.hip = sl.joint_offset(root, "hip_r", 0)
        self.tx, self.ty = sl.knee_splines(root)
        for j, which in (("hip_r", 1), ("knee_r", 0), ("knee_r", 1)):
            if np.any(sl.joint_offset(root, j, which) != 0):
                raise ValueError("gait2392 %s has an offset frame this code does not handle" % j)
        self._paths = {}

    def poses(self, c):
        """{body: (R, p)}: a point x of the body (OpenSim axes, scaled) is at R x + p in the pelvis frame."""
        sp, sf = self.scales["pelvis"], self.scales["femur_r"]
        Rf = _rot("z", c["hip_flexion_r"]) @ _rot("x", c["hip_adduction_r"]) @ _rot("y", c["hip_rotation_r"])
        Rf = Rf @ self.R_rest
        pf = sp * self.hip
        q = c["knee_angle_r"]
        Rt = Rf @ _rot("z", q)
        pt = pf + Rf @ (sf * np.array([float(self.tx(q)), float(self.ty(q)), 0.0]))
        return {"pelvis": (np.eye(3), np.zeros(3)), "femur_r": (Rf, pf), "tibia_r": (Rt, pt)}

    def points(self, muscle, c):
        """Active path points of a muscle in the pelvis frame (scaled model)."""
        if muscle not in self._paths:
            self._paths[muscle] = path_points(self.root, muscle)
        P = self.poses(c)
        out = []
        for pp in self._paths[muscle]:
            if pp.active(c):
                R, p = P[pp.body]
                out.append(R @ (self.scales[pp.body] * pp.location(c)) + p)
        return np.array(out)

    def length(self, muscle, c):
        X = self.points(muscle, c)
        return float(np.linalg.norm(np.diff(X, axis=0), axis=1).sum())


# ---------------------------------------------------------------------------
# registrations: gait2392 body frames -> scene frame
# ---------------------------------------------------------------------------

def os_scale_from_ros(s):
    """Scale factors along ROS axes (x, y, z) of a registration -> along the body's OpenSim axes."""
    return np.array([s[0], s[2], s[1]])


def _xsim(reg, scale_key):
    return np.concatenate([reg["rotvec"], reg["translation_vhf_ros"], np.log(reg[scale_key])])


def knee_chain(params, root, tibia_scale, q=KNEE_REST):
    """gait2392 tibia_r point (OpenSim axes, m) -> scene frame at the zero configuration, the way the
    URDF's knee is built: through the femur registration and gait2392's knee at angle q (its spline
    translations scaled with the femur, as in write_urdf and the gait bags), the point itself scaled
    by tibia_scale (3 factors along the tibia's OpenSim axes)."""
    fr = params["femur_registration"]
    xf = _xsim(fr, "scale_ap_ml_long")
    O = np.array(params["scene_origin_in_vhf_ros_m"])
    tx, ty = sl.knee_splines(root)
    sf = os_scale_from_ros(fr["scale_ap_ml_long"])
    t = sf * np.array([float(tx(q)), float(ty(q)), 0.0])
    Rq = _rot("z", q)
    st = np.asarray(tibia_scale, float)

    Rf = sl.rotvec_to_matrix(xf[:3])

    def chain(p_os):
        # femur-frame point, already scaled: only the registration's rotation and translation apply
        pf = t + (np.atleast_2d(np.asarray(p_os, float)) * st) @ Rq.T
        out = sl.os_to_ros(pf) @ Rf.T + xf[3:6] - O
        return out[0] if np.ndim(p_os) == 1 else out
    return chain


def fit_tibia(pkg, params, root):
    """Size and pose of the VHF tibia against gait2392's, measured: a similarity with one scale
    (rotation, translation, scale) carrying gait2392's tibia_r body onto the VHF tibia and fibula
    (data/meshes/bones/{tibia_r,fibula_r}.stl), fitted like the femur and pelvis registrations of
    build_scene.py (gait2392's tibia_r.vtp and fibula_r.vtp vertices to the VHF surfaces and the VHF
    vertices to gait2392's, robust loss), started from the knee chain at KNEE_REST.

    Only its scale is used (the tibia's body scale); the sites go through the knee chain, which keeps
    gait2392's alignment of the tibia under the femur and hence its knee moment arms. What the fit
    finds beyond that (the VHF tibia's rotation relative to the registered femur, and how far the
    chain-placed gait2392 tibia lies from the fitted one) is the error this choice leaves."""
    K = np.array(params["knee_centre"])
    fr = params["femur_registration"]
    Rf = sl.rotvec_to_matrix(fr["rotvec"])
    s_long = fr["scale_ap_ml_long"][2]

    def vtp(name):
        return sl.transform_pd(sl.read_vtp(os.path.join(sl.OSIM_DIR, "Geometry", name + ".vtp")), sl.os_to_ros)

    def stl(name):
        return sl.transform_pd(sl.read_stl(os.path.join(pkg, "data", "meshes", "bones", name + ".stl")),
                               lambda P: P + K)
    bones = ("tibia_r", "fibula_r")
    model = {b: vtp(b) for b in bones}
    vhf = {b: stl(b) for b in bones}
    sd_vhf = {b: sl.SDFGrid(pd) for b, pd in vhf.items()}
    sd_model = {b: sl.SDFGrid(pd) for b, pd in model.items()}
    M = {b: sl.pd_points(pd) for b, pd in model.items()}
    V = {b: sl.pd_points(pd)[::2] for b, pd in vhf.items()}

    def full(y):
        return np.concatenate([y[:6], [y[6]] * 3])

    def res(y):
        x = full(y)
        r = []
        for b in bones:
            r.append(sd_vhf[b](sl.sim_apply(x, M[b])))
            r.append(0.5 * np.exp(y[6]) * sd_model[b](sl.sim_inverse(x, V[b])))
        return np.concatenate(r)
    chain0 = knee_chain(params, root, [s_long] * 3)
    R0 = Rf @ sl.R_OS_TO_ROS @ _rot("z", KNEE_REST) @ sl.R_OS_TO_ROS.T
    y0 = np.concatenate([sl.rotvec_from_matrix(R0), chain0(np.zeros(3)), [np.log(s_long)]])
    sol = least_squares(res, y0, loss="soft_l1", f_scale=0.003,
                        x_scale=np.r_[[0.05] * 3, [0.005] * 3, [0.05]], max_nfev=400)
    x = full(sol.x)
    scale = float(np.exp(sol.x[6]))
    r = res(sol.x)
    nt = len(M["tibia_r"])
    # the fitted tibia relative to the registered femur, as gait2392 angles (about the knee axis, then
    # ab/adduction, then axial rotation: body-fixed Z X Y like the hip)
    rel = sl.body_fixed_zxy(Rf.T @ sl.rotvec_to_matrix(x[:3]))
    chain = knee_chain(params, root, [scale] * 3)
    T_os = sl.pd_points(sl.read_vtp(os.path.join(sl.OSIM_DIR, "Geometry", "tibia_r.vtp")))
    prox = T_os[:, 1] > -0.12      # the proximal 12 cm of gait2392's tibia, where the sites are
    d = np.linalg.norm(chain(T_os) - sl.sim_apply(x, M["tibia_r"]), axis=1)
    return x, {"scale": scale,
            "fit_model_to_vhf_tibia_mean_mm": float(np.abs(r[:nt]).mean() * 1e3),
            "fit_model_to_vhf_tibia_max_mm": float(np.abs(r[:nt]).max() * 1e3),
            "fit_relative_to_femur_zxy_deg": np.degrees(rel).tolist(),
            "fit_origin_minus_knee_centre_mm": ((x[3:6] - K) * 1e3).tolist(),
            "chain_origin_minus_knee_centre_mm": ((chain(np.zeros(3)) - K) * 1e3).tolist(),
            "chain_to_fit_proximal_tibia_mean_mm": float(d[prox].mean() * 1e3),
            "chain_to_fit_proximal_tibia_max_mm": float(d[prox].max() * 1e3)}


class Registrations:
    """Maps gait2392 body points into the scene frame at the zero configuration: pelvis and femur_r by
    the registrations of build_scene.py (build_params.json), tibia_r by the knee chain with the
    tibia's measured scale (fit_tibia)."""

    def __init__(self, pkg, params, root):
        self.params = params
        self.root = root
        self.O = np.array(params["scene_origin_in_vhf_ros_m"])
        self.xp = _xsim(params["pelvis_registration"], "scale_ap_ml_si")
        self.xf = _xsim(params["femur_registration"], "scale_ap_ml_long")
        self.x_tibia_fit, self.tibia_info = fit_tibia(pkg, params, root)
        self.tibia_scale = [round(self.tibia_info["scale"], 4)] * 3
        self.chain = knee_chain(params, root, self.tibia_scale)
        self.link_origin = {"pelvis": np.zeros(3), "femur_r": np.array(params["hip_centre"]),
                            "tibia_r": np.array(params["knee_centre"]),
                            "patella_r": np.array(params["patella_origin"])}

    def scene(self, body, p_os, fitted_tibia=False):
        """fitted_tibia: tibia_r points by the fitted pose of fit_tibia instead (only to show why not)."""
        p = sl.os_to_ros(np.asarray(p_os, float)[None])
        if body == "tibia_r" and fitted_tibia:
            return sl.sim_apply(self.x_tibia_fit, p)[0]
        if body == "pelvis":
            return sl.sim_apply(self.xp, p)[0] - self.O
        if body == "femur_r":
            return sl.sim_apply(self.xf, p)[0] - self.O
        if body == "tibia_r":
            return self.chain(p_os)
        raise KeyError("no registration for gait2392 body %s" % body)

    def body_scales(self):
        """Per gait2392 body, scale factors along its OpenSim axes (x, y, z)."""
        return {"pelvis": os_scale_from_ros(self.params["pelvis_registration"]["scale_ap_ml_si"]).tolist(),
                "femur_r": os_scale_from_ros(self.params["femur_registration"]["scale_ap_ml_long"]).tolist(),
                "tibia_r": list(self.tibia_scale)}


QUADRICEPS_OS = ("rect_fem_r", "vas_lat_r", "vas_med_r", "vas_int_r")


def patella_track(params, root, tibia_scale, knee_range):
    """How the patella slides with the knee, from gait2392: its quadriceps end on tibia_r points that
    move with knee_angle_r (its stand-in for the patella). Their mean displacement from KNEE_REST,
    carried into the tibia link's frame by the knee chain (the link frame is parallel to the scene's
    at the zero configuration), is fitted by a line through KNEE_REST over knee_range (the angles
    the bundled gait covers, sampled evenly): displacement = (q - KNEE_REST) * metres_per_rad * axis.
    A URDF prismatic joint mimicking the knee carries exactly that line. Returns the axis (unit,
    tibia link frame), metres_per_rad and the line's distance to gait2392's mean point, mm (max over
    knee_range, and max over the knee's whole range of motion)."""
    chain = knee_chain(params, root, tibia_scale)
    moving = [pp for m in QUADRICEPS_OS for pp in path_points(root, m)
              if pp.kind == "moving" and pp.body == "tibia_r"]
    if len(moving) != len(QUADRICEPS_OS):
        raise ValueError("gait2392: expected one moving tibia_r point per quadriceps muscle, found %d" % len(moving))

    def mean_point(q):
        return chain(np.mean([pp.location({"knee_angle_r": q}) for pp in moving], axis=0))
    rest = mean_point(KNEE_REST)

    def displacement(q):
        return mean_point(q) - rest
    qs = np.linspace(knee_range[0], knee_range[1], 41) - KNEE_REST
    D = np.array([displacement(q + KNEE_REST) for q in qs])
    v = (qs[:, None] * D).sum(0) / (qs ** 2).sum()    # least squares through the rest angle
    c = root.find(".//Coordinate[@name='knee_angle_r']")
    full = np.linspace(*sl._floats(c.find("range").text), 81) - KNEE_REST
    miss = lambda Q: max(np.linalg.norm(displacement(q + KNEE_REST) - q * v) for q in Q)  # noqa: E731
    return {"axis": (v / np.linalg.norm(v)).tolist(), "metres_per_rad": float(np.linalg.norm(v)),
            "knee_range_rad": [float(knee_range[0]), float(knee_range[1])],
            "fit_max_mm_over_knee_range": float(miss(qs) * 1e3),
            "fit_max_mm_over_range_of_motion": float(miss(full) * 1e3),
            "muscles": list(QUADRICEPS_OS)}


# ---------------------------------------------------------------------------
# geometry helpers
# ---------------------------------------------------------------------------

def arc_positions(Q, X):
    """Arc length along the polyline Q (n, 3) of the closest point of Q to each point of X, and that
    distance. A point whose closest point is an end of Q and that lies beyond it along the end segment
    gets the arc length of its projection onto that segment's extension (< 0 before the start, > the
    length after the end): so a belly that reaches past an end of the path shows."""
    Q, X = np.asarray(Q, float), np.atleast_2d(np.asarray(X, float))
    seg = np.diff(Q, axis=0)
    L = np.linalg.norm(seg, axis=1)
    s0 = np.concatenate([[0.0], np.cumsum(L)])
    best_d = np.full(len(X), np.inf)
    best_s = np.zeros(len(X))
    for k in range(len(seg)):
        raw = ((X - Q[k]) @ seg[k]) / max(L[k] ** 2, 1e-18)
        t = np.clip(raw, 0.0, 1.0)
        d = np.linalg.norm(Q[k] + t[:, None] * seg[k] - X, axis=1)
        better = d < best_d
        if k == 0:
            t = np.where(raw < 0.0, raw, t)
        if k == len(seg) - 1:
            t = np.where(raw > 1.0, raw, t)
        best_d[better] = d[better]
        best_s[better] = s0[k] + t[better] * L[k]
    return best_s, best_d


def polyline_length(X):
    return float(np.linalg.norm(np.diff(np.asarray(X, float), axis=0), axis=1).sum())


def tibial_tuberosity(tibia_pd_scene, patella_centroid):
    """Insertion of the patellar ligament on the VHF tibia: in the band 25-60 mm below the top of the
    tibia, the vertex furthest towards the patella (horizontal direction from the band's centroid to
    the patella's centroid)."""
    P = sl.pd_points(tibia_pd_scene)
    top = P[:, 2].max()
    band = P[(P[:, 2] < top - 0.025) & (P[:, 2] > top - 0.060)]
    d = patella_centroid - band.mean(0)
    d[2] = 0.0
    d /= np.linalg.norm(d)
    return band[np.argmax(band @ d)]


# ---------------------------------------------------------------------------
# the sites of every muscle
# ---------------------------------------------------------------------------

SNAP_MAX = 0.020     # m: a site further than this from its link's bones is left where it is (bone not in the scene)
COVER_MARGIN = 0.010  # m: a site is passed by the belly when the median fibre end lies this far beyond it
SNAP_FAR = 0.010     # m: a registered site this far off its bone ...
FLESHY = 0.020       # m: ... while the fibre ends lie this close to it (median) is replaced by the fleshy site
TIE = 0.005          # m: a belly end moves with its own attachment bone when that is within this of the nearest


def read_gait(path=GAIT_CSV):
    """{joint: values} of the bundled one-cycle gait (URDF joint names; the hip and knee angles are
    gait2392's coordinates unchanged)."""
    d = np.genfromtxt(path, delimiter=",", names=True, skip_header=1)
    return {n: np.asarray(d[n], float) for n in d.dtype.names}


def activity(pp, gait):
    """(share of the gait's range of the point's coordinate over which it is active, share of frames)."""
    v = gait[pp.coord]
    lo, hi = float(v.min()), float(v.max())
    covered = max(0.0, min(hi, pp.range[1]) - max(lo, pp.range[0]))
    frames = float(np.mean((v >= pp.range[0]) & (v <= pp.range[1])))
    return (covered / (hi - lo) if hi > lo else float(pp.range[0] <= lo <= pp.range[1])), frames


def bundle_short(names):
    """[glut_max1_r, glut_max2_r, glut_max3_r] -> glut_max1/2/3_r"""
    if len(names) == 1:
        return names[0]
    m = [re.fullmatch(r"(.*?)(\d)(_[lr])", n) for n in names]
    return m[0].group(1) + "/".join(x.group(2) for x in m) + m[0].group(3)


class Site:
    """A point of a tendon path: label (gait2392 point name or a description), URDF link, position in the
    scene frame at the zero configuration, and how it was obtained."""

    def __init__(self, label, link, scene, how):
        self.label, self.link, self.scene, self.how = label, link, np.asarray(scene, float), how
        self.moved_mm = None     # distance it was moved onto its bone (sites only)
        self.stand_in_mm = None  # a patella stand-in: its distance to our patella before it was moved onto it


class Bones:
    """The URDF's bone meshes at the zero configuration (scene frame), by link."""

    def __init__(self, pkg):
        import vtk
        self.meshes = overlaps.bone_meshes_scene(pkg)
        self._dist = {}
        for b, (_, pd) in self.meshes.items():
            f = vtk.vtkImplicitPolyDataDistance()
            f.SetInput(pd)
            self._dist[b] = f

    def of(self, link):
        return [b for b, (l, _) in sorted(self.meshes.items()) if l == link]

    def closest(self, x, link=None):
        """(signed distance, negative inside; closest surface point; mesh) over the link's meshes (all if None)."""
        best = (np.inf, None, None)
        for b in (self.of(link) if link else sorted(self.meshes)):
            c = [0.0, 0.0, 0.0]
            d = self._dist[b].EvaluateFunctionAndGetClosestPoint([float(v) for v in x], c)
            if abs(d) < abs(best[0]):
                best = (d, np.array(c), b)
        return best

    def links(self):
        return sorted({l for l, _ in self.meshes.values()})

    def median_distance(self, X, link):
        """Median over the points X of their distance to the link's bones."""
        return float(np.median([abs(self.closest(x, link)[0]) for x in X]))


def gait2392_path(root, reg, bl, gait, decisions, fitted_tibia=False):
    """Registered path of a gait2392 muscle (mean over its bundles) at the zero configuration, as Sites;
    records the ConditionalPathPoints kept or dropped in `decisions`."""
    rest = {"knee_angle_r": KNEE_REST}
    per_bundle = []
    for b in bl:
        pts = []
        for pp in path_points(root, b):
            if pp.kind == "conditional":
                share, frames = activity(pp, gait)
                keep = share > ACTIVE_SHARE
                decisions.append({"point": pp.name, "coordinate": pp.coord, "range_rad": list(pp.range),
                                  "gait_range_share": share, "gait_frame_share": frames, "kept": keep})
                if not keep:
                    continue
            pts.append(pp)
        per_bundle.append(pts)
    if any([p.body for p in pts] != [p.body for p in per_bundle[0]] for pts in per_bundle):
        raise ValueError("bundles %s have different path point bodies" % bl)
    path = []
    for k in range(len(per_bundle[0])):
        pps = [pts[k] for pts in per_bundle]
        body, kind = pps[0].body, pps[0].kind
        label = "/".join(sorted({pp.name.split("-")[-1] for pp in pps}))
        X = [reg.scene(body, pp.location(rest), fitted_tibia) for pp in pps]
        # a tibia_r moving point stands in for the patella (gait2392 has none): it goes onto our patella link
        link = PATELLA_STAND_IN if kind == "moving" and body == "tibia_r" else BODY_TO_LINK[body]
        path.append(Site(label, link, np.mean(X, axis=0), kind))
    return path


def median_arc(Q, X):
    s, _ = arc_positions(Q, X)
    return float(np.median(s))


def build_muscle(path, ends_o, ends_i, surf, bones, tuberosity, shared=None):
    """Origin and insertion paths of one muscle from its registered gait2392 path (None: no counterpart)
    and its fibre ends. Returns (origin_path, insertion_path, belly_path, notes): belly_path holds the via points
    the belly covers, in path order (the line the belly's fibres follow between the two tendons)."""
    c_o, c_i = ends_o.mean(0), ends_i.mean(0)
    notes = []

    def fleshy(link, c, which):
        """The site of a fleshy attachment: the closest point of the link's bones to the fibre ends'
        centroid (the centroid itself when no bone of the link comes within SNAP_MAX)."""
        d, x, mesh = bones.closest(c, link)
        if abs(d) <= SNAP_MAX:
            s = Site("fleshy %s: the point of %s nearest the %s fibre ends' centroid" % (which, mesh, which),
                     link, x, "fleshy")
        else:
            s = Site("fleshy %s: the %s fibre ends' centroid itself (no bone of %s within %.0f mm of it)"
                     % (which, which, link, SNAP_MAX * 1e3), link, c, "fleshy")
        s.moved_mm = 0.0
        return s

    def on_bone(site):
        d, x, mesh = bones.closest(site.scene, site.link)
        site.moved_mm = abs(d) * 1e3
        if abs(d) <= SNAP_MAX:
            site.scene = x
        return site

    if path is None:
        # not in gait2392 (obturators): fleshy attachments at both ends, except where a tendon joins
        # another muscle's (SHARED_INSERTION)
        ins = [on_bone(shared)] if shared is not None else [fleshy("femur_r", c_i, "insertion")]
        return [fleshy("pelvis", c_o, "origin")], ins, [], notes
    for s in path:
        if s.how == "moving":
            d, x, _ = bones.closest(s.scene, s.link)
            s.stand_in_mm = abs(d) * 1e3
            s.scene = x          # the patella stand-in goes onto the patella's surface
    if path[-1].link == PATELLA_STAND_IN:
        path.append(Site("tibial tuberosity", "tibia_r", tuberosity, "landmark"))
    Q = np.array([s.scene for s in path])
    n = len(path)
    s_pts = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(Q, axis=0), axis=1))])
    s_o, s_i = median_arc(Q, ends_o), median_arc(Q, ends_i)
    inside = overlaps.inside_flags(surf, Q)

    def replaced(k, ends, beyond, which):
        """Why the registered site path[k] gives way to the fleshy site, or None: it lies inside the belly,
        the belly reaches past it along the path, or it lies far off its bone while the fibre ends lie on
        that bone (a broad fleshy attachment, e.g. the mean of three bundles' origins across the curved
        iliac wing)."""
        site = path[k]
        d = abs(bones.closest(site.scene, site.link)[0])
        if inside[k]:
            why = "inside the belly"
        elif beyond > COVER_MARGIN:
            why = "passed by the belly (median fibre end %.0f mm beyond it along the path)" % (beyond * 1e3)
        elif d > SNAP_FAR and bones.median_distance(ends, site.link) <= FLESHY:
            why = "%.0f mm off the bone its fibres end on" % (d * 1e3)
        else:
            return None
        return "%s %s %s: fleshy %s used" % (which, site.label, why, which)
    why_o = replaced(0, ends_o, -s_o, "origin")
    why_i = replaced(n - 1, ends_i, s_i - s_pts[-1], "insertion")
    origin = [fleshy(path[0].link, c_o, "origin")] if why_o else [on_bone(path[0])]
    insertion = [fleshy(path[-1].link, c_i, "insertion")] if why_i else [on_bone(path[-1])]
    notes += [w for w in (why_o, why_i) if w]
    belly = []
    for k in range(1, n - 1):
        s = path[k]
        if inside[k]:
            notes.append("%s dropped: inside the belly" % s.label)
            belly.append(s)
        elif not why_o and s_pts[k] < s_o:
            origin.append(s)
        elif not why_i and s_pts[k] > s_i:
            insertion.insert(len(insertion) - 1, s)
        else:
            notes.append("%s dropped: within the belly's extent along the path" % s.label)
            belly.append(s)
    return origin, insertion, belly, notes


def belly_end_link(bones, c, attachment):
    """The link a fibre-end centroid is taken to move with for the length check: that of the bone
    nearest to it at rest, or its own attachment link when that one's bone is within TIE of as near
    (the belly end of the short head of biceps femoris lies between the femoral condyle and the
    fibular head, that of quadratus femoris between ischium and femur)."""
    d = {l: abs(bones.closest(c, l)[0]) for l in bones.links()}
    near = min(d, key=d.get)
    return (attachment if d[attachment] <= d[near] + TIE else near), d


def read_mot_coordinates(path=GAIT_MOT):
    """gait2392 coordinates of the raw one-cycle trial, radians: {name: values}."""
    import mot_to_bag
    names, data, in_deg = mot_to_bag.read_mot(path)
    f = np.pi / 180.0 if in_deg else 1.0
    return {n: data[:, i] * f for i, n in enumerate(names) if n != "time"}


def link_poses(gait):
    """World pose (R, p) of every URDF link for each frame of the gait."""
    import render_check
    n = len(gait["time_s"])
    return [render_check.forward_kinematics(URDF, {j: float(v[f]) for j, v in gait.items() if j != "time_s"})[1]
            for f in range(n)]


def path_lengths(poses, pts):
    """Length over the frames of a polyline whose points [(link, point in the link frame)] move with their links."""
    return np.array([polyline_length([P[l][0] @ x + P[l][1] for l, x in pts]) for P in poses])


DOFS = ("hip_flexion_r", "hip_adduction_r", "hip_rotation_r", "knee_angle_r")
STEP = 0.02          # rad, central differences of the moment arms


def skeleton_moment_arms(params, root, pts):
    """-dL/dq (m) at the zero configuration of a path fixed in URDF links, for each of DOFS; the knee's
    translations follow its angle as in the gait bags (mot_to_bag.py)."""
    import render_check
    tx, ty = sl.knee_splines(root)
    ks, k0 = params["knee_spline_scale"], params["knee_spline_at_zero"]
    out = []
    for dof in DOFS:
        L = []
        for q in (STEP, -STEP):
            v = {dof: q}
            if dof == "knee_angle_r":
                v.update(knee_tx_r=ks["tx"] * (float(tx(q)) - k0["tx"]), knee_ty_r=ks["ty"] * (float(ty(q)) - k0["ty"]))
            L.append(path_lengths([render_check.forward_kinematics(URDF, v)[1]], pts)[0])
        out.append(-(L[0] - L[1]) / (2 * STEP))
    return np.array(out)


def gait2392_moment_arms(model, bl, base):
    out = []
    for dof in DOFS:
        L = []
        for q in (STEP, -STEP):
            c = dict(base)
            c[dof] += q
            L.append(np.mean([model.length(b, c) for b in bl]))
        out.append(-(L[0] - L[1]) / (2 * STEP))
    return np.array(out)


def compute(pkg, params, root, muscles):
    """Sites, checks and the length comparison of every muscle of the table (build_scene.MUSCLES)."""
    reg = Registrations(pkg, params, root)
    gait = read_gait()
    bones = Bones(pkg)
    tuberosity = tibial_tuberosity(bones.meshes["tibia_r"][1], reg.link_origin["patella_r"])
    poses = link_poses(gait)
    mot = read_mot_coordinates()
    frames = [{k: v[f] for k, v in mot.items()} for f in range(len(mot["knee_angle_r"]))]
    if len(frames) != len(poses):
        raise ValueError("the gait CSV and the raw trial have different frame counts")
    ref = Gait2392(root, reg.body_scales())
    generic = Gait2392(root)
    posed = Gait2392(root, reg.body_scales(), params["vhf_rest_angles_rad"]["hip_flexion_adduction_rotation"])
    rest_hip = params["vhf_rest_angles_rad"]["hip_flexion_adduction_rotation"]
    rest = dict(zip(("hip_flexion_r", "hip_adduction_r", "hip_rotation_r"), rest_hip), knee_angle_r=KNEE_REST)
    LO = reg.link_origin

    def local(link, x):
        return (link, np.asarray(x, float) - LO[link])
    rec = {}
    for name, _stem, g, _tags, _col in muscles:
        bl = bundles(root, g)
        fib = overlaps.read_polylines(os.path.join(pkg, "data", "fibres", name + ".vtk"))
        ends_o = np.array([f[0] for f in fib])
        ends_i = np.array([f[-1] for f in fib])
        surf = sl.read_stl(os.path.join(pkg, "data", "meshes", "muscles", name + ".stl"))
        decisions = []
        path = gait2392_path(root, reg, bl, gait, decisions) if bl else None
        registered = [local(s.link, s.scene) for s in path] if path else None
        shared = None
        if name in SHARED_INSERTION:
            g2, label = SHARED_INSERTION[name]
            pp = next(p for p in path_points(root, g2) if p.name == "%s-%s" % (g2, label))
            shared = Site("%s %s" % (g2, label), BODY_TO_LINK[pp.body], reg.scene(pp.body, pp.location({})),
                          "shared")
        origin, insertion, belly, notes = build_muscle(path, ends_o, ends_i, surf, bones, tuberosity, shared)
        c_o, c_i = ends_o.mean(0), ends_i.mean(0)
        att_i = PATELLA_STAND_IN if any(s.link == PATELLA_STAND_IN for s in insertion) else insertion[-1].link
        link_o, _ = belly_end_link(bones, c_o, origin[0].link)
        link_i, _ = belly_end_link(bones, c_i, att_i)
        # checks: distance of every point to its link's bones, inside the belly, order from the belly outward
        checks = []
        for side, seq in (("origin", origin), ("insertion", insertion)):
            flags = overlaps.inside_flags(surf, np.array([s.scene for s in seq]))
            for s, f in zip(seq, flags):
                d, _, mesh = bones.closest(s.scene, s.link)
                checks.append({"side": side, "label": s.label, "link": s.link, "how": s.how,
                               "site": s is seq[0] if side == "origin" else s is seq[-1],
                               "bone_distance_mm": d * 1e3, "bone": mesh, "inside_belly": bool(f),
                               "moved_onto_bone_mm": s.moved_mm,
                               "stand_in_off_patella_mm": s.stand_in_mm})
        to_o = [np.linalg.norm(s.scene - c_o) for s in origin]
        to_i = [np.linalg.norm(s.scene - c_i) for s in insertion]
        ordered = bool(all(np.diff(to_o) < 0) and all(np.diff(to_i) > 0))
        pts = ([local(s.link, s.scene) for s in origin] + [local(link_o, c_o), local(link_i, c_i)]
               + [local(s.link, s.scene) for s in insertion])
        L = path_lengths(poses, pts)
        tendon_rest = (polyline_length([s.scene for s in origin] + [c_o])
                       + polyline_length([c_i] + [s.scene for s in insertion]))
        r = {"bundles": bl, "counterpart": g, "origin": origin, "insertion": insertion, "belly": belly, "notes": notes,
             "conditional": decisions, "belly_end_links": [link_o, link_i], "checks": checks, "ordered": ordered,
             "length": L, "rest_length": path_lengths([{l: (np.eye(3), LO[l]) for l in LO}], pts)[0],
             "tendon_rest": tendon_rest}
        if bl:
            G = np.mean([[ref.length(b, c) for c in frames] for b in bl], axis=0)
            G0 = np.mean([[generic.length(b, c) for c in frames] for b in bl], axis=0)
            Gp = np.mean([[posed.length(b, c) for c in frames] for b in bl], axis=0)
            Lreg = path_lengths(poses, registered)
            if any(s.link == "tibia_r" for s in path):
                # the road not taken: tibia points placed by the fitted pose of the VHF tibia
                alt = gait2392_path(root, reg, bl, gait, [], fitted_tibia=True)
                r["fitted_tibia_moment_arms"] = skeleton_moment_arms(params, root,
                                                                     [local(s.link, s.scene) for s in alt])
            r.update(moment_arms=skeleton_moment_arms(params, root, pts),
                     registered_moment_arms=skeleton_moment_arms(params, root, registered),
                     ref_moment_arms=gait2392_moment_arms(ref, bl, rest))
            r.update(ref_length=G, generic_length=G0, posed_length=Gp, registered_length=Lreg,
                     ref_rest_length=float(np.mean([ref.length(b, rest) for b in bl])),
                     tendon_slack=float(np.mean([float(root.find(".//*[@name='%s']/tendon_slack_length" % b).text)
                                                 for b in bl])))
        if name in OFF_BONE:
            notes.append(OFF_BONE[name])
        rec[name] = r
    return reg, rec


# ---------------------------------------------------------------------------
# the scene file's keys and the report
# ---------------------------------------------------------------------------

SITE_KEYS = ("origin_path", "insertion_path", "belly_path", "reference_muscles", "sites_source")
BODY_HOW = {"pelvis": "by the pelvis registration", "femur_r": "by the femur registration",
            "tibia_r": "through the femur registration and gait2392's knee at knee_angle_r = %g (tibia scale %s)"}


class FlowMap(dict):
    """A mapping written in flow style: {link: pelvis, point: [x, y, z]}."""


class SceneDumper(yaml.SafeDumper):
    pass


SceneDumper.add_representer(
    FlowMap, lambda d, m: d.represent_mapping("tag:yaml.org,2002:map", list(m.items()), flow_style=True))


def dump_scene(header, doc, f):
    """The scene file: header comment, then the document (block style, flow style for short lists and
    for the site entries)."""
    f.write(header + "\n")
    yaml.dump(doc, f, Dumper=SceneDumper, sort_keys=False, default_flow_style=None, width=100)


def _fmt_site(s, reg):
    moved = " moved %.1f mm onto the bone" % s.moved_mm if s.moved_mm else ""
    if s.how == "fleshy":
        return s.label
    if s.how == "landmark":
        return "the VHF tibial tuberosity (patellar ligament insertion, a landmark of the VHF tibia, not gait2392)"
    if s.how == "shared":
        return "%s (the gemelli's insertion, which its tendon joins; %s)%s" % (s.label, s.link, moved)
    if s.how == "moving":
        return ("%s (tibia_r moving point at knee_angle_r = %g, the patella in gait2392; on our patella's "
                "surface, %.1f mm away)" % (s.label, KNEE_REST, s.stand_in_mm))
    return "%s (%s)%s" % (s.label, s.link, moved)


def source_text(r, reg):
    bl = r["bundles"]
    if bl:
        head = "gait2392 %s path points%s" % (bundle_short(bl), ", mean of its %d bundles" % len(bl) if len(bl) > 1 else "")
    else:
        head = "not in gait2392"
    parts = [head,
             "origin: " + ", then ".join(_fmt_site(s, reg) for s in r["origin"]),
             "insertion: " + ", then ".join(_fmt_site(s, reg) for s in r["insertion"])]
    bodies = sorted({BODY_TO_LINK.get(s.link, "tibia_r") if s.how in ("fixed", "conditional", "shared", "moving")
                     else None for s in r["origin"] + r["insertion"]} - {None})
    if bodies:
        parts.append("mapped: " + "; ".join(
            "%s points %s" % (b, BODY_HOW[b] % (KNEE_REST, reg.tibia_scale[0]) if b == "tibia_r" else BODY_HOW[b])
            for b in bodies))
    parts += r["notes"]
    for d in r["conditional"]:
        parts.append("%s left out: conditional, active for %s in [%.3f, %.3f] rad, %.0f %% of the gait's range"
                     % (d["point"].split("-")[-1], d["coordinate"], d["range_rad"][0], d["range_rad"][1],
                        100 * d["gait_range_share"]) if not d["kept"] else
                     "%s kept: conditional, active over %.0f %% of the gait's range of %s"
                     % (d["point"].split("-")[-1], 100 * d["gait_range_share"], d["coordinate"]))
    return "; ".join(parts)


def yaml_keys(r, reg):
    LO = reg.link_origin

    def entry(s):
        return FlowMap(link=s.link, point=[float("%.*g" % (DIGITS, v)) + 0.0 for v in s.scene - LO[s.link]])
    keys = {"origin_path": [entry(s) for s in r["origin"]],
            "insertion_path": [entry(s) for s in r["insertion"]]}
    if r["belly"]:
        keys["belly_path"] = [entry(s) for s in r["belly"]]
    keys.update({"reference_muscles": list(r["bundles"]), "sites_source": source_text(r, reg)})
    return keys


def reference_model(reg):
    return {"osim": OSIM_IN_SCENE,
            "body_scales": {b: [round(float(v), 4) for v in sc] for b, sc in reg.body_scales().items()}}


def _r(x, d=2):
    return None if x is None else round(float(x), d) + 0.0   # no -0.0


def urdf_patella_track(reg):
    """The patella's slide (patella_track, the gait's knee angles) with the tibia scale of these sites, checked
    against the URDF's patella_slide_r: a URDF written from other measurements is an error, named."""
    knee = read_gait()["knee_angle_r"]
    track = patella_track(reg.params, reg.root, reg.tibia_scale, (float(knee.min()), float(knee.max())))
    import xml.etree.ElementTree as ET
    mimic = ET.parse(URDF).getroot().find("joint[@name='patella_slide_r']/mimic[@joint='knee_angle_r']")
    if mimic is None:
        raise ValueError("%s: no joint patella_slide_r mimicking knee_angle_r: rerun build_scene.py --urdf-only" % URDF)
    if mimic.get("multiplier") != "%.6g" % track["metres_per_rad"]:     # the URDF's precision (write_urdf)
        raise ValueError("%s: patella_slide_r mimics knee_angle_r at %s m/rad, the sites' fit gives %.6g: rerun "
                         "build_scene.py --urdf-only" % (URDF, mimic.get("multiplier"), track["metres_per_rad"]))
    return {k: ([_r(x, 5) for x in v] if k == "axis" else _r(v, 6) if k == "metres_per_rad" else
                [_r(x, 4) for x in v] if k == "knee_range_rad" else _r(v) if isinstance(v, float) else v)
            for k, v in track.items()}


def report(reg, rec):
    """The measurements behind the sites (tools/scene/sites_report.json, read by readme_text.py)."""
    out = {"knee_angle_rest_rad": KNEE_REST,
           "body_scales": reference_model(reg)["body_scales"],
           "tibia": {k: ([_r(x) for x in v] if isinstance(v, list) else _r(v, 4)) for k, v in reg.tibia_info.items()},
           "rules_mm": {"snap_max": SNAP_MAX * 1e3, "cover_margin": COVER_MARGIN * 1e3, "snap_far": SNAP_FAR * 1e3,
                        "fleshy": FLESHY * 1e3, "belly_end_tie": TIE * 1e3},
           "active_share": ACTIVE_SHARE,
           "order": list(rec),
           "hip_rest_rad": reg.params["vhf_rest_angles_rad"]["hip_flexion_adduction_rotation"],
           "patella_track": urdf_patella_track(reg),
           "muscles": {}}
    for name, r in rec.items():
        m = {"reference_muscles": r["bundles"], "notes": r["notes"], "ordered": r["ordered"],
             "belly_end_links": r["belly_end_links"],
             "conditional": [{k: (_r(v, 3) if isinstance(v, float) else v) for k, v in d.items()}
                             for d in r["conditional"]],
             "points": [{k: (_r(v) if isinstance(v, float) else v) for k, v in c.items()} for c in r["checks"]],
             "rest_length_mm": _r(r["rest_length"] * 1e3, 1), "tendon_rest_mm": _r(r["tendon_rest"] * 1e3, 1),
             "excursion_mm": _r(np.ptp(r["length"]) * 1e3)}
        if r["bundles"]:
            m.update({"ref_excursion_mm": _r(np.ptp(r["ref_length"]) * 1e3),
                      "generic_excursion_mm": _r(np.ptp(r["generic_length"]) * 1e3),
                      "r": _r(np.corrcoef(r["length"], r["ref_length"])[0, 1], 3),
                      "registered_r": _r(np.corrcoef(r["registered_length"], r["ref_length"])[0, 1], 3),
                      "registered_excursion_mm": _r(np.ptp(r["registered_length"]) * 1e3),
                      "registered_r_posed": _r(np.corrcoef(r["registered_length"], r["posed_length"])[0, 1], 3),
                      "posed_excursion_mm": _r(np.ptp(r["posed_length"]) * 1e3),
                      "ref_rest_length_mm": _r(r["ref_rest_length"] * 1e3, 1),
                      "tendon_slack_mm": _r(r["tendon_slack"] * 1e3, 1),
                      "moment_arms_at_rest_mm": {
                          "dofs": list(DOFS),
                          "ours": [_r(v * 1e3, 1) for v in r["moment_arms"]],
                          "registered": [_r(v * 1e3, 1) for v in r["registered_moment_arms"]],
                          "gait2392": [_r(v * 1e3, 1) for v in r["ref_moment_arms"]]}})
            if "fitted_tibia_moment_arms" in r:
                m["moment_arms_at_rest_mm"]["registered_fitted_tibia"] = [
                    _r(v * 1e3, 1) for v in r["fitted_tibia_moment_arms"]]
        out["muscles"][name] = m
    return out


def add_sites(doc, params, root, muscles, pkg=PKG):
    """Set the site keys of every muscle entry of the scene document and its reference_model (in place,
    reference_model right after `frame`); returns the report."""
    reg, rec = compute(pkg, params, root, muscles)
    entries = {m["name"]: m for m in doc["muscles"]}
    for name, r in rec.items():
        e = entries[name]
        for k in SITE_KEYS:
            e.pop(k, None)
        e.update(yaml_keys(r, reg))
    items = [(k, v) for k, v in doc.items() if k != "reference_model"]
    doc.clear()
    for k, v in items:
        doc[k] = v
        if k == "frame":
            doc["reference_model"] = reference_model(reg)
    return report(reg, rec)


def write_report(rep, path=REPORT_JSON):
    with open(path, "w") as f:
        json.dump(rep, f, indent=1, sort_keys=True, default=lambda o: o.item())  # numpy scalars
        f.write("\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 when the scene file differs")
    a = ap.parse_args()
    import build_scene   # the muscle table and the scene file's header
    params = json.load(open(PARAMS_JSON))
    root = sl.load_osim()
    with open(SCENE_YAML) as f:
        old = f.read()
    doc = yaml.safe_load(old)
    rep = add_sites(doc, params, root, build_scene.MUSCLES)
    buf = io.StringIO()
    dump_scene(build_scene.YAML_HEADER, doc, buf)
    if a.check:
        same = buf.getvalue() == old
        print("%s is %s" % (SCENE_YAML, "up to date" if same else "NOT up to date"))
        sys.exit(0 if same else 1)
    with open(SCENE_YAML, "w") as f:
        f.write(buf.getvalue())
    write_report(rep)
    for name, m in rep["muscles"].items():
        print("%-26s %-16s r %6s  excursion %6.1f mm (gait2392 %s)" % (
            name, ",".join(m["reference_muscles"]) or "-", m.get("r", "-"), m["excursion_mm"],
            m.get("ref_excursion_mm", "-")))


if __name__ == "__main__":
    main()
