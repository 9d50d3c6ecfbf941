#!/usr/bin/env python3
"""Build the bundled right hip + thigh scene from the raw VHF and OpenSim data.

Writes (relative to the package root):
  data/meshes/muscles/<name>.stl   muscle surfaces, metres, scene frame (pelvis link = world at zero)
  data/meshes/bones/<bone>.stl     bone surfaces, metres, in their URDF link frames
  urdf/right_hip_thigh.urdf        skeleton, zero configuration = VHF posture
  config/scenes/right_hip_thigh.yaml
  tools/scene/build_params.json    landmarks, registrations and scale factors
                                   (read by mot_to_bag.py and report.py)

Run:  PYENV_VERSION=system /usr/bin/python3 tools/scene/build_scene.py [--urdf-only]
      (--urdf-only rewrites just the URDF from build_params.json and the committed bones)
Deterministic: no random numbers; VTK filters and scipy's least squares are
deterministic for a fixed input.
"""

import json
import os
import sys

# Single-threaded BLAS / VTK: threaded reductions sum in varying order, and the
# registration optimiser amplifies those last-bit differences into different
# (equally good) results. One thread keeps the build byte-for-byte reproducible.
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VTK_SMP_MAX_THREADS"):
    os.environ.setdefault(_v, "1")
# OpenVDB (the bone carve, carve.py) runs on TBB, which sizes its thread pool from
# the CPU affinity mask: one CPU (the one the build starts on) keeps it to one thread.
os.sched_setaffinity(0, {int(open("/proc/self/stat").read().rsplit(")", 1)[1].split()[36])})

import numpy as np  # noqa: E402
import vtk  # noqa: E402
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from vtk.util.numpy_support import vtk_to_numpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scenelib as sl  # noqa: E402

# ---------------------------------------------------------------------------
# Muscle table: scene name, VHF file stem, gait2392 musculotendon used for the
# origin/insertion bodies (None: not in gait2392, anatomical attachment used),
# groups, display colour (RGBA, 0-1).
# ---------------------------------------------------------------------------
MUSCLES = [
    # name, VHF stem, gait2392 muscle, tags, colour
    ("rectus_femoris", "Right_Muscle_RectusFemoris", "rect_fem_r", ["thigh13"], (0.85, 0.20, 0.20, 1.0)),
    ("vastus_lateralis", "Right_Muscle_VastusLateralis", "vas_lat_r", ["thigh13"], (0.80, 0.35, 0.25, 1.0)),
    ("vastus_medialis", "Right_Muscle_VastusMedialis", "vas_med_r", ["thigh13"], (0.90, 0.45, 0.30, 1.0)),
    ("vastus_intermedius", "Right_Muscle_VastusIntermedius", "vas_int_r", ["thigh13"], (0.70, 0.25, 0.20, 1.0)),
    ("sartorius", "Right_Muscle_Sartorius", "sar_r", ["thigh13"], (0.95, 0.65, 0.30, 1.0)),
    ("gracilis", "Right_Muscle_Gracilis", "grac_r", ["thigh13"], (0.75, 0.55, 0.35, 1.0)),
    ("semitendinosus", "Right_Muscle_Semitendonosus", "semiten_r", ["thigh13"], (0.60, 0.20, 0.45, 1.0)),
    ("semimembranosus", "Right_Muscle_Semimembranosus", "semimem_r", ["thigh13"], (0.70, 0.30, 0.55, 1.0)),
    ("biceps_femoris_long_head", "Left_Muscle_BicepsFemorisLong", "bifemlh_r", ["thigh13"], (0.55, 0.15, 0.35, 1.0)),
    ("adductor_longus", "Right_Muscle_AdductorLongus", "add_long_r", ["thigh13"], (0.30, 0.55, 0.80, 1.0)),
    ("adductor_brevis", "Right_Muscle_AdductorBrevis", "add_brev_r", ["thigh13"], (0.25, 0.45, 0.70, 1.0)),
    ("adductor_magnus", "Right_Muscle_AdductorMagnus", "add_mag2_r", ["thigh13"], (0.20, 0.35, 0.60, 1.0)),
    ("pectineus", "Right_Muscle_Pectineus", "pect_r", ["thigh13"], (0.35, 0.65, 0.85, 1.0)),
    ("biceps_femoris_short_head", "Right_Muscle_BicepsFemorisShortHead", "bifemsh_r", ["thigh"], (0.45, 0.10, 0.30, 1.0)),
    ("gluteus_maximus", "Right_Muscle_GluteusMaximus", "glut_max2_r", ["hip"], (0.80, 0.30, 0.40, 1.0)),
    ("gluteus_medius", "Right_Muscle_GluteusMedius", "glut_med2_r", ["hip"], (0.85, 0.45, 0.50, 1.0)),
    ("gluteus_minimus", "Right_Muscle_GluteusMinimus", "glut_min2_r", ["hip"], (0.90, 0.60, 0.60, 1.0)),
    ("iliacus", "Right_Muscle_Illiacus", "iliacus_r", ["hip"], (0.40, 0.70, 0.40, 1.0)),
    ("psoas_major", "Right_Muscle_PsoasMajor", "psoas_r", ["hip"], (0.30, 0.60, 0.30, 1.0)),
    ("piriformis", "Right_Muscle_Piriformis", "peri_r", ["hip"], (0.60, 0.50, 0.20, 1.0)),
    ("tensor_fasciae_latae", "Right_Muscle_TensorFasciaeLatae", "tfl_r", ["hip"], (0.95, 0.80, 0.40, 1.0)),
    ("obturator_internus", "Right_Muscle_ObturatorInternus", None, ["hip"], (0.50, 0.40, 0.70, 1.0)),
    ("obturator_externus", "Right_Muscle_ObturatorExternus", None, ["hip"], (0.40, 0.30, 0.65, 1.0)),
    ("superior_gemellus", "Right_Muscle_SuperiorGemellus", "gem_r", ["hip"], (0.70, 0.60, 0.30, 1.0)),
    ("inferior_gemellus", "Right_Muscle_InferiorGemellus", "gem_r", ["hip"], (0.65, 0.55, 0.25, 1.0)),
    ("quadratus_femoris", "Right_Muscle_QuadratisFemoris", "quad_fem_r", ["hip"], (0.75, 0.45, 0.20, 1.0)),
]

