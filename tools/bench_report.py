#!/usr/bin/env python3
"""Writes docs/BENCHMARKS.md from the JSON files the benchmark programs leave in out/bench/.

Usage: bench_report.py OUT_BENCH_DIR BENCHMARKS_MD [--sections=realtime,stability,...]
Sections appear for the JSON files that exist; numbers are copied, never computed from assumptions. With --sections
only the named sections are made, each in place of the section of the same heading in BENCHMARKS_MD (appended if it has
none), and the header says which were regenerated apart from the rest."""
import datetime
import json
import os
import pathlib
import platform
import subprocess
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import accuracy_report  # noqa: E402
import realtime_report  # noqa: E402
import speed_error_report  # noqa: E402


def machine_description():
    cpu = "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=pathlib.Path(__file__).resolve().parent.parent).stdout.strip()
    except OSError:
        commit = "unknown"
    return (f"{cpu}, {os.cpu_count()} cores (shared machine), {platform.system()} {platform.release()}; "
            f"Release build (-O3), threads as each section says; commit {commit or 'unknown'}; "
            f"{datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}")


def load(directory, name):
    path = directory / name
    if not path.exists():
        return None
    with open(path) as handle:
        return json.load(handle)


def mss_section(rows):
    lines = ["## MSS update per iteration (core issue)", "",
             "Synthetic thigh (`makeSyntheticThigh`): 13 spindle muscles x 64 fibres, 18 nearest-neighbour springs, "
             "stiffness-scaled masses, a bent pose (hip 0.5 rad, knee 0.8 rad) so springs are loaded. Median of "
             f"{int(rows[0]['repetitions'])} runs of {int(rows[0]['iterations_per_repetition'])} iterations each. "
             "The paper's figure is its Table 1 MSS line (s per 500 iterations / 500; Core2Duo E6300, 2006).", "",
             "Wall time is what a user waits; thread CPU time leaves out the time the thread waited for a core on this "
             "shared machine.", "",
             "| particles/fibre | particles | springs | bytes/particle | ms/iteration (fixed dt) | CPU ms/iteration "
             "| ms/iteration (adaptive dt) | paper ms/iteration | speed-up (wall) | bandwidth floor ms |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(
            f"| {int(row['particles_per_fibre'])} | {int(row['particles'])} | {int(row['springs'])} | "
            f"{int(row['bytes_per_particle'])} | {row['mss_ms_per_iteration']:.3f} | {row['mss_cpu_ms_per_iteration']:.3f} | "
            f"{row['mss_adaptive_dt_ms_per_iteration']:.3f} | {row['paper_mss_ms_per_iteration']:.1f} | "
            f"{row['paper_mss_ms_per_iteration'] / row['mss_ms_per_iteration']:.0f}x | {row['bandwidth_floor_ms']:.2f} |")
    last = rows[-1]
    target_ms = last["paper_mss_ms_per_iteration"] / 50.0
    verdict = "meets" if last["mss_ms_per_iteration"] <= target_ms else "misses"
    cpu_verdict = "meets" if last["mss_cpu_ms_per_iteration"] <= target_ms else "misses"
    lines += ["",
              f"Target: at 80 particles per fibre at least 50x the paper (<= {target_ms:.2f} ms). In wall time this run "
              f"{verdict} it: {last['mss_ms_per_iteration']:.3f} ms, "
              f"{last['paper_mss_ms_per_iteration'] / last['mss_ms_per_iteration']:.0f}x; in thread CPU time it "
              f"{cpu_verdict} it: {last['mss_cpu_ms_per_iteration']:.3f} ms, "
              f"{last['paper_mss_ms_per_iteration'] / last['mss_cpu_ms_per_iteration']:.0f}x.",
              "",
              f"What bounds it: one iteration moves at least {last['bytes_moved_per_iteration'] / 1e6:.1f} MB "
              f"(springs 16 B each, plus per-particle state and forces); at the measured one-thread triad bandwidth "
              f"of {last['triad_bandwidth_gbs']:.1f} GB/s that takes {last['bandwidth_floor_ms']:.2f} ms, so "
              + ("memory traffic is not the limit here: the rest is per-spring work, "
                 f"{last['mss_cpu_ms_per_iteration'] * 1e6 / last['springs']:.1f} ns a spring (a double-precision square "
                 "root and division, and force updates scattered to the second particle). A variant that computed the "
                 "square roots and divisions in vector form over chunks of springs was not faster in an A/B run on "
                 "this machine, and -fno-math-errno made no measurable difference."
                 if last["mss_cpu_ms_per_iteration"] > 2 * last["bandwidth_floor_ms"] else
                 "memory traffic is what bounds it.")
              + " Bytes per particle counts the model arrays, the solver's copy of the springs and the state.", ""]
    return lines


