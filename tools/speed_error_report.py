"""The "Speed against error" section of docs/BENCHMARKS.md, from out/bench/speed_vs_error.json (bench/speed_error_bench.cpp)
and its plots (PNG in docs/img/).

Every figure in the section's tables is a value of the JSON, formatted; the section's judgements (which curve falls,
which configuration is fastest to a target) are computed from those values here and nowhere else."""
import math

import matplotlib

matplotlib.use("Agg")  # headless: make bench runs without a display
import matplotlib.pyplot as plt  # noqa: E402

HEADING = "## Speed against error"
BASE_MODEL = "20 x 64 nearest18"
# Error targets per kind (the fastest configuration that meets each is tabled).
CONVERGENCE_TARGETS_MM = (1.0, 0.5, 0.2)
RESOLUTION_TARGETS_MM = (2.0, 1.0, 0.5)
VOLUME_TARGETS_PCT = (10.0, 5.0, 3.0)
# Ours against the peer (Bullet's soft bodies) for the same distance to the converged stream.
PEER_SPEED_TARGET = 5.0
PEER_SOLVER = "bullet_soft_body"
# The per-muscle resolution's target: at least this much faster than uniform 20 per fibre for the same worst error.
PER_MUSCLE_SPEED_TARGET = 1.5


def fmt(value, digits=2):
    """A JSON figure as the tables show it; '-' for one that was not measured (null)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, float) and value.is_integer() and digits == 0:
        return str(int(value))
    return f"{value:.{digits}f}"


def configurations(rows):
    """The configuration points (every row but the per-muscle ones and the peer's set-up notes)."""
    return [r for r in rows if r.get("solver") not in ("per_muscle", "peer_setup", "machine")]


def is_reference(row):
    return bool(row.get("reference"))


def resolution_key(row):
    """Models ordered by particles then label."""
    return (row.get("particles", 0), row.get("model", ""))


# ---------------------------------------------------------------------------------------------------------------
# Judgements

def curve_solver(row):
    """The solver as a curve names it: the peer with bone colliders (played over part of the gait) is its own curve."""
    if row["solver"] == PEER_SOLVER and "bone meshes as colliders" in row.get("configuration", ""):
        return PEER_SOLVER + " with bone colliders"
    return row["solver"]


def curves(rows, mode):
    """Per (model, solver, threads): the non-reference points of `mode`, in order of frame time."""
    out = {}
    for r in configurations(rows):
        if r["mode"] != mode or is_reference(r) or r.get("configuration", "").startswith("node default"):
            continue
        out.setdefault((r["model"], curve_solver(r), int(r.get("threads", 0))), []).append(r)
    return {key: sorted(points, key=lambda r: r["frame_ms_median"]) for key, points in out.items()}


def falls_along(points, key="convergence_rms_mm"):
    """The points (in order of cost) whose error did not fall from the cheaper one before: [(cheaper, dearer)]."""
    rises = []
    values = [p for p in points if p.get(key) is not None]
    for cheaper, dearer in zip(values, values[1:]):
        if dearer[key] > cheaper[key]:
            rises.append((cheaper, dearer))
    return rises


def fastest(rows, mode, key, target):
    """The configuration of `mode` with the least frame time whose `key` is at most `target`, or None."""
    meeting = [r for r in configurations(rows)
               if r["mode"] == mode and r.get(key) is not None and r[key] <= target]
    return min(meeting, key=lambda r: r["frame_ms_median"]) if meeting else None


def resolution_trend(rows, mode, vary):
    """The converged references of one mode along one resolution axis ('particles_per_fibre' at 64 fibres, or
    'fibres_per_muscle' at 20 per fibre), nearest18 layout, sorted by that axis."""
    fixed = ("fibres_per_muscle", 64) if vary == "particles_per_fibre" else ("particles_per_fibre", 20)
    points = [r for r in configurations(rows)
              if r["mode"] == mode and is_reference(r) and r.get("spring_layout") == "nearest18"
              and not r.get("mixed_resolution") and r.get(fixed[0]) == fixed[1]]
    return sorted(points, key=lambda r: r[vary])


# ---------------------------------------------------------------------------------------------------------------
# Plots

def _plot_kind(rows, key, ylabel, path, log_y=True):
    figure, axes = plt.subplots(1, 2, figsize=(13, 5))
    for axis, mode in zip(axes, ("stream", "cold")):
        for (model, solver, threads), points in sorted(curves(rows, mode).items()):
            points = [p for p in points if p.get(key) is not None and (not log_y or p[key] > 0)]
            if not points:
                continue
            label = f"{solver} {model}" + (" 1 thread" if threads == 1 else "")
            axis.plot([p["frame_ms_median"] for p in points], [p[key] for p in points], marker="o", label=label)
        references = [r for r in configurations(rows) if r["mode"] == mode and is_reference(r)
                      and r.get(key) is not None and (not log_y or r[key] > 0)]
        if references:
            axis.scatter([r["frame_ms_median"] for r in references], [r[key] for r in references], marker="*", s=90,
                         color="black", label="converged (each model's reference)", zorder=3)
        axis.set_xscale("log")
        if log_y:
            axis.set_yscale("log")
        axis.set_xlabel("frame time, median (ms)" if mode == "stream" else "pose time, median (ms)")
        axis.set_ylabel(ylabel)
        axis.set_title(f"{mode}: the gait streamed" if mode == "stream" else "cold: five gait poses")
        axis.grid(True, which="both", alpha=0.3)
        if axis.get_legend_handles_labels()[0]:
            axis.legend(fontsize=6)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def plots(rows, img_dir):
    img_dir.mkdir(parents=True, exist_ok=True)
    names = {"convergence": ("convergence_rms_mm", "RMS to the converged answer of the same model (mm)", True),
             "resolution": ("resolution_rms_mm", "surface RMS to the finest model (mm)", True),
             "volume": ("model_volume_error_max_pct", "model volume error, worst muscle and frame (%)", False)}
    for name, (key, ylabel, log_y) in names.items():
        _plot_kind(rows, key, ylabel, img_dir / f"speed_vs_error_{name}.png", log_y)
    return [f"speed_vs_error_{name}.png" for name in names]


# ---------------------------------------------------------------------------------------------------------------
# Tables

EVERY_COLUMNS = ("mode", "model", "configuration", "threads", "particles", "frame_ms_median", "convergence_rms_mm",
                 "resolution_rms_mm", "resolution_max_mm", "fibre_length_rms_mm", "model_volume_error_max_pct",
                 "length_ratio_worst", "length_r_worst", "length_r_at_least_0_9")
DIGITS = {"threads": 0, "particles": 0, "frame_ms_median": 1, "convergence_rms_mm": 3, "resolution_rms_mm": 2,
          "resolution_max_mm": 2, "fibre_length_rms_mm": 2, "model_volume_error_max_pct": 2,
          "length_ratio_worst": 2, "length_r_worst": 2, "length_r_at_least_0_9": 0}


def cell(row, column):
    value = row.get(column)
    if column in DIGITS:
        return fmt(float(value) if isinstance(value, (int, float)) else value, DIGITS[column])
    return f"`{value}`" if column == "configuration" else str(value)


def every_configuration_lines(rows):
    lines = ["| mode | model | configuration | threads | particles | frame ms (median) | convergence RMS mm | "
             "surface RMS / max mm to the finest | fibre length RMS mm to the finest | model volume error % (worst) | "
             "length excursion ratio (worst) | r (worst) | muscles r >= 0.9 |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    ordered = sorted(configurations(rows), key=lambda r: (r["mode"] != "stream", resolution_key(r),
                                                           not is_reference(r), r["frame_ms_median"]))
    for r in ordered:
        cells = [cell(r, c) for c in EVERY_COLUMNS]
        # surface RMS / max share a column
        cells[7] = f"{cells[7]} / {cells[8]}"
        del cells[8]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def fastest_lines(rows):
    lines = ["| kind of error | target | mode | fastest configuration | model | frame ms (median) | its error |",
             "|---|---|---|---|---|---|---|"]
    kinds = (("convergence (RMS to the same model converged)", "convergence_rms_mm", CONVERGENCE_TARGETS_MM, "mm"),
             ("resolution (surface RMS to the finest model)", "resolution_rms_mm", RESOLUTION_TARGETS_MM, "mm"),
             ("anatomy (model volume error, worst muscle)", "model_volume_error_max_pct", VOLUME_TARGETS_PCT, "%"))
    for label, key, targets, unit in kinds:
        for target in targets:
            for mode in ("stream", "cold"):
                best = fastest(rows, mode, key, target)
                if best is None:
                    lines.append(f"| {label} | {target:g} {unit} | {mode} | none reached it | - | - | - |")
                else:
                    lines.append(f"| {label} | {target:g} {unit} | {mode} | `{best['configuration']}` | "
                                 f"{best['model']} | {fmt(best['frame_ms_median'], 1)} | {fmt(best[key], 3)} |")
    return lines


