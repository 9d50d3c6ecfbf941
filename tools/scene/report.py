#!/usr/bin/env python3
"""Quality report of the built scene; writes data/README.md.

Checks, for every muscle surface: closed and 2-manifold (vtkFeatureEdges plus a
vertex-link test), outward winding, triangle/vertex counts, rest volume; for
every muscle at rest: the fraction of its vertices inside any bone mesh (exact
inside test: vtkSelectEnclosedPoints against each closed bone surface) and the
maximum depth (distance to that bone's surface), and the same depth for its
fibre points (overlaps.py); for every bone mesh: closure, volume and
self-intersections. Also the registration numbers and the rest-overlap
resolution stored by build_scene.py.

Run after build_scene.py:  PYENV_VERSION=system /usr/bin/python3 tools/scene/report.py
"""

import json
import os
import sys

import numpy as np
import yaml

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import overlaps  # noqa: E402
import scenelib as sl  # noqa: E402

PKG = sl.PKG


def muscle_penetration(muscle_pd, bones):
    P = sl.pd_points(muscle_pd)
    inside_any = np.zeros(len(P), bool)
    worst = (0.0, "-")
    per_bone = {}
    for b, (_, bpd) in bones.items():
        lo, hi = np.array(bpd.GetBounds()).reshape(3, 2).T
        near = np.all((P > lo - 1e-3) & (P < hi + 1e-3), axis=1)
        if not near.any():
            continue
        flags = np.zeros(len(P), bool)
        flags[near] = overlaps.inside_flags(bpd, P[near])
        if flags.any():
            d = overlaps.unsigned_distance(bpd, P[flags]).max()
            per_bone[b] = (int(flags.sum()), d)
            if d > worst[0]:
                worst = (d, b)
        inside_any |= flags
    return inside_any.mean(), worst, per_bone


def main():
    scene = yaml.safe_load(open(os.path.join(PKG, "config", "scenes", "right_hip_thigh.yaml")))
    params = json.load(open(os.path.join(PKG, "tools", "scene", "build_params.json")))
    bones = overlaps.bone_meshes_scene()
    rows = []
    results = {}
    for m in scene["muscles"]:
        pd = sl.read_stl(os.path.join(PKG, "config", "scenes", m["surface"]))
        b, nm = sl.open_edges(pd)
        bow = sl.nonmanifold_vertices(pd)
        closed = b == 0 and nm == 0 and bow == 0
        outward = sl.signed_volume(pd) > 0 and sl.consistently_oriented(pd)
        frac, worst, per_bone = muscle_penetration(pd, bones)
        fpath = os.path.join(PKG, "config", "scenes", m["fibres"])
        fibre_depth = (0.0, "-")
        if os.path.exists(fpath):
            F = np.concatenate([overlaps.densify(f) for f in overlaps.read_polylines(fpath)])
            for b, (_, bpd) in bones.items():
                d = overlaps.depths_in(bpd, F).max()
                if d > fibre_depth[0]:
                    fibre_depth = (d, b)
        results[m["name"]] = {"triangles": pd.GetNumberOfCells(), "vertices": pd.GetNumberOfPoints(),
                              "closed_manifold": bool(closed), "outward": bool(outward),
                              "components": sl.n_components(pd),
                              "volume_ml": sl.volume(pd) * 1e6, "inside_fraction": frac,
                              "max_depth_mm": worst[0] * 1e3, "worst_bone": worst[1],
                              "fibre_max_depth_mm": fibre_depth[0] * 1e3, "fibre_worst_bone": fibre_depth[1],
                              "per_bone": {k: [v[0], v[1] * 1e3] for k, v in per_bone.items()}}
        r = results[m["name"]]
        rows.append("| %s | %s | %d | %d | %s | %.1f | %.2f %% | %.2f | %s | %.2f | %s |" % (
            m["name"], ", ".join(m["tags"]), r["triangles"], r["vertices"],
            "yes" if closed and outward else "NO", r["volume_ml"], 100 * frac, r["max_depth_mm"],
            r["worst_bone"], r["fibre_max_depth_mm"], r["fibre_worst_bone"]))
        print(rows[-1], flush=True)
    bone_rows = []
    for b, (link, pd) in sorted(bones.items()):
        bb, nm = sl.open_edges(pd)
        ok = bb == 0 and nm == 0 and sl.nonmanifold_vertices(pd) == 0 and sl.signed_volume(pd) > 0
        bone_rows.append("| %s | %s | %d | %s | %.1f | %d |" % (b, link, pd.GetNumberOfCells(),
                                                               "yes" if ok else "NO", sl.volume(pd) * 1e6,
                                                               sl.self_intersections(pd)))
    head = np.array(params["registered_femoral_head_centre"])
    hip = np.array(params["hip_centre"])
    pel_hip = np.array(params["registered_pelvis_hip_centre"])
    reg = {"femoral_head_to_cartilage_sphere_mm": float(np.linalg.norm(head - hip) * 1e3),
           "pelvis_hip_centre_to_cartilage_sphere_mm": float(np.linalg.norm(pel_hip - hip) * 1e3)}
    with open(os.path.join(PKG, "tools", "scene", "report.json"), "w") as f:
        json.dump({"muscles": results, "registration": reg}, f, indent=1, sort_keys=True)
    write_readme(rows, bone_rows, reg, params, results)


def write_readme(rows, bone_rows, reg, params, results):
    import readme_text
    text = readme_text.render(rows, bone_rows, reg, params, results)
    with open(os.path.join(PKG, "data", "README.md"), "w", encoding="utf-8") as f:
        f.write(text)


if __name__ == "__main__":
    main()