def iteration_section(rows):
    lines = ["## Full iteration with collision (collision issue)", "",
             "Same synthetic scene, boundary particles only in collision, bone sphere sets of 8527, 1568 and 1709 "
             "spheres (the paper's pelvis, femur and tibia counts). Milliseconds per iteration (wall, median); the "
             "paper's figures are its Table 1 (s per 500 iterations / 500).", "",
             "| particles/fibre | broad phase | boundary particles | muscle CD | paper | bone CD | paper | MSS | "
             "total | paper total | speed-up |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(
            f"| {int(row['particles_per_fibre'])} | {row['broad_phase']} | {int(row['boundary_particles'])} | "
            f"{row['muscle_cd_ms']:.3f} | {row['paper_muscle_cd_ms']:.1f} | {row['bone_cd_ms']:.3f} | "
            f"{row['paper_bone_cd_ms']:.1f} | {row['mss_ms']:.3f} | {row['total_ms_per_iteration']:.3f} | "
            f"{row['paper_total_ms_per_iteration']:.1f} | "
            f"{row['paper_total_ms_per_iteration'] / row['total_ms_per_iteration']:.0f}x |")
    lines += [""]
    for phase in sorted({row["broad_phase"] for row in rows}):
        fit = next(row for row in rows if row["broad_phase"] == phase)
        lines.append(f"- {phase}: collision time = {fit['fit_collision_ms_intercept']:.3f} ms + "
                     f"{fit['fit_collision_ms_per_1000_boundary']:.3f} ms per 1000 boundary particles "
                     f"(R^2 {fit['fit_collision_r2']:.2f}); log-log exponent {fit['fit_collision_loglog_exponent']:.2f} "
                     "(1 = linear).")
    at_80 = [row for row in rows if int(row["particles_per_fibre"]) == 80]
    best = min(at_80, key=lambda row: row["total_ms_per_iteration"]) if at_80 else None
    if best:
        lines += ["", f"Target: the full iteration at 80 particles per fibre <= 7 ms (50x the paper's 354.7 ms). "
                      f"This run: {best['total_ms_per_iteration']:.2f} ms with the {best['broad_phase']} "
                      f"({'met' if best['total_ms_per_iteration'] <= 7.0 else 'missed'})."]
    return lines + [""]


def skinning_section(rows):
    timing = [row for row in rows if row.get("measurement") == "timing"]
    scene = [row for row in rows if row.get("measurement") == "scene"]
    lines = ["## Surface skinning (surface issue)", "",
             "Update time of one muscle's surface from its 1280 particles (20 per fibre), median, and the one-off "
             "precompute. Details and the choice of default: `docs/surface_skinning.md`.", "",
             "| method | surface vertices | update ms | precompute ms | weights stored |", "|---|---|---|---|---|"]
    for row in timing:
        lines.append(f"| {row['method']} | {int(row['surface_vertices'])} | {row['update_ms']:.3f} | "
                     f"{row['precompute_ms']:.1f} | {int(row['weights_nonzero'])} |")
    if scene:
        lines += ["", "Each scene after a bending pose, solved cold with sphere collision; surfaces measured with the "
                      "exact inside test on the bone meshes (the bundled scene's rest pose already has vertices inside "
                      "the substituted bones, see data/README.md):", "",
                  "| scene | pose | solver iterations | method | volume error mean % | volume error max % | "
                  "vertices inside bone | max depth mm |",
                  "|---|---|---|---|---|---|---|---|"]
        for row in scene:
            lines.append(f"| {row.get('scene', 'synthetic thigh')} | {row['pose']} | {int(row['solver_iterations'])} | "
                         f"{row['method']} | {row['volume_error_mean_pct']:.2f} | {row['volume_error_max_pct']:.2f} | "
                         f"{int(row['vertices_inside_bone'])} | {row['max_inside_bone_depth_mm']:.2f} |")
    return lines + [""]