def reference_lines(rows):
    lines = ["| model | particles | fibres | stream: residual median / last frame moves mm with as many sweeps again | "
             "cold: residual median / middle pose moves mm |", "|---|---|---|---|---|"]
    by_model = {}
    for r in configurations(rows):
        if is_reference(r):
            by_model.setdefault(r["model"], {})[r["mode"]] = r
    for model, modes in sorted(by_model.items(), key=lambda item: resolution_key(next(iter(item[1].values())))):
        stream, cold = modes.get("stream", {}), modes.get("cold", {})
        any_row = stream or cold
        lines.append(f"| {model} | {fmt(float(any_row.get('particles', 0)), 0)} | {fmt(float(any_row.get('fibres', 0)), 0)} | "
                     f"{fmt(stream.get('reference_residual_median'), 3)} / {fmt(stream.get('reference_moves_mm'), 4)} | "
                     f"{fmt(cold.get('reference_residual_median'), 3)} / {fmt(cold.get('reference_moves_mm'), 4)} |")
    return lines


def per_muscle_lines(rows):
    """The mixed model's choice per muscle, with the converged error of that muscle there and at uniform 20 x 64."""
    per_muscle = [r for r in rows if r.get("solver") == "per_muscle"]
    mixed = [r for r in per_muscle if r.get("mixed_resolution")]
    if not mixed:
        return [], None
    base = {r["muscle"]: r for r in per_muscle if r["model"] == BASE_MODEL}
    lines = ["| muscle | particles per fibre x fibres chosen | its surface RMS mm, worst frame (mixed model) | "
             "at uniform 20 x 64 |", "|---|---|---|---|"]
    for r in mixed:
        lines.append(f"| {r['muscle']} | {fmt(float(r['particles_per_fibre']), 0)} x {fmt(float(r['fibres_per_muscle']), 0)} | "
                     f"{fmt(r['surface_rms_mm_worst_frame'], 2)} | "
                     f"{fmt(base.get(r['muscle'], {}).get('surface_rms_mm_worst_frame'), 2)} |")
    return lines, mixed[0]["model"]


