"""Stand-in bones carved by the measured muscles (level-set CSG, OpenVDB).

The VHF muscles are the measured data; the generic OpenSim femur and hip bone
(and, where two VHF segmentations disagree after decimation, a VHF bone) are
stand-ins that give way to them. Every bone that a muscle overlaps at rest is
replaced by

    bone' = bone minus (union of the muscle volumes grown by CLEARANCE_M)

as level sets on one voxel lattice (OpenVDB mesh-to-level-set, the CSG
difference max(bone, c - muscles) on the voxels, level-set-to-mesh), remeshed
to about its former triangle count (VTK quadric decimation in stages) with
disconnected pieces smaller than MIN_PIECE_FRACTION of the bone dropped.
Bones stay in their link frames: nothing moves, so the joint centres (from
the VHF cartilages) are unchanged; measure_joint_regions says how much the
femoral head and the acetabulum surfaces changed.

A bone is carved only if it overlaps a muscle (some lattice voxel inside both
surfaces); every other bone is returned as it came (same object, same bytes).

OpenVDB runs its loops on TBB, which sizes its thread pool from the process's
CPU affinity: build_scene.py pins the build to one CPU before anything starts
a pool, so the carve runs single-threaded. The output was checked to be
byte-identical between runs.
"""

import numpy as np
import pyopenvdb as vdb
import vtk
from vtk.util.numpy_support import vtk_to_numpy

import overlaps
import scenelib as sl

# Chosen by measurement (data/README.md, "Bones carved by the muscles"): the
# voxel resolves the generic iliac wing (2-4 mm thick) with the level-set
# surface within a few hundredths of a millimetre of the exact CSG; the
# clearance absorbs what remeshing and decimation move the surface back
# towards the muscles and the 1 mm-voxel distance fields the core reads the
# bones through.
VOXEL_M = 0.5e-3
CLEARANCE_M = 0.5e-3
BONE_HALF_WIDTH_VOXELS = 3.0
MIN_PIECE_FRACTION = 0.01     # pieces below 1 % of the bone's volume are dropped (reported)
DECIMATION_FACTORS = (4, 3, 2)  # largest reduction per quadric stage, tried in this order


def _level_set(pd, voxel, half_width):
    xform = vdb.createLinearTransform(voxelSize=voxel)
    return vdb.FloatGrid.createLevelSetFromPolygons(
        np.ascontiguousarray(sl.pd_points(pd)), triangles=np.ascontiguousarray(sl.pd_triangles(pd), dtype=np.uint32),
        transform=xform, halfWidth=half_width)


def _box(pd, voxel, pad):
    lo, hi = np.array(pd.GetBounds()).reshape(3, 2).T
    i0 = np.floor(lo / voxel).astype(int) - pad
    i1 = np.ceil(hi / voxel).astype(int) + pad
    return i0, tuple(int(n) for n in i1 - i0 + 1)


def carve_volume(bone_pd, muscles, clearance=CLEARANCE_M, voxel=VOXEL_M):
    """Level-set CSG of one bone against the muscles {name: pd} (same frame).

    Returns (carved grid or None when no muscle overlaps the bone, names of the
    overlapping muscles, stats)."""
    hw_bone = BONE_HALF_WIDTH_VOXELS
    hw_muscle = clearance / voxel + hw_bone  # so that c - (muscle background) = -(bone background)
    bone = _level_set(bone_pd, voxel, hw_bone)
    bg = bone.background
    i0, shape = _box(bone_pd, voxel, int(np.ceil(hw_bone)) + 2)
    ijk = tuple(int(v) for v in i0)
    B = np.empty(shape, np.float32)
    bone.copyToArray(B, ijk=ijk)
    lo, hi = np.array(bone_pd.GetBounds()).reshape(3, 2).T
    M = np.full(shape, np.float32(hw_muscle * voxel), np.float32)
    tmp = np.empty(shape, np.float32)
    overlapping, reaching = [], []
    for name in sorted(muscles):
        mlo, mhi = np.array(muscles[name].GetBounds()).reshape(3, 2).T
        if np.any(mlo - clearance > hi) or np.any(mhi + clearance < lo):
            continue
        _level_set(muscles[name], voxel, hw_muscle).copyToArray(tmp, ijk=ijk)
        if np.any((tmp < 0) & (B < 0)):
            overlapping.append(name)
        if np.any((tmp < clearance) & (B < 0)):
            reaching.append(name)
        np.minimum(M, tmp, out=M)
    if not overlapping:
        return None, [], {}
    R = np.maximum(B, np.float32(clearance) - M)
    np.clip(R, -bg, bg, out=R)
    removed = (B < 0) & (R >= 0)
    idx = np.argwhere(removed)
    stats = {"muscles_overlapping": overlapping, "muscles_within_clearance": reaching,
             "voxels_removed": int(len(idx)), "removed_ml": float(len(idx) * voxel ** 3 * 1e6),
             "removed_voxel_centres": (idx + i0) * voxel}
    out = vdb.FloatGrid(background=bg)
    out.transform = vdb.createLinearTransform(voxelSize=voxel)
    out.gridClass = vdb.GridClass.LEVEL_SET
    out.copyFromArray(R, ijk=ijk, tolerance=0.0)
    out.prune()
    return out, overlapping, stats


