"""Sections of docs/BENCHMARKS.md for the paper's table on real anatomy, stability on hard cases and the economies
(speed against error: tools/speed_error_report.py).

Used by tools/bench_report.py. Every number comes from the JSON files in out/bench/; nothing is assumed."""
import math
import statistics


def _number(value, digits=2):
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.{digits}f}"


def _mean(values):
    values = [v for v in values if v is not None and not math.isnan(v)]
    return statistics.fmean(values) if values else float("nan")


# ---------------------------------------------------------------------------------------------------------------
# The paper's Table 1

def paper_table_section(rows):
    first = rows[0]
    lines = ["## The paper's Table 1 on real anatomy (report issue)", "",
             "Milliseconds per iteration (wall; total thread CPU time beside it), the mean over gait frames "
             f"{first.get('gait_frames', '?')} of per-pose medians, measured after {int(first.get('warmup_iterations', 0))} "
             f"warm-up iterations at the pose; {first.get('spring_layout', '?')} springs (the paper used 26-cubic), "
             f"{first.get('broad_phase', '?')} broad phase. The paper's figures are its Table 1 (s per 500 iterations / "
             "500, Core2Duo E6300, 2006). Raw numbers: `out/bench/paper_table.json`.", "",
             "| scene | particles/fibre | particles | springs | boundary particles | bone spheres | MSS | paper | muscle CD "
             "| paper | bone CD | paper | total (CPU) | paper total | speed-up wall (CPU) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(
            f"| {row.get('scene', '-')} | {int(row['particles_per_fibre'])} | {int(row.get('particles', 0))} | "
            f"{int(row.get('springs', 0))} | {int(row.get('boundary_particles', 0))} | {int(row.get('bone_spheres', 0))} | "
            f"{row['mss_ms']:.3f} | {_number(row.get('paper_mss_ms'), 1)} | {row['muscle_cd_ms']:.3f} | "
            f"{_number(row.get('paper_muscle_cd_ms'), 1)} | {row['bone_cd_ms']:.3f} | "
            f"{_number(row.get('paper_bone_cd_ms'), 1)} | {row['total_ms']:.3f} ({_number(row.get('total_cpu_ms'), 3)}) | "
            f"{row['paper_total_ms']:.1f} | {row['ratio']:.0f}x ({_number(row.get('cpu_ratio'), 0)}x) |")
    lines += [""]
    for scene in sorted({row.get("scene") for row in rows}):
        sample = next(row for row in rows if row.get("scene") == scene)
        lines.append(f"- {scene}: bone spheres per bone {sample.get('bone_sphere_counts', '?')}; "
                     f"{_number(sample.get('contacts_per_iteration'), 0)} contacts per iteration at 20 particles per fibre.")
    return lines + [""]


# ---------------------------------------------------------------------------------------------------------------
# Stability and economies: generic tables of the benches' objects