def point_of(rows, mode, model, configuration):
    for r in configurations(rows):
        if r["mode"] == mode and r["model"] == model and r["configuration"] == configuration:
            return r
    return None


def per_muscle_verdict(rows, mixed_model):
    """The target line: the mixed model's worst surface error and frame time against uniform 20 x 64's."""
    lines = []
    base_worst = max((r["surface_rms_mm_worst_frame"] for r in rows
                      if r.get("solver") == "per_muscle" and r["model"] == BASE_MODEL), default=None)
    mixed_worst = max((r["surface_rms_mm_worst_frame"] for r in rows
                       if r.get("solver") == "per_muscle" and r["model"] == mixed_model), default=None)
    for configuration in ("block_descent 1 sweep", "block_descent 4 sweeps"):
        base = point_of(rows, "stream", BASE_MODEL, configuration)
        mixed = point_of(rows, "stream", mixed_model, configuration)
        if not base or not mixed:
            continue
        speed = base["frame_ms_median"] / mixed["frame_ms_median"]
        faster = speed >= PER_MUSCLE_SPEED_TARGET
        kept = mixed_worst <= base_worst
        if faster and kept:
            verdict = "met"
        else:
            why = ([] if faster else [f"{speed:.2f}x is below it"]) + \
                  ([] if kept else [f"the worst muscle's error rises by {mixed_worst - base_worst:.3f} mm"])
            verdict = "missed: " + " and ".join(why)
        lines.append(f"- Streamed, `{configuration}`: {fmt(mixed['frame_ms_median'], 1)} ms against "
                     f"{fmt(base['frame_ms_median'], 1)} ms for uniform 20 x 64 (**{speed:.2f}x**; target >= "
                     f"{PER_MUSCLE_SPEED_TARGET}x: {verdict}); surface RMS to the finest {fmt(mixed['resolution_rms_mm'], 2)} "
                     f"against {fmt(base['resolution_rms_mm'], 2)} mm; worst muscle, converged: {fmt(mixed_worst, 2)} "
                     f"against {fmt(base_worst, 2)} mm.")
    return lines