def grid_to_mesh(grid):
    """Closed triangle mesh of the grid's zero level set, wound outward."""
    pts, tris, quads = grid.convertToPolygons(isovalue=0.0, adaptivity=0.0)
    T = np.concatenate([np.asarray(tris, np.int64).reshape(-1, 3),
                        np.asarray(quads, np.int64)[:, [0, 1, 2]], np.asarray(quads, np.int64)[:, [0, 2, 3]]])
    pd = sl.clean(sl.make_pd(np.asarray(pts, np.float64), T))
    return sl.flip_winding(pd) if sl.signed_volume(pd) < 0 else pd


def split_pieces(pd):
    """Connected pieces of a closed mesh, largest first: [(volume m^3, pd)]."""
    cf = vtk.vtkPolyDataConnectivityFilter()
    cf.SetInputData(pd)
    cf.SetExtractionModeToAllRegions()
    cf.ColorRegionsOn()
    cf.Update()
    out = cf.GetOutput()
    region = vtk_to_numpy(out.GetPointData().GetArray("RegionId"))
    P, T = sl.pd_points(out), sl.pd_triangles(out)
    pieces = []
    for r in range(cf.GetNumberOfExtractedRegions()):
        sub = sl.clean(sl.make_pd(P, T[region[T[:, 0]] == r]))
        pieces.append((abs(sl.signed_volume(sub)), sub))
    pieces.sort(key=lambda vp: -vp[0])
    return pieces


def mesh_ok(pd):
    """Closed, 2-manifold, consistently and outward wound, not intersecting itself."""
    boundary, nonmanifold = sl.open_edges(pd)
    return (boundary == 0 and nonmanifold == 0 and sl.nonmanifold_vertices(pd) == 0 and sl.consistently_oriented(pd)
            and sl.signed_volume(pd) > 0 and sl.self_intersections(pd) == 0)