def gait_section(csv_path):
    import csv
    import statistics
    with open(csv_path) as handle:
        rows = list(csv.DictReader(handle))
    if not rows:
        return []
    # The node also publishes refinements of an unfinished frame between poses (`refined`); the times are of the frames
    # that solved a new pose, as the demo's summary gives them, and the fidelity figures of every frame shown.
    shown = rows
    rows = [row for row in shown if row.get("refined", "False") != "True"] or shown
    refinements = len(shown) - len(rows)
    solve = [float(row["solve_ms"]) for row in rows]
    iterations = sorted({int(float(row["iterations"])) for row in rows})
    volume_mean = [float(row["volume_error_mean_pct"]) for row in shown if row.get("has_surface_metrics") == "True"]
    volume_max = [float(row["volume_error_max_pct"]) for row in shown if row.get("has_surface_metrics") == "True"]
    # Rows of a node without collision figures (has_collision_metrics False) hold NaN there; older files lack the flag.
    penetration = [float(row["max_penetration_sphere_bone_m"]) * 1e3 for row in shown
                   if row.get("has_collision_metrics", "True") == "True"]
    surface_depth = [float(row["max_surface_inside_bone_m"]) * 1e3 for row in shown if row.get("has_surface_metrics") == "True"]
    particle_depth = [float(row["max_particle_inside_bone_m"]) * 1e3 for row in shown
                      if row.get("has_surface_metrics") == "True" and "max_particle_inside_bone_m" in row]
    total = [float(row["total_ms"]) for row in rows]
    metrics_ms = [float(row["metrics_ms"]) for row in rows if row.get("has_surface_metrics") == "True"]
    median = statistics.median(solve)
    stamp = datetime.datetime.fromtimestamp(os.path.getmtime(csv_path), datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = ["## The node on the bundled gait (node issue)", "",
             f"From the last `make demo` ({stamp}; `out/demo/stats.csv`): the 1-cycle gait bag through "
             "`muscle_deformation_node`, all 26 muscles, 20 particles per fibre, warm start, "
             f"the node's defaults ({statistics.median(float(row['iterations']) for row in rows):.0f} iterations per "
             f"frame median, {max(iterations)} at most: the cold first frame), rviz rendering in software at a few "
             "frames per second on the same 2 cores."
             + (f" Between poses the node also published {refinements} refinements of unfinished frames: the times "
                "below are of the frames that solved a pose, the volume and depths of every frame shown."
                if refinements else ""), "",
             "| frames solved | median / max solve ms | real-time factor at 60 Hz (solve) | median frame ms with surfaces "
             "and metrics | median metrics ms | volume error mean % (median over frames) | worst volume error % | max "
             "sphere penetration into bone mm | max surface depth inside bone mm | max particle depth inside bone mm |",
             "|---|---|---|---|---|---|---|---|---|---|",
             f"| {len(rows)} | {median:.1f} / {max(solve):.0f} | {(1000.0 / 60.0) / median:.2f} | "
             f"{statistics.median(total):.1f} | {statistics.median(metrics_ms) if metrics_ms else float('nan'):.1f} | "
             f"{statistics.median(volume_mean) if volume_mean else float('nan'):.2f} | "
             f"{max(volume_max) if volume_max else float('nan'):.2f} | "
             f"{max(penetration) if penetration else float('nan'):.2f} | "
             f"{max(surface_depth) if surface_depth else float('nan'):.2f} | "
             f"{max(particle_depth) if particle_depth else float('nan'):.2f} |", "",
             "The demo's solve times are measured beside rviz rendering in software and the bag player on the same two "
             "cores, so they run above the real-time section's; the per-muscle figures over this run are in "
             "`out/demo/muscles.md` and `out/demo/volume_error.png`.",
             ""]
    return lines


def local_global_section(rows):
    reference = next((row for row in rows if row.get("solver") == "reference"), None)
    groups = {}
    for row in rows:
        if row.get("solver") == "reference" or "wall_ms" not in row:
            continue  # the reference's description, and per-configuration summaries (time to 1 mm: -1 = never)
        key = (row["solver"], row.get("mode", ""), row.get("collisions", ""), row.get("time_step_s", 0),
               row.get("volume_weight", 0), row.get("chebyshev_rho", 0))
        groups.setdefault(key, []).append(row)
    lines = ["## Implicit local/global solver against Verlet (beyond-the-seeds issue)", "",
             "Synthetic thigh, 20 particles per fibre, pose hip 0.6 / knee 0.9 rad, cold start. RMS particle distance "
             "to a reference shape of the same model (`bench/local_global_bench.cpp`)."]
    if reference:
        lines += ["", f"Reference: {reference['reference_solver']} for {int(reference['reference_iterations'])} "
                      f"iterations (last mean displacement {reference['reference_last_mean_displacement_m']:.1e} m per "
                      f"iteration, so not below the 1e-7 m rule); Verlet started from it moves "
                      f"{reference['verlet_from_reference_rms_mm']:.2f} mm RMS, and Verlet run cold for "
                      f"{int(reference['verlet_cold_iterations'])} iterations ends "
                      f"{reference['verlet_cold_to_reference_rms_mm']:.2f} mm from it: the reference is uncertain by "
                      "about a millimetre, because the spring energy is nearly flat along some shape changes."]
    lines += ["", "| solver | mode | collisions | h s | volume weight | Chebyshev rho | RMS mm within 570 ms (iterations) "
                  "| last point: iterations, ms, RMS mm | volume error mean / max % at the last point |",
              "|---|---|---|---|---|---|---|---|---|"]
    for key, points in groups.items():
        points.sort(key=lambda row: row["wall_ms"])
        within = [row for row in points if row["wall_ms"] <= 570.0]
        best = min(within, key=lambda row: row["rms_mm"]) if within else None
        last = points[-1]
        lines.append(f"| {key[0]} | {key[1]} | {key[2]} | {key[3]:g} | {key[4]:g} | {key[5]:g} | "
                     + (f"{best['rms_mm']:.2f} ({int(best['iterations'])})" if best else "-")
                     + f" | {int(last['iterations'])}, {last['wall_ms']:.0f}, {last['rms_mm']:.2f} | "
                     f"{last['volume_error_pct']:.2f} / {last.get('volume_error_max_pct', float('nan')):.2f} |")
    lines += ["", "Target (beyond-the-seeds issue): a cold solve within 1 mm RMS of the converged shape in <= 0.57 s. "
                  "Not met by either solver on this scene; see the reference note above for why.", ""]
    return lines


def bone_proxy_section(rows):
    def row_of(proxy, case):
        return next((r for r in rows if r["proxy"] == proxy and r["case"] == case), None)

    first = rows[0]
    lines = ["## Bone proxies: the seeds' spheres against the bone itself (fidelity issue)", "",
             f"All {int(first['muscles'])} muscles ({int(first['particles'])} particles), node defaults "
             f"({first['solver']}, threads {int(first['threads'])}: 0 = every core, -1 = one or every core as measured), the gait streamed warm from rest "
             "and one hard pose (hip flexion 110 deg, knee 130 deg) solved cold. Both proxies are judged by yardsticks "
             "neither defines: depths inside the real bone (its mesh through its distance field), and the skinned "
             "surfaces' volume error and vertices inside bone. \"Deeper than at rest\" is a free particle's depth in "
             "a bone beyond what it had at rest (the bundled hip bone overlaps four muscles at rest). Frame times are "
             "medians (wall). Raw numbers: `out/bench/bone_proxy.json`.", "",
             "| proxy | case | setup ms (fields) | muscle spheres (dropped at rest) | solve ms median / max | bone contacts ms "
             "| particles deeper than at rest, mm | proxy's own penetration, mm | volume error mean / worst % "
             "| surface vertices inside bone (median), deepest mm | metrics ms |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for proxy in ("one_ring_spheres", "distance_field"):
        for case in ("gait", "hip_flexion_110_knee_130_cold"):
            r = row_of(proxy, case)
            if not r:
                continue
            fields = f" ({r['field_build_ms']:.0f})" if r["field_build_ms"] > 0 else ""
            lines.append(f"| {proxy} | {case} | {r['setup_ms']:.0f}{fields} | {int(r['collision_spheres'])} "
                         f"({int(r['rest_spheres_removed'])}) | {r['solve_ms']:.1f} / {r['solve_max_ms']:.1f} | "
                         f"{r['bone_cd_ms']:.2f} | {r['deeper_than_rest_mm']:.2f} | {r['proxy_penetration_mm']:.2f} | "
                         f"{r['volume_error_mean_pct']:.2f} / {r['volume_error_max_pct']:.1f} | "
                         f"{r['inside_bone_vertices_median']:.0f}, {r['inside_bone_depth_mm']:.2f} | "
                         f"{r['metrics_ms']:.1f} |")
    lines += [""]
    return lines


def _worst_pose(row):
    """Where the skinned surface's worst volume error was: its muscle and the pose's index in the case."""
    if "skinned_volume_error_max_muscle" not in row:
        return ""
    return f" ({row['skinned_volume_error_max_muscle']}, {int(row['skinned_volume_error_max_pose'])})"


def fidelity_section(rows):
    variants = [r for r in rows if "muscle" not in r and r.get("case") != "precompute"]
    unavailable = [r for r in rows if r.get("case") == "precompute"]
    per_muscle = [r for r in rows if "muscle" in r]
    lines = ["## Fidelity of the surfaces: volume and bone (fidelity issue)", "",
             "All 26 bundled muscles; the particles solved once per frame at the node's defaults (one block-descent "
             "sweep a frame, the sweep its time budget gives on this machine, run as a count so the figures repeat) "
             "and every surface variant skinned from the same particles. *gait*: the 1-cycle gait streamed warm; "
             "*hip_flexion*: the 2019 PBD thesis scenario on our data, hip_flexion_r 0 -> 1.5 rad -> 0 in warm frames. "
             "Volume errors are |V - V_rest| / V_rest of the surface the user sees, mean over muscles and frames and "
             "the worst muscle in any frame; *skinned* is the skinning's own worst error before the volume constraint. "
             "Depths inside bone are read from the bones' distance fields (1 mm voxels); *offsets* are how far the "
             "volume constraint moved the surface vertices; *bone contact* moves the skinned vertices inside a bone out to "
             "it before the volume constraint. The node's surfaces are the row marked (node). The first frame of "
             "*hip_flexion* is the rest pose; of *gait*, the gait's first pose. "
             + (f"The bone contact, the volume constraint and the metrics run on {int(variants[0]['threads'])} "
                "threads (the node's `threads`; the muscles shared out), the skinning on one. "
                if variants and "threads" in variants[0] else "")
             + "Raw numbers: `out/bench/fidelity.json`.",
             "",
             "| case | surface | volume error mean % | worst % (muscle) | skinned worst % (muscle, pose) | surface inside bone max mm "
             "(first frame) | particles inside bone max mm | offsets mean / max mm | vertices held by a bone | "
             "skinning ms | bone contact ms | volume ms | metrics ms |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in variants:
        node = " (node)" if r.get("node_default") else ""
        contact_ms = f"{r['contact_ms_median']:.2f}" if "contact_ms_median" in r else "-"
        lines.append(f"| {r['case']} | {r['variant']}{node} | {r['volume_error_mean_pct']:.2f} | "
                     f"{r['volume_error_max_pct']:.2f} ({r['volume_error_max_muscle']}) | "
                     f"{r['skinned_volume_error_max_pct']:.2f}{_worst_pose(r)} | {r['surface_inside_bone_max_mm']:.2f} "
                     f"({r['surface_inside_bone_rest_mm']:.2f}) | {r.get('particle_inside_bone_max_mm', float('nan')):.2f} | "
                     + (f"{r['offset_mean_mm']:.3f} / {r['offset_max_mm']:.2f} | {int(r['vertices_held_max'])} | "
                        if r["keep_volume"] else "- | - | ")
                     + f"{r['skinning_ms_median']:.2f} | {contact_ms} | "
                     + (f"{r['volume_ms_median']:.2f}" if r["keep_volume"] else "-")
                     + f" | {r['metrics_ms_median']:.2f} |")
    for r in unavailable:
        lines.append(f"\n{r['variant']} could not be set up: {r['unavailable']}")
    if per_muscle:
        lines += ["", "Per muscle, nearest_average skinned alone, with the volume constraint, and with the skin's contact "
                      "with the bones before the volume constraint (the node's surfaces): mean / worst |volume error| %, "
                      "deepest surface vertex inside bone mm, deepest particle inside bone mm:", "",
                  "| muscle | gait, skinned alone | gait, volume kept | gait, bone contact and volume kept (node) | "
                  "hip_flexion, skinned alone | hip_flexion, volume kept | hip_flexion, bone contact and volume kept "
                  "(node) |",
                  "|---|---|---|---|---|---|---|"]
        names = []
        for r in per_muscle:
            if r["muscle"] not in names:
                names.append(r["muscle"])
        for name in names:
            cells = []
            for case in ("gait", "hip_flexion"):
                for suffix in ("", " + volume", " + bone contact + volume"):
                    r = next((x for x in per_muscle if x["muscle"] == name and x["case"] == case
                              and x["variant"] == x["variant"].split(" + ")[0] + suffix), None)
                    cells.append(f"{r['volume_error_mean_pct']:.2f} / {r['volume_error_max_pct']:.2f}, "
                                 f"{r['surface_inside_bone_max_mm']:.1f}, {r.get('particle_inside_bone_max_mm', float('nan')):.1f}"
                                 if r else "-")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += [""]
    return lines

LENGTH_JOINTS = ("hip_flexion_r", "hip_adduction_r", "hip_rotation_r", "knee_angle_r")


def length_target_misses(r, prefix=""):
    """What keeps a muscle's belly length from issue 26's target, as short phrases (empty: it meets it)."""
    misses = []
    if r[prefix + "r"] < 0.9:
        misses.append(f"r {r[prefix + 'r']:.2f}")
    reference, product = r["range_mm_reference"], r[prefix + "range_mm_product"]
    if reference >= 10.0:
        if not 0.7 <= product / reference <= 1.3:
            misses.append(f"excursion x{product / reference:.2f}")
    elif abs(product - reference) > 3.0:
        misses.append(f"excursion {product - reference:+.1f} mm")
    for joint in LENGTH_JOINTS:
        expected = r["mm_per_rad_reference_" + joint]
        if abs(expected) > 5.0 and expected * r[prefix + "mm_per_rad_product_" + joint] <= 0:
            misses.append(f"{joint} sign")
    return misses


def lengths_section(rows):
    compared = [r for r in rows if "r" in r]
    without = [r["muscle"] for r in rows if "r" not in r and "fibre_folding" not in r]
    folding = next((r for r in rows if "fibre_folding" in r), None)
    meeting = [r for r in compared if not length_target_misses(r)]
    meeting_converged = [r for r in compared if not length_target_misses(r, "converged_")]
    lines = ["## Muscle lengths against gait2392", "",
             "Each bundled muscle's mean belly fibre length over the 1-cycle gait (what `~fibres` shows) against the "
             "musculotendon length of its gait2392 counterpart(s), computed by our reader from the .osim scaled to the "
             "skeleton at the trial's joint angles. *stream*: the node's defaults frame by frame; *converged*: every "
             "frame refined until it meets the residual criterion (so solver lag and the model can be told apart). "
             "*with tendon*: belly plus each tendon along its path to the site. mm/rad: least-squares slope against "
             "the four right-leg joint angles. Target (issue 26): r >= 0.9, excursion 0.7-1.3 x the reference's "
             "(within 3 mm where it moves < 10 mm), each joint's slope with gait2392's sign where that exceeds 5 mm/rad. "
             f"**{len(meeting)} of {len(compared)}** muscles meet it streamed, {len(meeting_converged)} converged. "
             "*span*: what the belly's tone aims at, each fibre's rest belly length plus the change of the span "
             "between its attachments as the bones carry them (through the muscle's belly path, tendon paths beyond), "
             "r and excursion ratio against gait2392: where the span follows gait2392 and the belly does not, the "
             "miss is inside the model; where the span does not, it is in the attachments. "
             "*tone sets*: the rest lengths the tone gives the belly, the span's change held to +-25 % of each "
             "fibre's rest belly length (excursion ratio; the share of fibre-frames the limit held; gait2392's "
             "excursion as a strain of the rest belly): where it falls short of the span, the belly as segmented is "
             "too short to take the reference's excursion within the limit. "
             "Raw numbers: `out/bench/lengths.json`.", "",
             "| muscle | gait2392 | r stream / converged | r with tendon | span r (excursion x) | "
             "tone sets x (limit held; strain asked) | excursion mm product / reference (x) | "
             "knee mm/rad product / reference | hip flexion mm/rad product / reference | misses (stream) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in compared:
        misses = length_target_misses(r)
        span = (f"{r['spanned_r']:.2f} (x{r['spanned_range_ratio']:.2f})" if "spanned_r" in r else "-")
        toned = (f"x{r['toned_range_ratio']:.2f} ({100 * r['tone_limited_share']:.0f} %; "
                 f"{100 * r['reference_excursion_strain']:.0f} % of {r['rest_belly_length_mm']:.0f} mm)"
                 if "toned_range_ratio" in r and "tone_limited_share" in r else "-")
        lines.append(f"| {r['muscle']} | {r['reference']} | {r['r']:.2f} / {r['converged_r']:.2f} | "
                     f"{r['with_tendon_r']:.2f} | {span} | {toned} | "
                     f"{r['range_mm_product']:.1f} / {r['range_mm_reference']:.1f} "
                     f"(x{r['range_ratio']:.2f}) | {r['mm_per_rad_product_knee_angle_r']:.0f} / "
                     f"{r['mm_per_rad_reference_knee_angle_r']:.0f} | {r['mm_per_rad_product_hip_flexion_r']:.0f} / "
                     f"{r['mm_per_rad_reference_hip_flexion_r']:.0f} | {', '.join(misses) if misses else 'meets'} |")
    if without:
        lines += ["", "No counterpart in gait2392: " + ", ".join(without) + "."]
    if folding:
        lines += ["", "Whether the fibres kept their line, so that their arc length measures the muscle (the worst frame "
                  "of all muscles; *folded*: a fibre turning back on itself somewhere, two consecutive segments more "
                  "than 90 degrees apart, where it did not at rest; *tortuosity*: arc length over end-to-end distance "
                  "against the same at rest): " + "; ".join(
                      f"{label} {_folding_phrase(folding, prefix)}"
                      for label, prefix in (("streamed", ""), ("converged", "converged_"))) + "."]
    lines += [""]
    return lines


def _folding_phrase(row, prefix):
    folded = int(row[prefix + "folded_fibres_max"])
    ratio = row.get(prefix + "fibre_tortuosity_ratio_max")
    return ((f"{folded} fibres folded ({row[prefix + 'most_folded_muscle']})" if folded else "no fibre folded")
            + (f", tortuosity at most x{ratio:.2f} of rest ({row[prefix + 'most_tortuous_muscle']})"
               if ratio is not None else ", tortuosity not measured"))


# Each section: its name for --sections, the JSON it is made from, and how.
SECTIONS = [
    ("realtime", "realtime.json", lambda rows, img_dir: realtime_report.realtime_section(rows, img_dir)),
    ("paper_table", "paper_table.json", lambda rows, img_dir: accuracy_report.paper_table_section(rows)),
    ("speed_vs_error", "speed_vs_error.json", None),  # with realtime.json's measured bandwidth
    ("bone_proxy", "bone_proxy.json", lambda rows, img_dir: bone_proxy_section(rows)),
    ("stability", "stability.json", lambda rows, img_dir: accuracy_report.stability_section(rows)),
    ("economy", "economy.json", lambda rows, img_dir: accuracy_report.economy_section(rows)),
    ("mss", "mss.json", lambda rows, img_dir: mss_section(rows)),
    ("iteration", "iteration.json", lambda rows, img_dir: iteration_section(rows)),
    ("gait", None, None),  # from out/demo/stats.csv
    ("local_global", "local_global.json", lambda rows, img_dir: local_global_section(rows)),
    ("fidelity", "fidelity.json", lambda rows, img_dir: fidelity_section(rows)),
    ("lengths", "lengths.json", lambda rows, img_dir: lengths_section(rows)),
    ("skinning", "skinning.json", lambda rows, img_dir: skinning_section(rows)),
]


def section_lines(name, out_dir, img_dir):
    """The lines of one section, or None when what it is made from is not there."""
    if name == "gait":
        demo_stats = out_dir.parent / "demo" / "stats.csv"
        return gait_section(demo_stats) if demo_stats.exists() else None
    _, json_name, build = next(entry for entry in SECTIONS if entry[0] == name)
    rows = load(out_dir, json_name)
    if name == "speed_vs_error":
        return speed_error_report.section(rows, img_dir, realtime_rows=load(out_dir, "realtime.json")) if rows else None
    return build(rows, img_dir) if rows else None


def split_sections(text):
    """The report's header lines and its sections as (heading, lines), in order."""
    header, sections = [], []
    for line in text.split("\n"):
        if line.startswith("## "):
            sections.append((line, [line]))
        elif sections:
            sections[-1][1].append(line)
        else:
            header.append(line)
    return header, sections


def replace_sections(text, new_sections, note):
    """`text` with each section of `new_sections` (lists of lines starting with their heading) in place of the one with
    the same heading, or appended when there is none; `note` goes below the header's machine line."""
    header, sections = split_sections(text)
    for lines in new_sections:
        heading = lines[0]
        for k, (existing, _) in enumerate(sections):
            if existing == heading:
                sections[k] = (heading, lines)
                break
        else:
            sections.append((heading, lines))
    header = [line for line in header if not line.startswith("Regenerated separately:")]
    while header and header[-1] == "":
        header.pop()
    header += ["", note, ""]
    return "\n".join(header + [line for _, lines in sections for line in lines])


def main():
    arguments = [a for a in sys.argv[1:] if not a.startswith("--sections=")]
    chosen = [a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("--sections=")]
    out_dir = pathlib.Path(arguments[0])
    target = pathlib.Path(arguments[1])
    img_dir = target.parent / "img"
    img_dir.mkdir(parents=True, exist_ok=True)
    if chosen:
        # Only the named sections, from this run's JSON, in place of their old text: the rest keeps its own run.
        names = chosen[0].split(",")
        unknown = [n for n in names if n not in {entry[0] for entry in SECTIONS}]
        if unknown:
            sys.exit(f"bench_report.py: unknown section(s) {', '.join(unknown)}")
        new_sections = []
        for name in names:
            lines = section_lines(name, out_dir, img_dir)
            if lines is None:
                sys.exit(f"bench_report.py: nothing in {out_dir} to make the {name} section from")
            new_sections.append(lines)
        headings = ", ".join(f"\"{lines[0][3:]}\"" for lines in new_sections)
        note = (f"Regenerated separately: {headings} on {machine_description()}; the other sections come from the "
                "full run named above, so compare numbers only within a section.")
        target.write_text(replace_sections(target.read_text(), new_sections, note))
        print(f"updated {', '.join(names)} in {target}")
        return
    lines = ["# Benchmarks", "",
             "Regenerated by `make bench` (do not edit by hand). The machine is shared and noisy: numbers are "
             "medians of repeated runs within one run of `make bench`; ratios compare numbers from that same run.", "",
             f"Machine: {machine_description()}.", ""]
    for name, _, _ in SECTIONS:
        section = section_lines(name, out_dir, img_dir)
        if section:
            lines += section
    known = {entry[1] for entry in SECTIONS if entry[1]}
    extra = sorted(p.name for p in out_dir.glob("*.json") if p.name not in known)
    if extra:
        lines += ["## Other results", "", "Raw numbers in `out/bench/`: " + ", ".join(extra) + ".", ""]
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("\n".join(lines))
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
