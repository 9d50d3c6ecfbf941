#!/usr/bin/env python3
"""make demo: the bundled 1-cycle gait through the node, headless.

Starts a virtual X server (Xvfb) and launch/gait_playback.launch with rviz on its own ROS master port, records every
~stats message into <out>/stats.csv (one row per frame) and its per-muscle figures into <out>/muscles.csv (one row per
frame and muscle), pauses the bag at mid-stance to take <out>/rviz.png, then writes the per-muscle fidelity table
<out>/muscles.md and the plot of volume error over the gait <out>/volume_error.png, and prints a summary.
Exit status 0 only if every pose of the bag was solved and no frame had non-finite positions.
Run from a shell where the workspace's devel/setup.bash is sourced (the Makefile does it)."""
import argparse
import csv
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import time


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_display():
    for number in range(99, 140):
        if not os.path.exists(f"/tmp/.X11-unix/X{number}") and not os.path.exists(f"/tmp/.X{number}-lock"):
            return number
    raise RuntimeError("no free X display number between 99 and 139")


def stop(process, name):
    """Ends a process this script started (by its id), politely first."""
    if process is None or process.poll() is not None:
        return
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=20)
    except subprocess.TimeoutExpired:
        print(f"demo: {name} did not stop on SIGINT, terminating it")
        process.terminate()
        process.wait(timeout=10)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="out/demo")
    parser.add_argument("--bag", default="", help="default: the bundled gait_1cycle.bag")
    parser.add_argument("--rate", type=float, default=0.01,
                        help="playback speed; slower than real time so the 2-core machine solves every pose while "
                             "rviz renders in software (the real-time factor comes from the measured solve times)")
    parser.add_argument("--mid-stance", type=float, default=0.2,
                        help="screenshot time as a fraction of the bag's duration (gait cycle from heel strike)")
    parser.add_argument("--rviz-frame-rate", type=int, default=5,
                        help="rviz redraws per second. rviz renders in software here (Xvfb, llvmpipe) and at its usual "
                             "30 fps takes more than a core of this 2-core machine, which the solver then waits for; "
                             "at 0.01x playback a pose stays on screen for 1.7 s, so 5 fps still shows every one")
    parser.add_argument("--timeout", type=float, default=600)
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)

    port = free_port()
    display = free_display()
    env = dict(os.environ, ROS_MASTER_URI=f"http://127.0.0.1:{port}", DISPLAY=f":{display}")
    os.environ.update(ROS_MASTER_URI=env["ROS_MASTER_URI"], DISPLAY=env["DISPLAY"])
    import rosbag  # noqa: E402 (after the environment is set)
    import rospkg

    bag_path = args.bag or os.path.join(rospkg.RosPack().get_path("muscle_deformation"), "data/bags/gait_1cycle.bag")
    with rosbag.Bag(bag_path) as bag:
        stamps = [m.header.stamp.to_sec() for _, m, _ in bag.read_messages(topics=["/joint_states"])]
    if not stamps:
        print(f"demo: {bag_path} has no /joint_states messages")
        return 1
    screenshot_stamp = stamps[0] + args.mid_stance * (stamps[-1] - stamps[0])
    bag_rate_hz = (len(stamps) - 1) / (stamps[-1] - stamps[0])

    rviz_config = os.path.join(args.out, "demo.rviz")
    with open(os.path.join(rospkg.RosPack().get_path("muscle_deformation"), "config/muscle_deformation.rviz")) as source:
        text = source.read()
    text, replaced = re.subn(r"Frame Rate: \d+", f"Frame Rate: {args.rviz_frame_rate}", text)
    if not replaced:
        print("demo: config/muscle_deformation.rviz sets no 'Frame Rate'; rviz runs at its own rate")
    with open(rviz_config, "w") as copy:
        copy.write(text)

    xvfb = launch = None
    log = open(os.path.join(args.out, "roslaunch.log"), "w")
    try:
        xvfb = subprocess.Popen(["Xvfb", f":{display}", "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.5)
        launch = subprocess.Popen(
            ["roslaunch", "-p", str(port), "muscle_deformation", "gait_playback.launch", f"rate:={args.rate}",
             "rviz:=true", f"rviz_config:={os.path.abspath(rviz_config)}", "delay:=1", "paused:=true", f"bag:={bag_path}"],
            env=env, stdout=log, stderr=subprocess.STDOUT)
        return record(args, stamps, screenshot_stamp, bag_rate_hz, launch)
    finally:
        stop(launch, "roslaunch")
        stop(xvfb, "Xvfb")
        log.close()


def record(args, stamps, screenshot_stamp, bag_rate_hz, launch):
    import rospy
    from muscle_deformation.msg import DeformationStats
    from std_srvs.srv import SetBool

    deadline = time.time() + 60
    while True:  # wait for the master roslaunch starts
        try:
            rospy.init_node("demo_recorder", anonymous=True, disable_signals=True)
            break
        except Exception:  # master not up yet
            if time.time() > deadline or launch.poll() is not None:
                print("demo: roslaunch did not start a master; see out/demo/roslaunch.log")
                return 1
            time.sleep(1)

    # The bag starts paused: resume it once the node has built its model (its service appears then).
    try:
        rospy.wait_for_service("/muscle_deformation/deform_pose", timeout=600)
        rospy.wait_for_service("/player/pause_playback", timeout=60)
    except rospy.ROSException:
        print("demo: the node or the bag player did not come up; see out/demo/roslaunch.log")
        return 1
    frames = []
    # Scalars go to stats.csv, one column each; the per-muscle arrays (muscle_*) to muscles.csv.
    list_fields = [f for f, kind in zip(DeformationStats.__slots__, DeformationStats._slot_types) if kind.endswith("[]")]
    fields = [f for f in DeformationStats.__slots__ if f != "header" and f not in list_fields]

    def on_stats(message):
        frames.append(message)

    rospy.Subscriber("/muscle_deformation/stats", DeformationStats, on_stats, queue_size=1000)
    time.sleep(2)  # subscriptions connect
    rospy.ServiceProxy("/player/pause_playback", SetBool)(False)
    # One attempt: each pauses the bag for seconds, so retrying while rviz is gone (it can die at start-up under software
    # GL) held the bag nearly still until the timeout and left most poses unplayed.
    shot_taken = shot_attempted = False
    start = time.time()
    last_change, last_count = time.time(), 0
    while time.time() - start < args.timeout:
        time.sleep(0.2)
        if launch.poll() is not None:
            print("demo: roslaunch ended early; see out/demo/roslaunch.log")
            break
        if len(frames) != last_count:
            last_count, last_change = len(frames), time.time()
        if not shot_attempted and frames and frames[-1].header.stamp.to_sec() >= screenshot_stamp:
            shot_attempted = True
            shot_taken = take_screenshot(args.out, SetBool)
        done = frames and frames[-1].poses_received >= len(stamps)
        if done and time.time() - last_change > 5:
            break
    rospy.signal_shutdown("demo finished")

    with open(os.path.join(args.out, "stats.csv"), "w", newline="") as out:
        writer = csv.writer(out)
        writer.writerow(["stamp_s"] + fields)
        for frame in frames:
            writer.writerow([f"{frame.header.stamp.to_sec():.6f}"] + [getattr(frame, f) for f in fields])
    per_muscle = [f for f in list_fields if f != "muscle_names"]
    with open(os.path.join(args.out, "muscles.csv"), "w", newline="") as out:
        writer = csv.writer(out)
        writer.writerow(["stamp_s", "muscle"] + per_muscle)
        for frame in frames:
            for m, name in enumerate(frame.muscle_names):
                writer.writerow([f"{frame.header.stamp.to_sec():.6f}", name] + [getattr(frame, f)[m] for f in per_muscle])
    # The node refines an unfinished frame while the bag pauses between poses (played slowly here) and publishes some
    # of the refinements (`refined`, in stats.csv): the figures below are of the frames that solved a new pose, as a
    # stream at the bag's own rate would show them.
    poses = [f for f in frames if not f.refined]
    write_muscle_table(args.out, poses)
    plot_volume_error(args.out, poses)
    return summarize(args, poses, stamps, bag_rate_hz, shot_taken, len(frames) - len(poses))


def muscle_series(frames):
    """Per muscle (in simulation order), its figures over the frames that measured them: name -> field -> list."""
    series = {}
    for frame in frames:
        for m, name in enumerate(frame.muscle_names):
            figures = series.setdefault(name, {"stamp_s": [], "volume": [], "skinned": [], "surface": [], "particle": []})
            figures["stamp_s"].append(frame.header.stamp.to_sec())
            figures["volume"].append(frame.muscle_volume_error_pct[m])
            figures["skinned"].append(frame.muscle_skinned_volume_error_pct[m])
            figures["surface"].append(frame.muscle_max_surface_inside_bone_m[m])
            figures["particle"].append(frame.muscle_max_particle_inside_bone_m[m])
    return series


def write_muscle_table(out, frames):
    """<out>/muscles.md: per muscle over the gait, its volume error (as shown and as skinned before the volume
    constraint) and how deep its surface and its particles went into a bone."""
    series = muscle_series(frames)
    path = os.path.join(out, "muscles.md")
    with open(path, "w") as table:
        if not series:
            table.write("No frame measured the per-muscle figures (see the stats' surface_metrics_absent_reason).\n")
            return
        measured = sum(1 for f in frames if f.muscle_names)
        table.write(f"Per-muscle fidelity over the gait ({measured} of {len(frames)} frames measured). Volume error: "
                    "|volume - rest volume| / rest volume of the surface shown; *skinned*: of the skinned surface before "
                    "the volume constraint restored it. Depths: deepest surface vertex / particle inside a bone (its "
                    "distance field).\n\n")
        table.write("| muscle | volume error mean / max % | skinned mean / max % | surface in bone max mm | "
                    "particle in bone max mm |\n|---|---|---|---|---|\n")
        for name, figures in series.items():
            volume = [abs(v) for v in figures["volume"]]
            skinned = [abs(v) for v in figures["skinned"]]
            table.write(f"| {name} | {statistics.mean(volume):.2f} / {max(volume):.2f} | "
                        f"{statistics.mean(skinned):.2f} / {max(skinned):.2f} | {1000 * max(figures['surface']):.2f} | "
                        f"{1000 * max(figures['particle']):.2f} |\n")


def plot_volume_error(out, frames):
    """<out>/volume_error.png: each muscle's signed volume error over the gait, as skinned (thin) and as shown."""
    series = muscle_series(frames)
    if not series:
        return
    import matplotlib
    matplotlib.use("Agg")  # no display needed
    import matplotlib.pyplot as plt
    start = min(min(f["stamp_s"]) for f in series.values())
    figure, (shown, skinned) = plt.subplots(1, 2, figsize=(13, 5), sharex=True)
    colours = plt.get_cmap("tab20", len(series))
    for i, (name, figures) in enumerate(series.items()):
        time_s = [t - start for t in figures["stamp_s"]]
        shown.plot(time_s, figures["volume"], color=colours(i), linewidth=1)
        skinned.plot(time_s, figures["skinned"], color=colours(i), linewidth=1, label=name)
    shown.set_title("surface shown (volume constraint on)")
    skinned.set_title("skinned surface before the volume constraint")
    for axes in (shown, skinned):
        axes.set_xlabel("gait time (s)")
        axes.set_ylabel("volume error (%)")
        axes.axhline(0, color="black", linewidth=0.5)
        axes.grid(alpha=0.3)
    skinned.legend(fontsize=6, ncol=2, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    figure.suptitle("Per-muscle volume error over the bundled gait (make demo)")
    figure.tight_layout()
    figure.savefig(os.path.join(out, "volume_error.png"), dpi=110)
    plt.close(figure)


def take_screenshot(out, SetBool):
    import rospy
    pause = rospy.ServiceProxy("/player/pause_playback", SetBool)
    try:
        pause(True)
    except rospy.ServiceException as error:
        print(f"demo: could not pause the bag ({error}); screenshot taken while playing")
    time.sleep(6)  # rviz (software rendering) shows the newest frame
    path = os.path.join(out, "rviz.png")
    if os.path.exists(path):
        os.remove(path)  # never report an earlier run's picture as this one's
    # rviz under software GL can die at start-up; a screenshot of the empty display would look like success.
    if rviz_window_shown():
        subprocess.run(["import", "-window", "root", path], check=False)
    else:
        print("demo: no rviz window on the virtual display (rviz ended; see out/demo/roslaunch.log): no screenshot")
    try:
        pause(False)
    except rospy.ServiceException:
        pass
    return os.path.exists(path)


def rviz_window_shown():
    tree = subprocess.run(["xwininfo", "-root", "-tree"], capture_output=True, text=True, check=False).stdout
    return "rviz" in tree.lower()


def summarize(args, frames, stamps, bag_rate_hz, shot_taken, refined_published):
    if not frames:
        print("demo: no frame was solved (is the node running? see out/demo/roslaunch.log)")
        return 1
    last = frames[-1]
    solve = [f.solve_ms for f in frames]
    total = [f.total_ms for f in frames]
    finite = all(f.finite for f in frames)
    metrics = [f for f in frames if f.has_surface_metrics]
    frame_period_ms = 1000.0 / bag_rate_hz
    print("== muscle_deformation demo: bundled 1-cycle gait")
    print(f"poses in the bag           {len(stamps)} ({bag_rate_hz:.1f} Hz), played at rate {args.rate}; rviz at "
          f"{args.rviz_frame_rate} fps")
    print(f"frames received / solved   {last.poses_received} / {last.poses_solved} "
          f"(dropped {last.poses_dropped}, unchanged {last.poses_unchanged}, tf failures {last.tf_failures})")
    converged = sum(1 for f in frames if f.converged)
    print(f"refined between poses      {last.poses_refined} refinement solves ({refined_published} published); "
          f"{converged} of {len(frames)} pose frames met the residual criterion within their own budget")
    print(f"solve (whole, prepared)    median {statistics.median(solve):.1f} ms, max {max(solve):.1f} ms, "
          f"iterations {statistics.median([f.iterations for f in frames]):.0f}")
    print(f"frame total (+ surfaces)   median {statistics.median(total):.1f} ms, max {max(total):.1f} ms")
    print(f"real-time factor           {frame_period_ms / statistics.median(solve):.2f} (solve only), "
          f"{frame_period_ms / statistics.median(total):.2f} (with surfaces and metrics); "
          f"1.0 = keeps up with {bag_rate_hz:.0f} Hz")
    # A figure the node did not measure is flagged and NaN in the stats, never 0: report it as absent, with why.
    if metrics:
        print(f"volume error               mean {statistics.mean(f.volume_error_mean_pct for f in metrics):.2f} %, "
              f"max {max(f.volume_error_max_pct for f in metrics):.2f} % ({len(metrics)} of {len(frames)} frames)")
        skinned = [[abs(v) for v in f.muscle_skinned_volume_error_pct] for f in metrics if f.muscle_skinned_volume_error_pct]
        if skinned:
            print(f"  skinned, before the volume constraint: mean {statistics.mean(statistics.mean(v) for v in skinned):.2f} %, "
                  f"max {max(max(v) for v in skinned):.2f} %")
        offsets = [f for f in metrics if f.muscle_projection_offset_max_m]
        if offsets:
            print(f"  vertices the constraint moved: mean {1000 * statistics.mean(statistics.mean(f.muscle_projection_offset_mean_m) for f in offsets):.3f} mm, "
                  f"max {1000 * max(max(f.muscle_projection_offset_max_m) for f in offsets):.2f} mm")
        deepest = max(metrics, key=lambda f: f.max_surface_inside_bone_m)
        print(f"surface inside bone        max {1000 * deepest.max_surface_inside_bone_m:.2f} mm"
              + (f" ({deepest.max_surface_inside_bone_muscle} in {deepest.max_surface_inside_bone_bone})"
                 if deepest.max_surface_inside_bone_muscle else ""))
        deepest = max(metrics, key=lambda f: f.max_particle_inside_bone_m)
        print(f"particles inside bone      max {1000 * deepest.max_particle_inside_bone_m:.2f} mm"
              + (f" ({deepest.max_particle_inside_bone_muscle} in {deepest.max_particle_inside_bone_bone})"
                 if deepest.max_particle_inside_bone_muscle else "") + " (bone fields)")
    else:
        print(f"volume error               not measured ({last.surface_metrics_absent_reason})")
    collided = [f for f in frames if f.has_collision_metrics]
    if collided:
        print(f"max sphere penetration     bone {1000 * max(f.max_penetration_sphere_bone_m for f in collided):.2f} mm, "
              f"muscle {1000 * max(f.max_penetration_sphere_muscle_m for f in collided):.2f} mm")
    else:
        print(f"max sphere penetration     not measured ({last.collision_absent_reason})")
    print(f"outputs                    {args.out}/stats.csv, muscles.csv, muscles.md, volume_error.png, rviz.png "
          f"({'taken' if shot_taken else 'MISSING'})")
    ok = finite and last.poses_solved == len(stamps) and last.poses_received == len(stamps)
    print("demo: OK, every frame solved without NaN" if ok else
          f"demo: FAILED (finite: {finite}, solved {last.poses_solved} of {len(stamps)})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
