"""The real-time section of docs/BENCHMARKS.md from out/bench/realtime.json (bench/realtime_bench.cpp), with a plot of
error against frame time. Every number comes from the JSON; the targets are the real-time issue's."""
import matplotlib

matplotlib.use("Agg")  # headless: make bench runs without a display
import matplotlib.pyplot as plt  # noqa: E402

FRAME_BUDGET_MS = 1000.0 / 60.0
TARGET_MAX_FRAME_MS = 25.0


def _rows(rows, scene, mode):
    return [r for r in rows
            if r["scene"] == scene and r["mode"] == mode and r["solver"] not in ("reference", "agreement", "agreement_frame")]


def _reference(rows, scene, mode):
    return next((r for r in rows if r["scene"] == scene and r["mode"] == mode and r["solver"] == "reference"), None)


def _agreement(rows, scene):
    return next((r for r in rows if r["scene"] == scene and r["solver"] == "agreement"), None)


def _by_label(rows, label):
    return next((r for r in rows if r["configuration"].startswith(label)), None)


def realtime_plot(rows, path):
    panels = (("stream", "rms_mm_mean", "RMS to the reference (mm), mean over frames"),
              ("stream", "residual_median", "residual (relative RMS force), median"),
              ("cold", "rms_mm_mean", "RMS to the reference (mm), mean over poses"))
    figure, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for axis, (mode, key, label) in zip(axes, panels):
        for scene, marker in (("all_26", "o"), ("thigh13", "s")):
            for row in _rows(rows, scene, mode):
                colour = {"verlet": "tab:red", "local_global": "tab:purple"}.get(row["solver"], "tab:blue")
                axis.scatter(row["frame_ms_median"], row[key], marker=marker, color=colour,
                             edgecolor="black" if row["node_default"] else colour, s=60 if row["node_default"] else 30)
                if scene == "all_26":
                    name = row["configuration"].replace("block_descent ", "bd ").replace("node default: ", "default ")
                    axis.annotate(f"{name}, {int(row['threads'])}t", (row["frame_ms_median"], row[key]), fontsize=6,
                                  xytext=(3, 2), textcoords="offset points")
        if mode == "stream":
            axis.axvline(FRAME_BUDGET_MS, color="grey", linestyle="--", linewidth=0.8)
        axis.set_xscale("log")
        if key == "residual_median":
            axis.set_yscale("log")
        axis.set_xlabel("frame time, median (ms, log)")
        axis.set_ylabel(label)
        axis.set_title(mode, fontsize=9)
        axis.grid(True, which="both", alpha=0.3)
    figure.suptitle("circles: all 26 muscles (labelled), squares: thigh13; red Verlet, blue block descent, purple "
                    "local/global; outlined: node default; dashed: 16.7 ms", fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def realtime_section(rows, img_dir, img_link_prefix="img/"):
    realtime_plot(rows, img_dir / "realtime.png")
    lines = ["## Real time (real-time issue)", "",
             "Bundled scene at the node's model and collision settings (20 particles per fibre, 18 nearest-neighbour "
             "springs), `bench/realtime_bench.cpp`, Release. A frame's answer is the equilibrium of the springs, the "
             "contacts and the tissue drag towards where the tissue carries each particle (the previous answer moved "
             "with the bones; cold: the rigid pre-transform), `tissue_relaxation_s` (docs/realtime.md says why). "
             "*stream*: the 1-cycle gait streamed frame by frame as the node does (warm starts), every configuration "
             "starting from the same converged frame 0 and judged against the converged stream, whose frame k "
             "continues its own frame k-1; *cold*: the five paper gait poses, each from its rigid pre-transform. "
             "Frame time = the frame's whole solve, wall clock, on this 2-core shared machine: the pose's preparation (the "
             "tendons' and the belly tone's rest lengths, carrying the particles to the pose, the tissue drag's anchors), "
             "the solver (sweeps, contact search) and the figures and volume pressure after it (the runs up to "
             "2026-11-28 22:00 UTC counted the solver alone: 14.4 of 21.1 ms at the node's defaults when measured both "
             "ways in one run); "
             "`threads` 0 = every core, -1 = one or every core, whichever sweeps faster as measured while it runs. *residual* is one "
             "yardstick for every solver: the RMS net force on the free particles (springs, the block-descent "
             "contact energy and the reference's tissue drag) over the springs' material constant (10 N), median "
             "over frames; configurations without drag solve another problem and are judged by this one. Raw "
             "numbers: `out/bench/realtime.json`.", ""]
    for mode in ("stream", "cold"):
        for scene in ("all_26", "thigh13"):
            reference = _reference(rows, scene, mode)
            table = _rows(rows, scene, mode)
            if not table:
                continue
            lines.append(f"**{scene}, {mode}** ({int(table[0]['particles'])} particles).")
            if reference:
                moved = (f"; the same frame given twice the sweeps from another start ends "
                         f"{reference['reference_moves_mm']:.3f} mm RMS from it" if "reference_moves_mm" in reference
                         else "")
                own = (f" by the yardstick, which leaves out the muscles' volume pressure; by its own solve, with "
                       f"the volume term (what the residual criterion applies to): "
                       f"{reference['reference_own_residual_median']:.1e} median, "
                       f"{reference['reference_own_residual_max']:.1e} max"
                       if reference.get("reference_own_residual_median") is not None else "")
                lines.append(f"Reference: block descent with tissue drag {1e3 * reference['tissue_relaxation_s']:.2g} ms, "
                             f"{int(reference['reference_sweeps'])} sweeps per "
                             f"{'frame from the previous reference frame' if mode == 'stream' else 'pose'}, "
                             f"{int(reference['frames'])} {'frames' if mode == 'stream' else 'poses'}; its residual "
                             f"{reference['reference_residual_median']:.1e} median, "
                             f"{reference['reference_residual_max']:.1e} max{own}{moved}.")
            agreement = _agreement(rows, scene) if mode == "stream" else None
            if agreement:
                frames = [r for r in rows if r["scene"] == scene and r["solver"] == "agreement_frame"]
                per_frame = "; ".join(
                    f"frame {int(r['frame'])}: {int(r['newton_iterations'])} steps, its residual "
                    f"{r['newton_own_residual']:.1e} ({'converged' if r['newton_converged'] else 'not converged'}), "
                    f"{r['newton_rms_mm']:.3f} mm RMS / {r['newton_max_mm']:.2f} mm at the farthest particle"
                    for r in frames)
                lines.append(f"Two solvers, one answer: the Newton-Krylov solver (global Newton steps, conjugate "
                             f"gradients; at most {int(agreement['newton_iterations_cap'])} steps to a residual of "
                             f"1e-3) solving {int(agreement['frames'])} of the frames from the reference's start, "
                             f"{agreement['newton_ms_median']:.0f} ms median per frame ({per_frame}).")
            lines += ["", "| configuration | threads | iterations | frame ms median / max | RMS to reference mm "
                          "mean / max | residual | bone penetration max mm | sweep ms (x its floor) |",
                      "|---|---|---|---|---|---|---|---|"]
            for row in table:
                name = row["configuration"] + (" **(default)**" if row["node_default"] else "")
                sweep = (f"{row['sweep_ms']:.1f} ({row['roofline_ratio']:.1f}x)" if "roofline_ratio" in row
                         else "-")
                lines.append(f"| {name} | {int(row['threads'])} | {row['iterations']:.1f} | "
                             f"{row['frame_ms_median']:.1f} / {row['frame_ms_max']:.1f} | "
                             f"{row['rms_mm_mean']:.2f} / {row['rms_mm_max']:.2f} | {row['residual_median']:.2g} | "
                             f"{row['bone_penetration_max_mm']:.2f} | {sweep} |")
            lines.append("")
    lines += [f"![error against frame time]({img_link_prefix}realtime.png)", ""]
    lines += floor_lines(rows)
    lines += targets_lines(rows)
    return lines


def floor_lines(rows):
    """The machine's floor measured in the run, and how far the node's sweep is from it."""
    swept = [r for r in rows if "roofline_ratio" in r]
    if not swept:
        return []
    machines = {}
    for r in swept:
        machines[int(r["floor_threads"])] = (r["bandwidth_gbs"], r["gflops"])
    measured = "; ".join(f"on {threads} thread{'s' if threads > 1 else ''} {bandwidth:.1f} GB/s and {gflops:.1f} "
                         f"Gflop/s" for threads, (bandwidth, gflops) in sorted(machines.items()))
    lines = ["**The floor.** The run measures the machine (a STREAM-like triad over arrays far beyond the caches, and "
             f"independent multiply-adds, compiled like the solver): {measured}. A sweep must at least stream its "
             "arrays once and do one Newton step per particle (`BlockDescentSolver::sweepCost` counts both from the "
             "data structures); the larger of bytes / bandwidth and flops / rate is its floor, and *x its floor* is "
             "the sweep's median time (its frame's time in the sweeps over their count) over it."]
    default = next((r for r in swept if r["scene"] == "all_26" and r["mode"] == "stream" and r["node_default"]), None)
    if default:
        ratio = default["roofline_ratio"]
        lines.append("")
        lines.append(f"- The node's default stream of all 26 muscles: a sweep moves {default['sweep_bytes'] / 1e6:.1f} "
                     f"MB and does {default['sweep_flops'] / 1e6:.1f} Mflop, {default['sweep_ms']:.1f} ms median, "
                     f"{ratio:.1f}x its floor; target <= 2.5x, "
                     f"{'met' if ratio <= 2.5 else f'missed by {ratio / 2.5:.1f}x'}.")
    lines.append("")
    return lines


def targets_lines(rows):
    """The issue's targets, each with the measured figure and met / missed by how much."""
    lines = ["**Targets** (all 26 muscles unless named):", ""]
    stream = _rows(rows, "all_26", "stream")
    default = next((r for r in stream if r["node_default"]), None)
    verlet = _by_label(stream, "verlet 30 iterations")
    agreement = _agreement(rows, "all_26")
    if agreement:
        converged = int(agreement.get("newton_converged_frames", 0))
        total = int(agreement["frames"])
        if converged:
            rms = agreement["newton_converged_rms_mm_max"]
            lines.append(f"- Two solvers from the same start reach the same converged state within 0.1 mm RMS: on the "
                         f"{converged} of {total} frames where Newton-Krylov met its tolerance, {rms:.3f} mm RMS at most "
                         f"({agreement['newton_converged_max_mm']:.2f} mm at the farthest particle), "
                         f"{'met' if rms <= 0.1 else 'missed'}"
                         + (f"; on the other {total - converged} it stopped at its step cap (RMS "
                            f"{agreement['newton_rms_mm_max']:.3f} mm, {agreement['newton_max_mm']:.2f} mm at the "
                            f"farthest particle)" if converged < total else "") + ".")
        else:
            lines.append(f"- Two solvers from the same start reach the same converged state within 0.1 mm RMS: not "
                         f"shown, Newton-Krylov met its tolerance on none of the {total} frames.")
    if default:
        median, worst = default["frame_ms_median"], default["frame_ms_max"]
        lines.append(f"- Median frame <= 16.7 ms: {median:.1f} ms, "
                     f"{'met' if median <= FRAME_BUDGET_MS else f'missed by {median / FRAME_BUDGET_MS:.2f}x'}; "
                     f"max <= 25 ms: {worst:.1f} ms, "
                     f"{'met' if worst <= TARGET_MAX_FRAME_MS else f'missed by {worst / TARGET_MAX_FRAME_MS:.2f}x'}.")
        lines.append(f"- Within 1 mm RMS of the converged stream on average, 2 mm at worst: "
                     f"{default['rms_mm_mean']:.2f} / {default['rms_mm_max']:.2f} mm, "
                     f"{'met' if default['rms_mm_mean'] <= 1 and default['rms_mm_max'] <= 2 else 'missed'}.")
        if verlet:
            speed = verlet["frame_ms_median"] / median
            closer = verlet["rms_mm_mean"] / default["rms_mm_mean"]
            force = verlet["residual_median"] / default["residual_median"]
            lines.append(f"- At least 7x faster than 30 Verlet iterations in the same run: {speed:.1f}x "
                         f"({'met' if speed >= 7 else 'missed'}); at least 4x closer to the reference: {closer:.2f}x "
                         f"({'met' if closer >= 4 else 'missed'}); {force:.0f}x smaller residual force.")
    cold = _rows(rows, "thigh13", "cold")
    service = next((r for r in cold if r["node_default"]), None)
    if service:
        met = service["rms_mm_max"] <= 1 and service["frame_ms_median"] <= 300
        lines.append(f"- thigh13 cold within 1 mm of its converged state in <= 300 ms: the service default "
                     f"({service['configuration']}) {service['rms_mm_mean']:.2f} mm mean / {service['rms_mm_max']:.2f}"
                     f" mm worst in {service['frame_ms_median']:.0f} ms median, {'met' if met else 'missed'}.")
    penetration = max((r["bone_penetration_max_mm"] for r in stream if r["node_default"]), default=None)
    if penetration is not None:
        lines.append(f"- Sphere penetration into bone during the gait stream at the defaults: {penetration:.2f} mm max "
                     "(the stability table below has the hard cases).")
    lines.append("")
    return lines