def peer_lines(rows):
    """Each peer point against our fastest streamed block-descent configuration of the same model that is at least as
    close to the converged stream."""
    peers = [r for r in configurations(rows) if r.get("solver") == PEER_SOLVER and r["mode"] == "stream"]
    if not peers:
        return ["- The peer (Bullet's soft bodies) was not measured in this run (the bench was built without "
                "libbullet-dev)."]
    lines = []
    for peer in sorted(peers, key=lambda r: (curve_solver(r), r["iterations"])):
        what = f"`{peer['configuration']}`: {fmt(peer['frame_ms_median'], 1)} ms a frame"
        if ", first " in peer["configuration"]:
            lines.append(f"- {what}, {fmt(peer['convergence_rms_mm'], 3)} mm RMS from the converged stream over those "
                         "frames only (the gait's start, where the distance is smallest): not set against ours over the "
                         "whole gait.")
            continue
        if peer.get("convergence_rms_mm") is None:
            lines.append(f"- {what}; no distance (its stream did not stay finite).")
            continue
        if peer["convergence_rms_mm"] > 1000.0:
            lines.append(f"- {what}; its stream flew apart ({peer['convergence_rms_mm'] / 1000.0:.0f} m RMS from the "
                         "converged stream): no distance of ours to set it against.")
            continue
        ours = [r for r in configurations(rows) if r["mode"] == "stream" and r["model"] == peer["model"]
                and r["solver"] == "block_descent" and not is_reference(r)
                and r.get("convergence_rms_mm") is not None and r["convergence_rms_mm"] <= peer["convergence_rms_mm"]]
        if not ours:
            lines.append(f"- {what}, {fmt(peer['convergence_rms_mm'], 3)} mm RMS from the converged stream; none of our "
                         "configurations measured is as close.")
            continue
        best = min(ours, key=lambda r: r["frame_ms_median"])
        speed = peer["frame_ms_median"] / best["frame_ms_median"]
        verdict = "met" if speed >= PEER_SPEED_TARGET else f"missed by {PEER_SPEED_TARGET / speed:.1f}x"
        closer = peer["convergence_rms_mm"] / best["convergence_rms_mm"] if best["convergence_rms_mm"] > 0 else None
        lines.append(f"- {what}, {fmt(peer['convergence_rms_mm'], 3)} mm RMS from the converged stream; ours "
                     f"(`{best['configuration']}`, {fmt(best['convergence_rms_mm'], 3)} mm"
                     + (f", {closer:.1f}x closer" if closer else "") + f") takes "
                     f"{fmt(best['frame_ms_median'], 1)} ms: the peer takes **{speed:.1f}x** our time (target >= {PEER_SPEED_TARGET:g}x "
                     f"for the same distance: {verdict}).")
    return lines


def peer_cost_lines(rows):
    """Why the peer compares as it does, from the slopes of both curves: what one more of its position iterations costs
    against one more of our sweeps, and how far its distance falls with them."""
    def cost_slope(points):
        first, last = points[0], points[-1]
        return (last["frame_ms_median"] - first["frame_ms_median"]) / (last["iterations"] - first["iterations"])

    peers = sorted((r for r in configurations(rows) if r.get("solver") == PEER_SOLVER and r["mode"] == "stream"
                    and ", first " not in r["configuration"] and r.get("convergence_rms_mm") is not None
                    and r["convergence_rms_mm"] <= 1000.0), key=lambda r: r["iterations"])
    ours = sorted((r for r in configurations(rows) if r["mode"] == "stream" and r["model"] == BASE_MODEL
                   and r["solver"] == "block_descent" and not is_reference(r) and r.get("threads") != 1
                   and (r.get("iterations") or 0) > 0 and r.get("convergence_rms_mm") is not None),
                  key=lambda r: r["iterations"])
    if len(peers) < 2 or len(ours) < 2 or peers[0]["iterations"] == peers[-1]["iterations"] \
            or ours[0]["iterations"] == ours[-1]["iterations"]:
        return []
    cheapest = min(ours, key=lambda r: r["frame_ms_median"])
    needed = peers[0]["frame_ms_median"] / PEER_SPEED_TARGET
    return [f"- Why, from the slopes of the two curves: one more position iteration of the peer costs "
            f"{cost_slope(peers):.1f} ms (one thread, {peers[0]['iterations']} to {peers[-1]['iterations']} "
            f"iterations), one more sweep of ours {cost_slope(ours):.1f} ms (every core, {ours[0]['iterations']} to "
            f"{ours[-1]['iterations']} sweeps). The peer's distance to the converged stream falls only from "
            f"{fmt(peers[0]['convergence_rms_mm'], 1)} to {fmt(peers[-1]['convergence_rms_mm'], 1)} mm over those "
            "iterations: it converges towards its own answer, without tissue drag, volume term, bone or muscle "
            "contacts, not towards ours. No iteration count brings it as close as our cheapest configuration "
            f"(`{cheapest['configuration']}`, {fmt(cheapest['convergence_rms_mm'], 3)} mm in "
            f"{fmt(cheapest['frame_ms_median'], 1)} ms), so it is compared at its cheapest stable setting; "
            f"{PEER_SPEED_TARGET:g}x that setting's speed would need a frame of ours in {needed:.1f} ms, "
            f"{cheapest['frame_ms_median'] / needed:.1f}x below our cheapest."]