# gait2392 body -> URDF link. gait2392 has no patella body: its quadriceps end on
# tibia_r through moving path points that stand in for the patella. Our patella
# is a link of its own (fixed to the tibia), so the four quadriceps, which
# anatomically insert on the patella, are given patella_r (see QUADRICEPS).
BODY_TO_LINK = {"pelvis": "pelvis", "femur_r": "femur_r", "tibia_r": "tibia_r"}
QUADRICEPS = {"rectus_femoris", "vastus_lateralis", "vastus_medialis", "vastus_intermedius"}

TARGET_TRIS = 4000      # muscle decimation target (triangles)
BONE_TRIS = 4000        # VHF bone decimation target
JOINT_REGION_RADIUS = 0.035  # m: the femoral head and acetabulum lie within this of the hip centre
SDF_SPACING = 0.0015    # m, signed-distance grid used by the registrations


def out_path(*p):
    return os.path.join(sl.PKG, *p)


def vhf(stem):
    return sl.read_stl(os.path.join(sl.VHF_DIR, "VHF_%s_smooth.stl" % stem))


def to_ros_pd(pd, mirror_x_mm=None):
    """VHF mm polydata -> ROS axes, metres (origin still the VHF origin).

    mirror_x_mm: mirror about the sagittal plane x = mirror_x_mm first; a
    mirror reverses handedness, so the triangle winding is flipped to keep the
    normals pointing outward."""
    P = sl.pd_points(pd)
    T = sl.pd_triangles(pd)
    if mirror_x_mm is not None:
        P = P.copy()
        P[:, 0] = 2.0 * mirror_x_mm - P[:, 0]
        T = T[:, [0, 2, 1]]
    return sl.make_pd(sl.vhf_mm_to_ros(P), T)


def closed_ok(pd):
    b, nm = sl.open_edges(pd)
    return b == 0 and nm == 0 and sl.nonmanifold_vertices(pd) == 0


def process_closed(pd, target, log, name):
    """Decimate, then verify closed + 2-manifold + outward; repair if needed."""
    out = sl.decimate(pd, target)
    notes = []
    if not closed_ok(out):
        b, nm = sl.open_edges(out)
        notes.append("decimation left %d boundary / %d non-manifold edges, %d bow-tie vertices: "
                     "holes filled (vtkFillHolesFilter), largest piece kept"
                     % (b, nm, sl.nonmanifold_vertices(out)))
        out = sl.repair(out)
        if not closed_ok(out):
            # last resort: decimate the raw surface slightly differently
            for k in (0.9, 1.1, 1.25):
                alt = sl.decimate(pd, int(target * k))
                if closed_ok(alt):
                    out = alt
                    notes.append("re-decimated to %d triangles instead" % int(target * k))
                    break
    if sl.signed_volume(out) < 0:
        out = sl.flip_winding(out)
        notes.append("winding flipped to face outward")
    log[name] = notes
    return out


# ---------------------------------------------------------------------------
# landmarks
# ---------------------------------------------------------------------------

def vhf_landmarks():
    L = {}
    head = sl.pd_points(vhf("Right_Cartilage_FemurHead"))
    c, r = sl.sphere_fit(head)
    L["hip_centre_mm"], L["head_radius_mm"] = c, r
    ac = sl.pd_points(vhf("Right_Cartilage_PelvisAcetabulum"))
    L["acetabulum_centre_mm"], L["acetabulum_radius_mm"] = sl.sphere_fit(ac)
    # Knee: each femoral condyle's posterior-distal cartilage is close to a sphere;
    # the flexion axis passes through both sphere centres, the knee centre is their
    # midpoint. Condyles are split at the cartilage centroid in x (medial < lateral),
    # the trochlea (anterior half) is left out of the fits.
    D = sl.pd_points(vhf("Right_Cartilage_FemurDistal"))
    cen = D.mean(0)
    post = D[:, 1] < cen[1]
    med_c, med_r = sl.sphere_fit(D[(D[:, 0] < cen[0]) & post])
    lat_c, lat_r = sl.sphere_fit(D[(D[:, 0] >= cen[0]) & post])
    L["medial_condyle_mm"], L["lateral_condyle_mm"] = med_c, lat_c
    L["condyle_radii_mm"] = (med_r, lat_r)
    L["knee_centre_mm"] = 0.5 * (med_c + lat_c)
    # Sagittal midline from the (midline) sacrum: centre of its x extent.
    S = sl.pd_points(vhf("Left_Bone_Sacrum"))
    L["midline_x_mm"] = 0.5 * (S[:, 0].min() + S[:, 0].max())
    return L


def os_femur_condyles(F):
    """Condyle sphere centres of the OpenSim femur (OS axes): distal 3 cm, posterior half."""
    d = F[(F[:, 1] < F[:, 1].min() + 0.06) & (F[:, 0] < 0.0)]
    lat, _ = sl.sphere_fit(d[d[:, 2] > 0.0])
    med, _ = sl.sphere_fit(d[d[:, 2] <= 0.0])
    return med, lat


# ---------------------------------------------------------------------------
# signed distance grids and similarity registration
# ---------------------------------------------------------------------------

# SDFGrid, sim_apply, sim_inverse live in scenelib (tools/scene/sites.py maps points with them too)
SDFGrid, sim_apply, sim_inverse = sl.SDFGrid, sl.sim_apply, sl.sim_inverse


def frame_from(a, b):
    """Orthonormal frame: e1 along a, e2 = b orthogonalised against a."""
    e1 = a / np.linalg.norm(a)
    e2 = b - (b @ e1) * e1
    e2 /= np.linalg.norm(e2)
    return np.column_stack([e1, e2, np.cross(e1, e2)])


rotvec_from_matrix = sl.rotvec_from_matrix


def penetration(sdf, x, Q):
    """Depth (m, >= 0) of world points Q inside the registered bone of params x."""
    d = sdf(sim_inverse(x, Q)) * np.exp(x[6:9]).mean()
    return np.maximum(0.0, -d)