def decimate_checked(pd, target):
    """Quadric decimation to about `target` triangles in stages of at most `factor`.

    vtkQuadricDecimation has no topology check: one large step can collapse an
    edge across a thin part and leave a non-manifold edge. Smaller stages are
    tried in turn until the result passes mesh_ok; none passing is an error."""
    for factor in DECIMATION_FACTORS:
        out = pd
        while out.GetNumberOfCells() > target:
            out = sl.decimate(out, max(target, out.GetNumberOfCells() // factor))
        if mesh_ok(out):
            return out, factor
    raise RuntimeError("carve: no decimation schedule %s keeps the mesh closed, manifold and free of "
                       "self-intersections" % (DECIMATION_FACTORS,))


def carve_depth(bone_pd, muscles):
    """Deepest vertex of the old bone surface inside a muscle (m), and that muscle."""
    P = sl.pd_points(bone_pd)
    worst = (0.0, "-")
    for name in sorted(muscles):
        d = overlaps.depths_in(muscles[name], P).max()
        if d > worst[0]:
            worst = (float(d), name)
    return worst


def carve_bone(bone_pd, muscles, clearance=CLEARANCE_M, voxel=VOXEL_M):
    """(carved bone or the same pd when no muscle overlaps it, stats)."""
    grid, overlapping, stats = carve_volume(bone_pd, muscles, clearance, voxel)
    if grid is None:
        return bone_pd, None
    pieces = split_pieces(grid_to_mesh(grid))
    total = sum(v for v, _ in pieces)
    kept = [p for v, p in pieces if v >= MIN_PIECE_FRACTION * total]
    dropped = [v for v, _ in pieces if v < MIN_PIECE_FRACTION * total]
    app = vtk.vtkAppendPolyData()
    for p in kept:
        app.AddInputData(p)
    app.Update()
    remeshed = sl.clean(app.GetOutput())
    carved, factor = decimate_checked(remeshed, bone_pd.GetNumberOfCells())
    depth, deepest = carve_depth(bone_pd, {n: muscles[n] for n in overlapping})
    stats.update({
        "clearance_mm": clearance * 1e3, "voxel_mm": voxel * 1e3,
        "volume_before_ml": sl.volume(bone_pd) * 1e6, "volume_after_ml": sl.volume(carved) * 1e6,
        "carve_depth_mm": depth * 1e3, "carve_depth_muscle": deepest,
        "triangles_before": bone_pd.GetNumberOfCells(), "triangles_remeshed": remeshed.GetNumberOfCells(),
        "triangles_after": carved.GetNumberOfCells(), "decimation_stage_factor": factor,
        "pieces_kept": len(kept), "pieces_dropped_ml": [v * 1e6 for v in dropped],
        "self_intersections_before": sl.self_intersections(bone_pd),
        "self_intersections_after": sl.self_intersections(carved), "closed_manifold_after": mesh_ok(carved)})
    return carved, stats


def surface_change(old_pd, new_pd, centre, radius):
    """Largest distance (m) between the two surfaces over their vertices within `radius` of `centre`."""
    worst = 0.0
    for a, b in ((old_pd, new_pd), (new_pd, old_pd)):
        P = sl.pd_points(a)
        near = P[np.linalg.norm(P - centre, axis=1) < radius]
        if len(near):
            worst = max(worst, float(overlaps.unsigned_distance(b, near).max()))
    return worst


def measure_joint_regions(old_pd, new_pd, stats, centre, radius):
    """How far the carve came to a joint centre, and how much the surface within `radius` of it changed."""
    removed = stats.pop("removed_voxel_centres")
    stats["closest_removed_voxel_to_joint_centre_mm"] = (
        float(np.linalg.norm(removed - centre, axis=1).min() * 1e3) if len(removed) else None)
    stats["joint_region_radius_mm"] = radius * 1e3
    stats["joint_region_surface_change_mm"] = surface_change(old_pd, new_pd, centre, radius) * 1e3
    # inside the closest carved voxel's distance only remeshing and decimation changed the surface
    stats["uncarved_joint_region_surface_change_mm"] = (
        surface_change(old_pd, new_pd, centre, min(radius, stats["closest_removed_voxel_to_joint_centre_mm"] * 1e-3))
        * 1e3 if len(removed) else stats["joint_region_surface_change_mm"])
    fits = []
    for pd in (old_pd, new_pd):
        P = sl.pd_points(pd)
        near = P[np.linalg.norm(P - centre, axis=1) < radius]
        c, r = sl.sphere_fit(near)
        fits.append((np.asarray(c), float(r)))
    stats["joint_region_sphere_centre_shift_mm"] = float(np.linalg.norm(fits[1][0] - fits[0][0]) * 1e3)
    stats["joint_region_sphere_radius_mm"] = [fits[0][1] * 1e3, fits[1][1] * 1e3]


def carve_bones(bones, muscles, joint_centres, joint_radius):
    """Carve every bone of {name: pd} (scene frame) that a muscle of {name: pd} overlaps.

    joint_centres {bone: centre (scene frame)} selects the region each bone's
    joint check looks at. Returns ({name: pd}, {name: stats} of the carved bones)."""
    out, report = {}, {}
    for name in sorted(bones):
        carved, stats = carve_bone(bones[name], muscles)
        out[name] = carved
        if stats is None:
            continue
        centre = joint_centres.get(name)
        if centre is not None:
            measure_joint_regions(bones[name], carved, stats, np.asarray(centre), joint_radius)
        else:
            stats.pop("removed_voxel_centres")
        report[name] = stats
        print("carve %-9s by %s: volume %.1f -> %.1f ml, deepest old surface %.1f mm inside %s, %d -> %d "
              "triangles, dropped %d pieces" % (
                  name, ", ".join(stats["muscles_overlapping"]), stats["volume_before_ml"], stats["volume_after_ml"],
                  stats["carve_depth_mm"], stats["carve_depth_muscle"], stats["triangles_before"],
                  stats["triangles_after"], len(stats["pieces_dropped_ml"])), flush=True)
    return out, report