# ---------------------------------------------------------------------------------------------------------------
# The section

def curve_lines(rows):
    """Does convergence error fall with cost along each solver's curve?"""
    lines = []
    for mode in ("stream", "cold"):
        for (model, solver, threads), points in sorted(curves(rows, mode).items()):
            if len(points) < 2:
                continue
            rises = falls_along(points)
            what = f"{mode}, {solver}, {model}" + (", 1 thread" if threads == 1 else "")
            if not rises:
                values = ", ".join(f"{fmt(p['convergence_rms_mm'], 3)}" for p in points)
                lines.append(f"- {what}: falls with cost ({values} mm).")
            else:
                steps = "; ".join(f"`{a['configuration']}` {fmt(a['convergence_rms_mm'], 3)} mm -> "
                                  f"`{b['configuration']}` {fmt(b['convergence_rms_mm'], 3)} mm" for a, b in rises)
                lines.append(f"- {what}: **rises** with cost: {steps}.")
    return lines


def trend_lines(rows):
    lines = []
    for mode in ("stream", "cold"):
        for vary, label in (("particles_per_fibre", "particles per fibre (64 fibres)"),
                            ("fibres_per_muscle", "fibres per muscle (20 per fibre)")):
            points = resolution_trend(rows, mode, vary)
            if len(points) < 2:
                continue
            values = ", ".join(f"{fmt(float(p[vary]), 0)}: {fmt(p['resolution_rms_mm'], 2)}"
                               + ("" if p.get("resolution_rms_mm") is not None else " (the finest)") for p in points)
            measured = [p for p in points if p.get("resolution_rms_mm") is not None]
            rises = falls_along(measured, "resolution_rms_mm")
            verdict = "falls with resolution" if not rises else "**does not fall** everywhere: " + "; ".join(
                f"{fmt(float(a[vary]), 0)} -> {fmt(float(b[vary]), 0)}" for a, b in rises)
            lines.append(f"- {mode}, converged, {label}: surface RMS mm {values}; {verdict}.")
    return lines


def machine_line(rows, realtime_rows=None):
    """The machine's measured bandwidth: this bench's own measurement, else the real-time bench's from the same run."""
    own = [r for r in rows if r.get("solver") == "machine" and r.get("bandwidth_gbs")]
    if own:
        r = own[0]
        return (f"Machine: the one in the header; this bench measured its memory bandwidth at {r['bandwidth_gbs']:.1f} "
                f"GB/s and {r['gflops']:.1f} Gflop/s on {int(r['floor_threads'])} threads before its models. Times are "
                "wall clock on it.")
    for r in realtime_rows or []:
        if r.get("bandwidth_gbs") and r.get("floor_threads", 0) > 1:
            return (f"Machine: the one in the header; the real-time bench measured its memory bandwidth at "
                    f"{r['bandwidth_gbs']:.1f} GB/s on {int(r['floor_threads'])} threads. Times are wall clock on it.")
    return "Machine: the one in the header (its bandwidth was not measured in this run)."