def register_femur(F_ros, L_ros, cart_head, cart_distal, muscle_pts):
    """Scale and place the OpenSim femur (ROS axes, metres) onto the VHF landmarks.

    Terms (metres): head centre -> femoral-head cartilage sphere centre (weight
    10); condyle centres -> VHF condyle sphere centres (3); cartilage vertices
    lie on the bone surface, i.e. 0..3 mm outside it (target +1.5 mm); muscle
    vertices must not be inside the bone (depth penalised)."""
    pd = F_ros["pd"]
    sdf = SDFGrid(pd, SDF_SPACING)
    med_os, lat_os = F_ros["med"], F_ros["lat"]
    H, med, lat = L_ros["hip"], L_ros["med"], L_ros["lat"]
    K_os, K = 0.5 * (med_os + lat_os), 0.5 * (med + lat)
    # initial guess: long axis and condyle axis aligned, isotropic scale by length
    R0 = frame_from(K - H, lat - med) @ frame_from(K_os, lat_os - med_os).T
    s0 = np.linalg.norm(K - H) / np.linalg.norm(K_os)
    x0 = np.concatenate([rotvec_from_matrix(R0), H, np.log([s0, s0, s0])])
    ch = cart_head[:: max(1, len(cart_head) // 400)]
    cd = cart_distal[:: max(1, len(cart_distal) // 600)]
    Fx = sim_apply(x0, sl.pd_points(pd))
    lo, hi = Fx.min(0) - 0.03, Fx.max(0) + 0.03
    M = muscle_pts[np.all((muscle_pts > lo) & (muscle_pts < hi), axis=1)]
    wm = 1.0 / np.sqrt(max(1, len(M)) / 2000.0)

    def res(x):
        s = np.exp(x[6:9]).mean()
        r = [10 * (sim_apply(x, np.zeros((1, 3)))[0] - H),
             3 * (sim_apply(x, med_os[None])[0] - med),
             3 * (sim_apply(x, lat_os[None])[0] - lat),
             0.5 * (sdf(sim_inverse(x, ch)) * s - 0.0015),
             0.5 * (sdf(sim_inverse(x, cd)) * s - 0.0015),
             wm * penetration(sdf, x, M)]
        return np.concatenate(r)
    lb = np.concatenate([-np.full(3, np.pi), x0[3:6] - 0.05, np.log([0.75] * 3)])
    ub = np.concatenate([np.full(3, np.pi), x0[3:6] + 0.05, np.log([1.35] * 3)])
    sol = least_squares(res, x0, bounds=(lb, ub), x_scale=np.r_[[0.05] * 3, [0.005] * 3, [0.05] * 3],
                        max_nfev=400)
    return sol.x, x0, sdf


def pd_bounds(pd):
    b = np.array(pd.GetBounds()).reshape(3, 2)
    return b[:, 0][None], b[:, 1][None]


def register_pelvis(P_pd, hip_os_r, hip_os_l, sac_os, L_ros, vhf_sacrum, cart_acet, muscle_pts):
    """Scale and place the OpenSim pelvis (right hip bone; ROS axes, metres).

    Terms: right hip centre -> VHF femoral-head sphere centre (weight 10); left
    hip centre -> its mirror about the sacral midline (3); OpenSim sacrum
    vertices -> VHF sacrum surface (robust, 0.3); acetabular cartilage vertices
    0..3 mm outside the bone (0.5); hip-muscle vertices not inside the bone."""
    sdf = SDFGrid(P_pd, SDF_SPACING)
    H, HL = L_ros["hip"], L_ros["hip_l"]
    tree = cKDTree(vhf_sacrum)
    s_ml = np.linalg.norm(H - HL) / np.linalg.norm(hip_os_r - hip_os_l)
    s0 = np.array([1.0, s_ml, 1.0])
    x0 = np.concatenate([np.zeros(3), np.zeros(3), np.log(s0)])
    x0[3:6] = H - sim_apply(x0, hip_os_r[None])[0]
    ca = cart_acet[:: max(1, len(cart_acet) // 500)]
    M = muscle_pts

    wm = 1.0 / np.sqrt(max(1, len(M)) / 2000.0)

    def res(x):
        s = np.exp(x[6:9]).mean()
        d_sac, _ = tree.query(sim_apply(x, sac_os))
        r = [10 * (sim_apply(x, hip_os_r[None])[0] - H),
             3 * (sim_apply(x, hip_os_l[None])[0] - HL),
             0.3 * d_sac / np.sqrt(len(sac_os) / 50.0),
             0.5 * (sdf(sim_inverse(x, ca)) * s - 0.0015),
             wm * penetration(sdf, x, M)]
        return np.concatenate(r)
    lb = np.concatenate([-np.full(3, 0.6), x0[3:6] - 0.06, np.log([0.75] * 3)])
    ub = np.concatenate([np.full(3, 0.6), x0[3:6] + 0.06, np.log([1.4] * 3)])
    sol = least_squares(res, x0, bounds=(lb, ub), x_scale=np.r_[[0.05] * 3, [0.005] * 3, [0.05] * 3],
                        loss="soft_l1", f_scale=0.01, max_nfev=400)
    return sol.x, x0, sdf


body_fixed_zxy = sl.body_fixed_zxy


def os_bone(name):
    """OpenSim bone surface in ROS axes (metres), closed and outward."""
    pd = sl.read_vtp(os.path.join(sl.OSIM_DIR, "Geometry", name + ".vtp"))
    pd = sl.transform_pd(pd, sl.os_to_ros)  # proper rotation: winding unchanged
    notes = []
    b, nm = sl.open_edges(pd)
    if b or nm:
        notes.append("OpenSim mesh had %d boundary and %d non-manifold edges: repaired "
                     "(non-manifold faces split off, holes filled)" % (b, nm))
        pd = fix_open_bone(pd)
    if sl.signed_volume(pd) < 0:
        pd = sl.flip_winding(pd)
    return pd, notes


def fix_open_bone(pd):
    """Make a coarse OpenSim bone watertight: drop duplicated triangles and the
    triangles on non-manifold edges, then close every boundary loop with a fan
    around the loop centroid (the holes are small, nearly planar loops)."""
    P = sl.pd_points(pd)
    T = sl.pd_triangles(pd)
    _, first = np.unique(np.sort(T, axis=1), axis=0, return_index=True)
    T = T[np.sort(first)]
    for _ in range(5):
        e = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
        _, inv, cnt = np.unique(e, axis=0, return_inverse=True, return_counts=True)
        bad = (cnt[inv.ravel()] > 2).reshape(3, -1).any(axis=0)
        if not bad.any():
            break
        T = T[~bad]
    # directed boundary edges: (a, b) used by a triangle whose neighbour is missing
    directed = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    have = {(a, b) for a, b in directed}
    nxt = {a: b for a, b in directed if (b, a) not in have}
    P = list(P)
    new = []
    while nxt:
        start = min(nxt)
        loop = [start]
        while nxt[loop[-1]] != start:
            loop.append(nxt[loop[-1]])
        for v in loop:
            del nxt[v]
        c = len(P)
        P.append(np.mean([P[v] for v in loop], axis=0))
        for a, b in zip(loop, loop[1:] + loop[:1]):
            new.append((b, a, c))  # reverse of the boundary edge keeps the winding
    T = np.vstack([T, np.array(new, dtype=np.int64).reshape(-1, 3)])
    out = sl.largest_component(sl.make_pd(np.array(P), T))
    if sl.signed_volume(out) < 0:
        out = sl.flip_winding(out)
    return out


def deform_out(bone_pd, muscle_pts, margin=0.5e-3, sigma=3e-3, iters=25, max_step=None, max_total=None):
    """Overclosure adjustment of a substituted (OpenSim) bone.

    The generic OpenSim femur / hip bone cannot match the VHF anatomy exactly,
    so after registration some muscle vertices still lie inside it. The muscle
    surfaces are the VHF ground truth; the bone is the stand-in. So the bone
    surface is pushed locally inward under every penetrating muscle vertex (by
    its depth plus `margin`), the push spread over the bone surface with a
    Gaussian of width `sigma` (a smooth radial-basis displacement field, in the
    spirit of the overclosure adjustment of Andreassen et al.), and repeated
    until no muscle vertex is inside. Topology is unchanged. A wide kernel
    (sigma larger than the bone's thickness) moves both faces of a thin plate
    together, so a misplaced iliac wing shifts into the gap between the muscles
    on its two sides instead of being squeezed flat; max_step bounds each
    iteration's move and the loop stops before the volume collapses."""
    P = sl.pd_points(bone_pd).copy()
    T = sl.pd_triangles(bone_pd)
    lo, hi = P.min(0) - 0.01, P.max(0) + 0.01
    Q = muscle_pts[np.all((muscle_pts > lo) & (muscle_pts < hi), axis=1)]
    moved = np.zeros(len(P))
    v0 = sl.signed_volume(bone_pd)
    P_init = P.copy()
    for _ in range(iters):
        pd = sl.make_pd(P, T)
        f = vtk.vtkImplicitPolyDataDistance()
        f.SetInput(pd)
        c = [0.0, 0.0, 0.0]
        cs, us = [], []
        for q in Q:
            d = f.EvaluateFunctionAndGetClosestPoint(q, c)
            if d < margin * 0.5:  # inside (negative) or touching
                v = q - np.array(c)
                n = np.linalg.norm(v)
                if n < 1e-9:
                    continue
                cs.append(np.array(c))
                # inside: move the surface past q; touching from outside: step back
                us.append(v / n * (n + margin) if d < 0 else -v / n * (margin - n))
        if not cs:
            break
        cs, us = np.array(cs), np.array(us)
        tree = cKDTree(cs)
        D = np.zeros_like(P)
        for i, nb in enumerate(tree.query_ball_point(P, 3 * sigma)):
            if nb:
                w = np.exp(-((cs[nb] - P[i]) ** 2).sum(1) / (2 * sigma ** 2))
                D[i] = (w[:, None] * us[nb]).sum(0) / max(1.0, w.sum())
        if max_step is not None:
            n = np.linalg.norm(D, axis=1)
            D *= np.minimum(1.0, max_step / np.maximum(n, 1e-12))[:, None]
        if max_total is not None:
            # bound every vertex's total displacement: a generic bone bent too far
            # turns ragged, which is worse than a few millimetres of overlap
            Pn = P + D - P_init
            n = np.linalg.norm(Pn, axis=1)
            D = P_init + Pn * np.minimum(1.0, max_total / np.maximum(n, 1e-12))[:, None] - P
        if sl.signed_volume(sl.make_pd(P + D, T)) < 0.85 * v0:
            break
        P += D
    moved = np.linalg.norm(P - P_init, axis=1)
    return sl.make_pd(P, T), float(moved.max()), len(Q)


def subdivide(pd, levels):
    """Butterfly subdivision: interpolating, so the coarse OpenSim bone keeps its
    vertices and size while its facets are smoothed for display and contact."""
    f = vtk.vtkButterflySubdivisionFilter()
    f.SetInputData(pd)
    f.SetNumberOfSubdivisions(levels)
    f.Update()
    return sl.clean(f.GetOutput())


def fmt(v):
    return " ".join("%.6g" % (0.0 if abs(a) < 5e-10 else a) for a in v)


def main():
    log = {}
    L = vhf_landmarks()
    Lr = {"hip": sl.vhf_mm_to_ros(L["hip_centre_mm"][None])[0],
          "med": sl.vhf_mm_to_ros(L["medial_condyle_mm"][None])[0],
          "lat": sl.vhf_mm_to_ros(L["lateral_condyle_mm"][None])[0]}
    hl = L["hip_centre_mm"].copy()
    hl[0] = 2 * L["midline_x_mm"] - hl[0]
    Lr["hip_l"] = sl.vhf_mm_to_ros(hl[None])[0]
    Lr["knee"] = 0.5 * (Lr["med"] + Lr["lat"])

    # ---- muscles (VHF ROS-axis coordinates for now) ----
    muscles = {}
    for name, stem, _, _, _ in MUSCLES:
        raw = vhf(stem)
        mirror = L["midline_x_mm"] if stem.startswith("Left_") else None
        pd = to_ros_pd(raw, mirror)
        if sl.signed_volume(pd) < 0:
            pd = sl.flip_winding(pd)
        muscles[name] = (raw.GetNumberOfCells(), process_closed(pd, TARGET_TRIS, log, name))
        print("muscle %-26s %6d -> %5d triangles" % (name, raw.GetNumberOfCells(),
                                                      muscles[name][1].GetNumberOfCells()), flush=True)
    all_muscle = np.concatenate([sl.pd_points(m) for _, m in muscles.values()])
    hip_names = {m[0] for m in MUSCLES if "hip" in m[3]} | {"rectus_femoris", "sartorius", "pectineus",
                                                             "adductor_longus", "adductor_brevis",
                                                             "adductor_magnus", "gracilis",
                                                             "semitendinosus", "semimembranosus",
                                                             "biceps_femoris_long_head"}
    hip_muscle = np.concatenate([sl.pd_points(muscles[n][1]) for n in sorted(hip_names)])

    # ---- femur registration ----
    femur_raw, fnotes = os_bone("femur_r")
    femur_raw = subdivide(femur_raw, 1)
    med_os, lat_os = os_femur_condyles(sl.pd_points(
        sl.read_vtp(os.path.join(sl.OSIM_DIR, "Geometry", "femur_r.vtp"))))
    med_os, lat_os = sl.os_to_ros(med_os[None])[0], sl.os_to_ros(lat_os[None])[0]
    cart_h = sl.vhf_mm_to_ros(sl.pd_points(vhf("Right_Cartilage_FemurHead")))
    cart_d = sl.vhf_mm_to_ros(sl.pd_points(vhf("Right_Cartilage_FemurDistal")))
    xf, xf0, _ = register_femur({"pd": femur_raw, "med": med_os, "lat": lat_os}, Lr, cart_h, cart_d, all_muscle)
    print("femur registration scale", np.exp(xf[6:9]), flush=True)

    # ---- pelvis registration ----
    root = sl.load_osim()
    hip_os = sl.joint_offset(root, "hip_r", 0)
    hip_os_r = sl.os_to_ros(hip_os[None])[0]
    hip_os_l = sl.os_to_ros((hip_os * [1, 1, -1])[None])[0]
    pel_r, pnotes = os_bone("pelvis")
    pel_l, plnotes = os_bone("l_pelvis")
    pel_r, pel_l = subdivide(pel_r, 2), subdivide(pel_l, 2)
    sac_os = sl.pd_points(sl.transform_pd(sl.read_vtp(os.path.join(sl.OSIM_DIR, "Geometry", "sacrum.vtp")),
                                          sl.os_to_ros))
    vsac = sl.vhf_mm_to_ros(sl.pd_points(vhf("Left_Bone_Sacrum")))
    cart_a = sl.vhf_mm_to_ros(sl.pd_points(vhf("Right_Cartilage_PelvisAcetabulum")))
    xp, xp0, _ = register_pelvis(pel_r, hip_os_r, hip_os_l, sac_os, Lr, vsac, cart_a, hip_muscle)
    print("pelvis registration scale", np.exp(xp[6:9]), flush=True)

    # ---- scene frame: origin = registered gait2392 pelvis origin, ROS axes ----
    O = sim_apply(xp, np.zeros((1, 3)))[0]
    Rp = sl.rotvec_to_matrix(xp[:3])
    Rf = sl.rotvec_to_matrix(xf[:3])
    H = Lr["hip"] - O          # hip joint centre, scene frame
    K = Lr["knee"] - O         # knee joint centre, scene frame

    def shift(pd, origin):
        return sl.transform_pd(pd, lambda P: P - origin)

    # muscles: scene (= pelvis link) frame
    for name, (_, pd) in muscles.items():
        sl.write_stl(shift(pd, O), out_path("data", "meshes", "muscles", name + ".stl"))

    # bones in link frames
    bones = {}
    bone_notes = {"femur_r": fnotes, "hip_r": pnotes, "hip_l": plnotes}
    pelvis_to_scene = lambda P: sim_apply(xp, P) - O  # noqa: E731
    muscle_scene = np.concatenate([sl.pd_points(m) for _, m in muscles.values()]) - O
    hip_r_scene, mv, nq = deform_out(sl.transform_pd(pel_r, pelvis_to_scene), muscle_scene,
                                    sigma=8e-3, iters=20, max_step=1e-3, max_total=6e-3)
    bone_notes["hip_r"].append("overclosure adjustment: surface moved inward by up to %.1f mm under "
                               "penetrating muscle vertices" % (mv * 1e3))
    bones["hip_r"] = ("pelvis", hip_r_scene)
    bones["hip_l"] = ("pelvis", sl.transform_pd(pel_l, pelvis_to_scene))
    for b, stem in (("sacrum", "Left_Bone_Sacrum"), ("coccyx", "Left_Bone_Coccyx")):
        pd = process_closed(to_ros_pd(vhf(stem)), BONE_TRIS, bone_notes, b)
        bones[b] = ("pelvis", shift(pd, O))
    femur_scene = sl.transform_pd(femur_raw, lambda P: sim_apply(xf, P) - O)
    femur_scene, mv, nq = deform_out(femur_scene, muscle_scene, max_total=8e-3)
    bone_notes["femur_r"].append("overclosure adjustment: surface moved inward by up to %.1f mm under "
                                 "penetrating muscle vertices" % (mv * 1e3))
    bones["femur_r"] = ("femur_r", shift(femur_scene, H))
    patella_pd = process_closed(to_ros_pd(vhf("Right_Bone_Patella")), BONE_TRIS, bone_notes, "patella_r")
    Pc = sl.pd_points(patella_pd).mean(0) - O  # patella link origin: its centroid
    for b, stem in (("tibia_r", "Right_Bone_Tibia"), ("fibula_r", "Right_Bone_Fibula")):
        pd = process_closed(to_ros_pd(vhf(stem)), BONE_TRIS, bone_notes, b)
        bones[b] = ("tibia_r", shift(shift(pd, O), K))
    bones["patella_r"] = ("patella_r", shift(shift(patella_pd, O), Pc))
    for b, (link, pd) in bones.items():
        if sl.signed_volume(pd) < 0:
            bones[b] = (link, sl.flip_winding(pd))

    # ---- the stand-in bones give way to the measured muscles: every bone a muscle overlaps at rest is carved
    # by the muscles grown by a clearance (carve.py); the others are written as they are
    link_origin = {"pelvis": np.zeros(3), "femur_r": H, "tibia_r": K, "patella_r": Pc}
    muscles_scene = {name: shift(pd, O) for name, (_, pd) in muscles.items()}
    bones_scene = {b: shift(pd, -link_origin[link]) for b, (link, pd) in bones.items()}
    import carve  # OpenVDB: only the full build needs it, not the tools that import this module's tables
    carved, carve_stats = carve.carve_bones(bones_scene, muscles_scene, {"hip_r": H, "femur_r": H},
                                            JOINT_REGION_RADIUS)
    for b in carve_stats:
        link = bones[b][0]
        bones[b] = (link, shift(carved[b], link_origin[link]))
        bone_notes.setdefault(b, []).append(
            "carved by %s (clearance %.1f mm): volume %.1f -> %.1f ml"
            % (", ".join(carve_stats[b]["muscles_overlapping"]), carve_stats[b]["clearance_mm"],
               carve_stats[b]["volume_before_ml"], carve_stats[b]["volume_after_ml"]))
    for b, (_, pd) in bones.items():
        sl.write_stl(pd, out_path("data", "meshes", "bones", b + ".stl"))
        print("bone %-10s %5d triangles closed=%s" % (b, pd.GetNumberOfCells(), closed_ok(pd)), flush=True)

    # ---- knee translation scale: the spline translations live in the femur
    # frame; OpenSim's scale tool scales them with the femur, so we do the same
    # with the registration scale (AP for tx, long axis for ty).
    sf = np.exp(xf[6:9])
    tx, ty = sl.knee_splines(root)
    params = {
        "units": "metres, radians; coordinates in the scene frame (pelvis link = world at zero)",
        "vhf_landmarks_mm": {k: np.asarray(v).tolist() for k, v in L.items()},
        "scene_origin_in_vhf_ros_m": O.tolist(),
        "hip_centre": H.tolist(),
        "knee_centre": K.tolist(),
        "patella_origin": Pc.tolist(),
        "femur_registration": {"rotvec": xf[:3].tolist(), "translation_vhf_ros": xf[3:6].tolist(),
                               "scale_ap_ml_long": sf.tolist(), "initial": xf0.tolist()},
        "pelvis_registration": {"rotvec": xp[:3].tolist(), "translation_vhf_ros": xp[3:6].tolist(),
                                "scale_ap_ml_si": np.exp(xp[6:9]).tolist(), "initial": xp0.tolist()},
        "registered_femoral_head_centre": (sim_apply(xf, np.zeros((1, 3)))[0] - O).tolist(),
        "registered_pelvis_hip_centre": (sim_apply(xp, hip_os_r[None])[0] - O).tolist(),
        "knee_spline_scale": {"tx": float(sf[0]), "ty": float(sf[2])},
        "knee_spline_at_zero": {"tx": float(tx(0.0)), "ty": float(ty(0.0))},
        "vhf_rest_angles_rad": {
            "pelvis_tilt_list_rotation": body_fixed_zxy(Rp).tolist(),
            "hip_flexion_adduction_rotation": body_fixed_zxy(Rp.T @ Rf).tolist()},
        "notes": {k: v for k, v in {**log, **bone_notes}.items() if v},
        "carve": carve_stats,
    }
    with open(out_path("tools", "scene", "build_params.json"), "w") as f:
        json.dump(params, f, indent=1, sort_keys=True)

    write_urdf(root, H, K, Pc, Rp, Rf, sf, xp, patella_track(params, root))
    write_yaml(root)
    print(json.dumps(params["notes"], indent=1))


# ---------------------------------------------------------------------------
# URDF
# ---------------------------------------------------------------------------

def body_inertial(root, body, R, scale, origin):
    """gait2392 mass, centre of mass (registered) and principal inertia (axes
    permuted to ROS; registration rotation ignored: display/tf only)."""
    b = root.find(".//Body[@name='%s']" % body)
    m = float(b.find("mass").text)
    com = sl.os_to_ros(sl._floats(b.find("mass_center").text)[None])[0]
    com = R @ (com * scale) + origin
    I = sl._floats(b.find("inertia").text)[:3]
    I_ros = [I[0], I[2], I[1]]
    return ('    <inertial>\n      <origin xyz="%s" rpy="0 0 0"/>\n      <mass value="%.4f"/>\n'
            '      <inertia ixx="%.4f" ixy="0" ixz="0" iyy="%.4f" iyz="0" izz="%.4f"/>\n    </inertial>\n'
            % (fmt(com), m, I_ros[0], I_ros[1], I_ros[2]))


def patella_track(params, root):
    """The patella's slide with the knee (sites.patella_track), fitted over the bundled gait's knee angles,
    with the tibia's measured scale (sites.fit_tibia, rounded as the scene file's body_scales are)."""
    import sites
    _, tibia = sites.fit_tibia(sl.PKG, params, root)
    knee = sites.read_gait()["knee_angle_r"]
    return sites.patella_track(params, root, [round(tibia["scale"], 4)] * 3, (float(knee.min()), float(knee.max())))


def rewrite_urdf():
    """Only the URDF, from build_params.json and the committed bones (what a change to write_urdf needs; the
    meshes, registrations and scene file stay as they are)."""
    root = sl.load_osim()
    with open(out_path("tools", "scene", "build_params.json")) as f:
        params = json.load(f)
    fr, pr = params["femur_registration"], params["pelvis_registration"]
    xp = np.concatenate([pr["rotvec"], pr["translation_vhf_ros"], np.log(pr["scale_ap_ml_si"])])
    write_urdf(root, np.array(params["hip_centre"]), np.array(params["knee_centre"]),
               np.array(params["patella_origin"]), sl.rotvec_to_matrix(pr["rotvec"]), sl.rotvec_to_matrix(fr["rotvec"]),
               np.array(fr["scale_ap_ml_long"]), xp, patella_track(params, root))


def write_urdf(root, H, K, Pc, Rp, Rf, sf, xp, patella):
    """patella: how the patella slides with the knee (sites.patella_track)."""
    pkg = "package://muscle_deformation/data/meshes/bones/"
    ex, ey, ez = np.eye(3)
    os_x, os_y, os_z = ex, ez, -ey   # OpenSim axes written in ROS axes

    def rng(coord):
        c = root.find(".//Coordinate[@name='%s']" % coord)
        return sl._floats(c.find("range").text)

    def unit(v):
        v = np.asarray(v, float)
        return v / np.linalg.norm(v)

    lines = ['<?xml version="1.0"?>',
             '<!-- Generated by tools/scene/build_scene.py: do not edit by hand.',
             '     Right hip + thigh skeleton. Units: metres, radians. Frames: REP 103 (X forward,',
             '     Y left, Z up). Zero configuration = posture of the Visible Human Female (VHF)',
             '     data; every link frame is parallel to world at zero. Joint names and axes follow',
             '     OpenSim gait2392 (OpenSim Y up converted: ROS x = OS x, ROS y = -OS z, ROS z = OS y).',
             '     Hip and knee axes are gait2392\'s parent-body axes as registered into the VHF',
             '     (pelvis / femur registration rotations applied). Bone meshes: see data/NOTICE. -->',
             '<robot name="right_hip_thigh">',
             '  <link name="world"/>']

    def link(name, body=None, meshes=(), inertial=""):
        s = '  <link name="%s">\n' % name + inertial
        for m in meshes:
            for tag in ("visual", "collision"):
                s += ('    <%s name="%s">\n      <origin xyz="0 0 0" rpy="0 0 0"/>\n      <geometry>\n'
                      '        <mesh filename="%s%s.stl" scale="1 1 1"/>\n      </geometry>\n' % (tag, m, pkg, m))
                if tag == "visual":
                    s += '      <material name="bone"><color rgba="0.92 0.88 0.78 1"/></material>\n'
                s += '    </%s>\n' % tag
        s += '  </link>'
        lines.append(s)

    def joint(name, jtype, parent, child, xyz=(0, 0, 0), axis=None, limits=None, comment=None, mimic=None):
        s = ''
        if comment:
            s += '  <!-- %s -->\n' % comment
        s += '  <joint name="%s" type="%s">\n    <parent link="%s"/>\n    <child link="%s"/>\n' % (
            name, jtype, parent, child)
        s += '    <origin xyz="%s" rpy="0 0 0"/>\n' % fmt(xyz)
        if axis is not None:
            s += '    <axis xyz="%s"/>\n' % fmt(unit(axis))
        if limits is not None:
            s += '    <limit lower="%.6g" upper="%.6g" effort="1000" velocity="20"/>\n' % tuple(limits)
        if mimic is not None:
            s += '    <mimic joint="%s" multiplier="%.6g" offset="0"/>\n' % mimic
        s += '  </joint>'
        lines.append(s)

    # pelvis: translations first (ground axes), then body-fixed tilt, list, rotation
    chain = [("pelvis_tx", "prismatic", os_x), ("pelvis_ty", "prismatic", os_y), ("pelvis_tz", "prismatic", os_z),
             ("pelvis_tilt", "revolute", os_z), ("pelvis_list", "revolute", os_x),
             ("pelvis_rotation", "revolute", os_y)]
    parent = "world"
    for i, (jn, jt, ax) in enumerate(chain):
        child = "pelvis" if i == len(chain) - 1 else jn + "_link"
        lim = (-5, 5) if jt == "prismatic" else rng(jn)
        comment = None
        if i == 0:
            comment = ("ground_pelvis (gait2392 CustomJoint): translations along the ground axes, then "
                       "body-fixed rotations Z(tilt) X(list) Y(rotation); massless links in between")
        joint(jn, jt, parent, child, axis=ax, limits=lim, comment=comment)
        if child != "pelvis":
            link(child)
        parent = child
    link("pelvis", meshes=("sacrum", "coccyx", "hip_r", "hip_l"),
         inertial=body_inertial(root, "pelvis", Rp, np.exp(xp[6:9]), np.zeros(3)))

    # hip: body-fixed flexion (Z), adduction (X), rotation (Y) of the registered pelvis frame
    hip = [("hip_flexion_r", Rp @ os_z), ("hip_adduction_r", Rp @ os_x), ("hip_rotation_r", Rp @ os_y)]
    parent = "pelvis"
    for i, (jn, ax) in enumerate(hip):
        child = "femur_r" if i == 2 else jn + "_link"
        joint(jn, "revolute", parent, child, xyz=H if i == 0 else (0, 0, 0), axis=ax, limits=rng(jn),
              comment="hip_r: centre = sphere fit of the VHF femoral-head cartilage" if i == 0 else None)
        if child != "femur_r":
            link(child)
        parent = child
    link("femur_r", meshes=("femur_r",), inertial=body_inertial(root, "femur_r", Rf, sf, np.zeros(3)))

    # knee: gait2392 translations (splines of knee angle) as prismatic joints along
    # the registered femur's OS x and y axes, then the knee flexion about its z axis.
    joint("knee_tx_r", "prismatic", "femur_r", "knee_tx_r_link", xyz=K - H, axis=Rf @ os_x, limits=(-0.05, 0.05),
          comment=("knee_r: centre = midpoint of the VHF condyle sphere centres. knee_tx_r / knee_ty_r = "
                   "gait2392 tibia translation splines minus their value at knee_angle_r = 0, scaled "
                   "with the femur (values come from the gait bag)"))
    link("knee_tx_r_link")
    joint("knee_ty_r", "prismatic", "knee_tx_r_link", "knee_ty_r_link", axis=Rf @ os_y, limits=(-0.05, 0.05))
    link("knee_ty_r_link")
    joint("knee_angle_r", "revolute", "knee_ty_r_link", "tibia_r", axis=Rf @ os_z, limits=rng("knee_angle_r"))
    link("tibia_r", meshes=("tibia_r", "fibula_r"),
         inertial=body_inertial(root, "tibia_r", Rf, sf, np.zeros(3)))
    # the patella slides with the knee as gait2392's quadriceps ends do (sites.patella_track): a
    # prismatic joint mimicking knee_angle_r, so every source of knee angles moves it (the bags carry
    # no value for it: robot_state_publisher and the node's skeleton derive it)
    lo, hi = sorted(patella["metres_per_rad"] * np.array(rng("knee_angle_r")))
    joint("patella_slide_r", "prismatic", "tibia_r", "patella_r", xyz=Pc - K, axis=patella["axis"],
          limits=(lo, hi), mimic=("knee_angle_r", patella["metres_per_rad"]),
          comment=("gait2392 has no patella body: its quadriceps end on tibia_r points that move back "
                   "with knee flexion. patella_slide_r = %.6g m/rad x knee_angle_r along their mean path "
                   "(a line fitted over the gait's knee angles %.2f..%.2f rad, carried into the tibia by "
                   "the knee chain; it lies within %.1f mm of their mean point there, %.1f mm over the "
                   "knee's whole range)" % (patella["metres_per_rad"], patella["knee_range_rad"][0],
                                            patella["knee_range_rad"][1], patella["fit_max_mm_over_knee_range"],
                                            patella["fit_max_mm_over_range_of_motion"])))
    link("patella_r", meshes=("patella_r",))
    lines.append('</robot>')
    os.makedirs(out_path("urdf"), exist_ok=True)
    with open(out_path("urdf", "right_hip_thigh.urdf"), "w") as f:
        f.write("\n".join(lines) + "\n")


# ---------------------------------------------------------------------------
# scene YAML
# ---------------------------------------------------------------------------

YAML_HEADER = """\
# Bundled scene: right hip and thigh muscles of the Visible Human Female on a
# gait2392-derived skeleton. Generated by tools/scene/build_scene.py (do not edit
# by hand; change the script and rerun it).
#
# Units and frames
#   All mesh coordinates are metres. Muscle surfaces are given in the scene frame
#   of the zero configuration: the `pelvis` link frame, which coincides with
#   `world` when every joint is 0 (REP 103: X forward, Y left, Z up).
#   Bones are NOT listed here: they are the <collision> meshes of the URDF links.
#
# Keys
#   Paths: relative ones start at this file's folder (here config/scenes/); absolute
#   paths, package:// and file:// URIs are also accepted.
#
#   urdf                    path of the skeleton URDF
#   frame                   frame the muscle surfaces are expressed in (link name)
#   reference_model         the musculoskeletal model the attachment sites come from
#     osim                  path of the OpenSim model (gait2392)
#     body_scales           per gait2392 body, scale factors (dimensionless) along the body's
#                           own OpenSim axes (x forward, y up, z right) that make gait2392 match
#                           this skeleton: pelvis and femur_r from the scene's bone registrations,
#                           tibia_r one factor fitted to the VHF tibia and fibula; the knee's
#                           translation functions scale with femur_r (as OpenSim's scale tool
#                           does, and as the URDF's knee_tx_r / knee_ty_r do)
#   muscles[]               one entry per muscle
#     name                  snake_case identifier, unique
#     surface               closed 2-manifold triangle surface, binary STL, metres
#     fibres                fibre polylines (VTK legacy polydata, metres, same frame);
#                           produced by generate_fibres (may not exist until it has
#                           been run)
#     origin_bone           URDF link of the origin (first gait2392 path point body)
#     insertion_bone        URDF link of the insertion (last gait2392 path point body)
#     color                 display colour RGBA, each component 0-1 (dimensionless)
#     tags                  group tags: thigh13 = the 13 thigh muscles of the seed
#                           paper, thigh = other thigh muscles, hip = hip muscles
#     rest_volume_ml        enclosed volume of the surface at rest, millilitres
#                           (1 ml = 1e-6 m^3), informative
#     source                raw file it was made from (see data/NOTICE)
#     attachment_note       where origin_bone / insertion_bone come from (text)
#     origin_path           tendon path at the origin, from the bone towards the belly: the
#                           origin site, then the via points the tendon passes; each entry
#                           {link: URDF link, point: [x, y, z] in that link's frame, m}
#     insertion_path        tendon path at the insertion, from the belly towards the bone: the
#                           via points, then the insertion site (entries as above)
#     belly_path            optional: the via points the belly covers, from origin to
#                           insertion (entries as above): the line the belly's fibres follow,
#                           along which the belly's tone measures the span between its tendons
#     reference_muscles     the gait2392 musculotendon(s) the sites come from, for length
#                           comparisons ([] when none: the obturators)
#     sites_source          how each point was obtained (text)
#                           These five are written by tools/scene/sites.py from gait2392's path
#                           points, mapped into the scene as the bones were (data/README.md,
#                           "Attachment sites").
#     particles_per_fibre   optional: particles sampled along each of this muscle's fibres
#                           (count, >= 2); left out: the node's particles_per_fibre
"""


def write_yaml(root):
    entries = []
    for name, stem, g, tags, col in MUSCLES:
        if g is not None:
            o, i = sl.muscle_bodies(root, g)
            o, i = BODY_TO_LINK[o], BODY_TO_LINK[i]
        else:
            # obturator internus/externus are not in gait2392: pelvis -> femur anatomically
            o, i = "pelvis", "femur_r"
        if name in QUADRICEPS:
            i = "patella_r"
        surf = "data/meshes/muscles/%s.stl" % name
        pd = sl.read_stl(out_path(surf))
        # Paths in a scene start at its own folder (config/scenes/), two levels below the package root.
        e = {"name": name, "surface": "../../" + surf, "fibres": "../../data/fibres/%s.vtk" % name,
             "origin_bone": o, "insertion_bone": i,
             "color": [float(c) for c in col], "tags": list(tags),
             "rest_volume_ml": round(sl.volume(pd) * 1e6, 1),
             "source": "VHF_%s_smooth.stl%s" % (stem, " (mirrored left to right)" if stem.startswith("Left") else "")}
        if g is None:
            e["attachment_note"] = "not in gait2392; anatomical origin (pelvis) and insertion (femur)"
        elif name in QUADRICEPS:
            e["attachment_note"] = "gait2392 %s ends on tibia_r via patella-like moving points; patella_r used" % g
        else:
            e["attachment_note"] = "from gait2392 %s path points" % g
        entries.append(e)
    doc = {"urdf": "../../urdf/right_hip_thigh.urdf", "frame": "pelvis", "muscles": entries}
    # attachment sites from gait2392's path points (sites.py); they read the fibres, which generate_fibres
    # makes from this build's output: rerun sites.py after it (tools/scene/README.md)
    import sites
    with open(out_path("tools", "scene", "build_params.json")) as f:
        params = json.load(f)
    sites.write_report(sites.add_sites(doc, params, root, MUSCLES))
    os.makedirs(out_path("config", "scenes"), exist_ok=True)
    with open(out_path("config", "scenes", "right_hip_thigh.yaml"), "w") as f:
        sites.dump_scene(YAML_HEADER, doc, f)


if __name__ == "__main__":
    if sys.argv[1:] == ["--urdf-only"]:
        rewrite_urdf()
    elif sys.argv[1:]:
        sys.exit("usage: build_scene.py [--urdf-only]")
    else:
        main()