def _generic_table(rows, columns):
    lines = ["| " + " | ".join(label for label, _ in columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        cells = []
        for _, key in columns:
            value = row.get(key)
            if isinstance(value, float):
                cells.append(_number(value, 3 if abs(value) < 10 else 1))
            elif isinstance(value, bool):
                cells.append("yes" if value else "no")
            else:
                cells.append("-" if value is None else str(value))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _converged_strain(row):
    if row.get("converged_strain_p99_median") is None:
        return "not measured"
    return (f"{row['converged_strain_p99_median']:.3f} / {row['converged_strain_p99_max']:.3f} "
            f"({int(row['converged_frames'])} of {int(row['reference_frames'])})")


def _deepest_centre(cases):
    """The deepest particle centre in a bone over the cases (the distance fields'), as a sentence; empty if unmeasured."""
    measured = [row for row in cases if row.get("max_particle_inside_bone_mm") is not None]
    if not measured:
        return ""
    row = max(measured, key=lambda r: r["max_particle_inside_bone_mm"])
    if row["max_particle_inside_bone_mm"] <= 0:
        return " No particle centre is inside a bone."
    where = f", {row['deepest_particle']}" if row.get("deepest_particle") else ""
    return (f" The deepest particle centre inside a bone (the bone's distance field): "
            f"{row['max_particle_inside_bone_mm']:.2f} mm ({row['case']}{where}).")


def _folding(row):
    """Whether the fibres kept their line in the case's worst frame: fibres folded and tortuosity against rest."""
    if "folded_fibres_max" not in row:
        return "-"
    folded = int(row["folded_fibres_max"])
    ratio = row.get("fibre_tortuosity_ratio_max")
    return ((f"{folded} ({row['most_folded_muscle']})" if folded else "none")
            + (f" / x{ratio:.2f} ({row['most_tortuous_muscle']})" if ratio is not None else " / absent"))


def stability_section(rows):
    motions = [row for row in rows if "strain_p99_median" in row]
    cases = [row for row in rows if row.get("case") != "pbd_femur_flexion" and "strain_p99_median" not in row]
    pbd = [row for row in rows if row.get("case") == "pbd_femur_flexion"]
    lines = ["## Stability on hard cases (report issue)", "",
             "The bundled thigh13 muscles at 20 particles per fibre with the node's defaults "
             "(`config/muscle_deformation.yaml`; iterations per frame in the table). Every case is also a gtest on the synthetic scene (`core/test/stability_test.cpp`), where the "
             "recovered error is asserted against stated bounds. Divergence: three growing, direction-reversing steps "
             "above a quarter of the mean spring rest length; recovery restores the solve's start and halves dt "
             "(kept for later frames). *Fibres folded*: in the case's worst frame, the fibres that turn back on "
             "themselves somewhere (two consecutive segments more than 90 degrees apart) where they did not at rest, "
             "and the muscle with the most; *tortuosity x rest*: the largest fibre arc length over its end-to-end "
             "distance, against the same at rest (1 = as straight as at rest), and its muscle. "
             "Raw numbers: `out/bench/stability.json`.", ""]
    if cases:
        radius = cases[0].get("median_sphere_radius_mm", float("nan"))
        lines += ["| case | what | recoveries | gave up | finite | iterations | wall ms | dt at the end s | RMS to the "
                  "pre-transform mm | sphere penetration into bone mm | between muscles mm | particle centres in "
                  "bone mm (deepest) | fibres folded / tortuosity x rest |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in cases:
            lines.append(f"| {row['case']} | {row.get('description', '')} | {int(row['recoveries'])} | "
                         f"{'yes' if row['diverged'] else 'no'} | {'yes' if row['finite'] else 'no'} | "
                         f"{int(row['iterations'])} | {row['wall_ms']:.0f} | {row['time_step_s']:.3g} | "
                         f"{row['rms_to_pretransform_mm']:.2f} | {row['max_penetration_sphere_bone_mm']:.2f} | "
                         f"{row['max_penetration_sphere_muscle_mm']:.2f} | "
                         f"{row.get('max_particle_inside_bone_mm', float('nan')):.2f}"
                         f"{' (' + row['deepest_particle'] + ')' if row.get('deepest_particle') else ''} | "
                         f"{_folding(row)} |")
        deep = [row for row in cases if row["max_penetration_sphere_bone_mm"] > radius]
        names = {row["case"] for row in cases}
        notes = []
        for row in deep:
            note = (f"{row['case']} ({row['max_penetration_sphere_bone_mm']:.2f} mm, "
                    f"{int(row['iterations'])} iteration{'s' if int(row['iterations']) != 1 else ''}"
                    f"{', no recovery fired' if int(row['recoveries']) == 0 else ''})")
            if row["case"] + "_stream" in names:
                note += (f"; the node's stream never starts that jump warm: it sees a discontinuity and starts cold "
                         f"({row['case']}_stream)")
            notes.append(note)
        lines += ["", f"The median collision sphere radius is {radius:.2f} mm. "
                  + (f"Penetration deeper than that (a particle centre inside the bone proxy) remains in: "
                     + "; ".join(notes) + ". It is convergence unfinished within the frame's iterations, not "
                     "divergence." if deep else "No contact is deeper than that.")
                  + _deepest_centre(cases), ""]
    if motions:
        gait = next((row for row in motions if row["case"] == "gait_1x"), None)
        lines += ["### Motions beyond the gait", "",
                  "Each motion streamed as the node streams it (poses 1/60 s apart, thigh13, node defaults), then its "
                  "last pose held for up to 2 s. *strain p99*: the 99th percentile of |l - l0| / l0 over the springs, "
                  "per frame (median and worst frame of the motion); *volume*: the model's own, from tetrahedra over "
                  "each muscle's particles (no surface, so no projection), the worst muscle and frame; *settled*: held "
                  "poses until the stream stops refining (its residual criterion met, or the residual no longer "
                  "falling); *converged*: the same motion played again with every frame solved until it meets the "
                  "residual criterion (at most 150 sweeps), so the strain of the motion itself, without the stream's "
                  "lag; *after the hold*: the last frame solved within the first 30 held poses (the held pose it "
                  "solved; 0: the motion's last frame, when the hold needed none), its worst muscle's volume error "
                  "from the skinned surface before any correction (the model's own, as the fidelity section measures "
                  "it) and its strain p99, beside the held pose's own when converged (the converged replay's last "
                  "frame)."
                  + (f" The yardstick (issue 29): the gait's median strain p99, {gait['strain_p99_median']:.3f}; 2 x is "
                     f"{2 * gait['strain_p99_median']:.3f}." if gait else ""), "",
                  "| motion | what | finite | cold restarts | strain p99 median / worst frame | converged: strain p99 "
                  "median / worst frame (frames that met the criterion) | max strain | particle "
                  "centres in bone mm (deepest) | volume error max % | settled after held poses | after the hold: "
                  "model volume error max % / strain p99 (held pose) | fibres folded / tortuosity x rest |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in motions:
            settled = (f"{int(row['held_poses_until_settled'])} "
                       f"({'converged' if row['settled_converged'] else 'residual no longer falling'})"
                       if "held_poses_until_settled" in row else "still refining")
            lines.append(f"| {row['case']} | {row.get('description', '')} | {'yes' if row['finite'] else 'no'} | "
                         f"{int(row['restarts'])} | {row['strain_p99_median']:.3f} / {row['strain_p99_max']:.3f} | "
                         f"{_converged_strain(row)} | "
                         f"{row['max_strain']:.1f} | {row['max_particle_inside_bone_mm']:.2f}"
                         f"{' (' + row['deepest_particle'] + ')' if row.get('deepest_particle') else ''} | "
                         f"{row['particle_volume_error_max_pct']:.1f} | {settled} | {_after_hold(row)} | "
                         f"{_folding(row)} |")
        lines += [""]
        owned = [row for row in motions if row.get("strain_p99_owners")]
        if owned:
            lines += ["Whose springs make each motion's strain p99 (per frame, the springs at or above that frame's "
                      "99th percentile, by muscle and kind, summed over the motion; *across the fibres*: belly springs "
                      "at more than 45 degrees to them, the soft ones; *stretched*: longer than their rest length): " + "; ".join(
                          f"{row['case']}: {row['strain_p99_owners']}" for row in owned) + ".", ""]
        lines += _after_hold_lines(motions, gait)
        if gait:
            beyond = [row for row in motions if row.get("converged_strain_p99_median") is not None
                      and row["converged_strain_p99_median"] > 2 * gait["strain_p99_median"]]
            if beyond:
                lines += ["Above 2 x the gait's median even when converged frame by frame, so beyond what more sweeps "
                          "can give: " + "; ".join(
                              f"{row['case']} ({row['converged_strain_p99_median']:.3f} converged against "
                              f"{row['strain_p99_median']:.3f} streamed)" for row in beyond)
                          + ". Their springs are stretched that far by the poses themselves.", ""]
    for row in pbd:
        lines += ["### The 2019 PBD thesis scenario on our data", "",
                  f"{row.get('description', '')} ({int(row['particles'])} particles, {int(row['iterations'])} "
                  f"iterations in {row['wall_ms'] / 1e3:.1f} s): the gluteus maximus ends "
                  f"**{row['gluteus_end_rms_to_start_mm']:.2f} mm RMS** from its starting shape (peak on the way "
                  f"{row['gluteus_peak_rms_to_start_mm']:.1f} mm); the deepest sphere penetration into bone on the "
                  f"way is **{row['max_penetration_sphere_bone_mm']:.2f} mm** (median sphere radius "
                  f"{row['median_sphere_radius_mm']:.2f} mm), the deepest particle centre in bone "
                  f"{row.get('max_particle_inside_bone_mm', float('nan')):.2f} mm; {int(row['recoveries'])} recoveries, "
                  f"{'every frame finite' if row['finite'] else 'NON-FINITE frames'}.", ""]
    return lines


def _after_hold(row):
    """The after-the-hold cell: volume error / strain p99 (held pose), '-' for what was not measured."""
    if row.get("after_hold_poses") is None or row["after_hold_poses"] < 0:
        return "-"
    volume = row.get("after_hold_volume_error_max_pct")
    strain = row.get("after_hold_strain_p99")
    own = row.get("converged_last_strain_p99")
    return (f"{'-' if volume is None else f'{volume:.3f}'} / {'-' if strain is None else f'{strain:.3f}'}"
            f"{'' if own is None else f' (converged {own:.3f})'} ({int(row['after_hold_poses'])})")


# Issue 29's window and volume bound after a jump that follows a hold.
HELD_POSES_JUDGED = 30
AFTER_JUMP_VOLUME_PCT = 5.0


def _after_hold_lines(motions, gait):
    """The issue's targets after the motion stops: after the jump, the model's volume within 5 % and the residual
    criterion met within 30 held poses; after every motion, the strain back at the level of the pose held."""
    lines = []
    jump = next((row for row in motions if row["case"] == "hold_then_jump"), None)
    if jump and jump.get("after_hold_volume_error_max_pct") is not None:
        volume = jump["after_hold_volume_error_max_pct"]
        settled = jump.get("held_poses_until_settled")
        criterion = (settled is not None and settled <= HELD_POSES_JUDGED and bool(jump.get("settled_converged")))
        lines.append(f"After the jump that follows the hold, within {HELD_POSES_JUDGED} held poses: the model's volume "
                     f"error at most {volume:.3f} % at the worst muscle (target <= {AFTER_JUMP_VOLUME_PCT:g} %: "
                     f"{'met' if volume <= AFTER_JUMP_VOLUME_PCT else 'missed'}); the residual criterion "
                     + (f"met after {int(settled)} held poses (met)." if criterion else "not met within them (missed)."))
    still = next((row for row in motions if row["case"] == "standing_jitter"), None)
    if still and still.get("residual_motion_max") is not None:
        tolerance = still.get("residual_tolerance")
        lines.append(f"Standing still with a recording's jitter ({still.get('description', '')}), every pose solved "
                     f"warm with the stream's sweeps: residual median {still['residual_motion_median']:.2g}, at most "
                     f"{still['residual_motion_max']:.2g}"
                     + (f" (the residual criterion is {tolerance:g}: "
                        f"{'never left' if still['residual_motion_max'] <= tolerance else 'left'})" if tolerance else "")
                     + ".")
    judged = [row for row in motions if row.get("after_hold_strain_p99") is not None
              and row.get("converged_last_strain_p99") is not None]
    if judged:
        # A held pose cannot relax below its own equilibrium: the reference is that pose solved to convergence (the
        # last frame of the converged replay), within the strain histogram's resolution (6.25 %, SolveStats).
        above = [row for row in judged if row["after_hold_strain_p99"] > 1.0625 * row["converged_last_strain_p99"]]
        lines.append(f"Once the motion stops, strain p99 at the last frame within {HELD_POSES_JUDGED} held poses against the held pose's own, converged"
                     + (f" (the gait's median is {gait['strain_p99_median']:.3f})" if gait else "") + ": "
                     + "; ".join(f"{row['case']} {row['after_hold_strain_p99']:.3f} against "
                                 f"{row['converged_last_strain_p99']:.3f}" for row in judged) + ". "
                     + ("Every motion comes back to its held pose's own level." if not above else
                        "Still above it: " + ", ".join(row["case"] for row in above) + "."))
    return [part for line in lines for part in (line, "")]


def economy_section(rows):
    def of(economy):
        return [row for row in rows if row.get("economy") == economy]

    lines = ["## Model only what a scene needs (report issue)", "",
             "What each economy buys on the bundled scene at 20 particles per fibre with the node's defaults (warm "
             f"start, {rows[0].get('solver', 'verlet')} under the node's stopping rule; a small subset fits more "
             "iterations into a time budget), over the 73 frames of the gait. "
             "Frame times are medians, wall "
             "(thread CPU in brackets). Raw numbers: `out/bench/economy.json`.", ""]
    subsets = of("muscle_subset")
    if subsets:
        lines += ["### Simulating only the requested muscles", "",
                  "| muscles | particles | springs | collision spheres | memory MB | build ms | frame ms |",
                  "|---|---|---|---|---|---|---|"]
        for row in subsets:
            lines.append(f"| {row['variant']} | {int(row['particles'])} | {int(row['springs'])} | "
                         f"{int(row['collision_spheres'])} | {row['memory_bytes'] / 1e6:.1f} | {row['build_ms']:.0f} | "
                         f"{row['frame_ms']:.1f} ({row['frame_cpu_ms']:.1f}) |")
        lines += [""]
    reach = of("bone_reach")
    if reach:
        lines += ["### Skipping bones out of reach", "",
                  "Each iteration the collision stage skips a bone whose sphere bounds reach no muscle's bounds "
                  "(`CollisionSettings::skip_bones_out_of_reach`); the results are identical either way (largest "
                  "position difference in the column).", "",
                  "| variant | bones skipped (median) | frame ms | bone CD ms per frame | largest position difference m |",
                  "|---|---|---|---|---|"]
        for row in reach:
            lines.append(f"| {row['variant']} | {row['bones_skipped_median']:g} | {row['frame_ms']:.1f} "
                         f"({row['frame_cpu_ms']:.1f}) | {row['bone_cd_ms_per_frame']:.1f} | "
                         f"{row['max_position_difference_m']:g} |")
        lines += [""]
    particles = of("collision_particles")
    if particles:
        lines += ["### Boundary-only collision", "",
                  "The seeds give spheres to boundary particles only. Penetration into bone is measured with both "
                  "models' spheres: each keeps its own spheres out of the bones.", "",
                  "| variant | collision spheres | spheres dropped at rest | frame ms | collision ms per frame | "
                  "bone penetration mm (boundary spheres) | (every-particle spheres) |", "|---|---|---|---|---|---|---|"]
        for row in particles:
            lines.append(f"| {row['variant']} | {int(row['collision_spheres'])} | {int(row['rest_spheres_removed'])} | "
                         f"{row['frame_ms']:.1f} ({row['frame_cpu_ms']:.1f}) | {row['collision_ms_per_frame']:.1f} | "
                         f"{row['penetration_boundary_spheres_mm']:.2f} | {row['penetration_every_particle_spheres_mm']:.2f} |")
        lines += [""]
    unchanged = of("unchanged_pose")
    if unchanged:
        lines += ["### Skipping unchanged poses", "",
                  f"The node's unchanged-pose check costs {unchanged[0]['check_ms'] * 1e3:.2f} us per message. Mean "
                  "cost per message of streams made from the gait (measured solve and check times):", "",
                  "| stream | messages | solved | skipped | ms per message | without the check |", "|---|---|---|---|---|---|"]
        for row in unchanged:
            lines.append(f"| {row['variant']} | {int(row['messages'])} | {int(row['solved'])} | {int(row['skipped'])} | "
                         f"{row['frame_ms']:.1f} | {row['frame_ms_without_check']:.1f} |")
        lines += [""]
    return lines