def section(rows, img_dir, img_link_prefix="img/", realtime_rows=None):
    points = configurations(rows)
    stream_frames = "the 1-cycle gait (73 frames, 60 Hz)"
    lines = [HEADING, "",
             "The bundled `thigh13` muscles (13) at several resolutions (particles per fibre x fibres per muscle) and "
             "spring layouts, the node's model and contacts, on the well-posed problem: block descent with the node's "
             "tissue drag, so that a frame has one answer. Every configuration is one point; x is its frame time "
             f"(stream: {stream_frames}, each frame's solve, median) or pose time (cold: five gait poses, median), "
             "the wall clock of the frame's whole solve (the pose's preparation, the solver's springs and contacts, the "
             "figures after it; skinning and metrics left out; the runs up to 2026-11-28 22:00 UTC counted the solver "
             "alone). Threads 0 = every core. "
             "Raw points: `out/bench/speed_vs_error.json` (null where not measured).", "",
             machine_line(rows, realtime_rows), "",
             "Three kinds of error, each against a reference that is defined for what it measures:", "",
             "- **convergence**: RMS particle distance to the converged answer of the *same* model. Stream frames "
             "against the converged stream (each frame warm from the previous converged frame), every compared stream "
             "starting from the same converged frame 0; cold poses against the same pose solved to convergence.",
             "- **resolution**: RMS and largest distance of the skinned surface vertices to the finest model's (80 "
             "particles per fibre, 128 fibres per muscle, converged) at the same frames (stream: 18, 36, 54, 72) or "
             "poses (cold), and the same for each muscle's mean belly fibre length. The surface is the skin of the "
             "particles alone: neither its contact with the bones nor the volume projection moved it.",
             "- **anatomy**: each muscle's belly length over the gait against gait2392 (the excursion ratio farthest "
             "from 1, the lowest r, the muscles at r >= 0.9; stream only), and the model's volume error (that same "
             "skinned surface, before any projection) at its worst muscle and compared frame or pose.", "",
             "Verlet and local/global have no tissue drag: they solve a different problem, so their distance to the "
             "converged stream holds that difference as well as their lag (their error can grow with iterations as "
             "they approach their own answer).", ""]
    images = plots(points, img_dir)
    captions = {"speed_vs_error_convergence.png": "convergence error against time",
                "speed_vs_error_resolution.png": "surface error to the finest model against time",
                "speed_vs_error_volume.png": "model volume error against time"}
    for image in images:
        lines += [f"![{captions[image]}]({img_link_prefix}{image})", ""]
    lines += ["### Fastest configuration per target", "",
              "Each kind of error separately: the least frame (or pose) time that meets the target.", ""]
    lines += fastest_lines(points) + [""]
    lines += ["### Against a peer: Bullet's soft bodies", "",
              "What a robotics user would pick instead: Bullet's position-based soft bodies (Debian's libbullet, "
              "single precision, one thread) given the same particles, springs (our rest lengths) and fixed particles "
              "of the 20 x 64 model, the fixed ones moved with their bones; no gravity, its collision margin at our "
              "particles' median radius, muscle-against-muscle contacts left out (`bench/bullet_peer.hpp`). One "
              "Bullet step per frame, from the same converged frame 0; its distance is to our converged stream. With "
              "each bone's surface mesh as a kinematic collider a Bullet step takes tens of seconds on this scene (its "
              "soft body meets a mesh triangle by triangle; tried once on 2026-11-26 with its distance-field voxel at our "
              "particle radius, one frame did not end within 80 s), so that variant plays only the gait's first frames, and the full-gait "
              "points have no bone colliders: they do less work per frame than ours.", ""]
    lines += peer_lines(points) + peer_cost_lines(points) + [""]
    lines += ["### Does the error fall with cost and with resolution?", ""]
    lines += curve_lines(points) + trend_lines(points) + [""]
    table, mixed_model = per_muscle_lines(rows)
    if table:
        lines += ["### Resolution per muscle", "",
                  "From the converged streams, each muscle's surface error to the finest model at its worst checked "
                  "frame, per measured resolution; the mixed model takes for each muscle the coarsest resolution "
                  "(fewest particles; of two as large, the closer) whose error stays within the worst muscle's error "
                  "of uniform 20 x 64 less 1 % (measured in the same run as every other model), finer than 20 x 64 "
                  "where that one is not within it: without the margin the muscle that sets the target keeps it "
                  "exactly, and its coarser neighbours moved it 0.007 mm past (2026-11-28).", ""]
        lines += per_muscle_verdict(rows, mixed_model) + [""] + table + [""]
    lines += ["### The references", "",
              "How converged each model's references are: the block-descent force residual (relative; it stops "
              "falling near 0.01-0.05 where contacts hold particles) and how far the answer moves when given as many "
              "sweeps again.", ""]
    lines += reference_lines(points) + [""]
    lines += ["### Every configuration", ""] + every_configuration_lines(points) + [""]
    return lines
