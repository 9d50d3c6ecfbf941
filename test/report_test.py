#!/usr/bin/env python3
"""Specifications of the benchmark report's arithmetic (tools/accuracy_report.py, tools/bench_report.py): averaging
convergence curves over poses, picking the fastest configuration per error target, judging muscle lengths against
issue 26's target and tabling the motions of the stability bench, on small hand-made inputs.

    PYENV_VERSION=system /usr/bin/python3 test/report_test.py
"""

import os
import pathlib
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))
import accuracy_report  # noqa: E402
import bench_report  # noqa: E402
import realtime_report  # noqa: E402


def point(config, start, pose, iterations, wall_ms, rms_mm, **extra):
    row = {"kind": "curve", "config": config, "solver": "verlet", "layout": "nearest_18", "dt_rule": "fixed",
           "dt_fraction": 0.9, "broad_phase": "octree", "start": start, "pose": pose, "particles_per_fibre": 20,
           "iterations": iterations, "wall_ms": wall_ms, "rms_mm": rms_mm, "spring_deviation": 0.01,
           "volume_error_pct": 1.0, "max_penetration_mm": 0.1 * pose}
    row.update(extra)
    return row


class ConvergenceCurves(unittest.TestCase):
    def test_means_over_poses_and_worst_pose(self):
        points = [point("a", "cold", 0, 10, 10.0, 4.0), point("a", "cold", 1, 10, 20.0, 2.0),
                  point("a", "cold", 0, 20, 20.0, 1.0), point("a", "cold", 1, 20, 40.0, 3.0)]
        curve = accuracy_report.convergence_curves(points)[("a", "cold")]
        self.assertEqual([p["iterations"] for p in curve], [10, 20])
        self.assertAlmostEqual(curve[0]["wall_ms"], 15.0)
        self.assertAlmostEqual(curve[0]["rms_mm"], 3.0)
        self.assertAlmostEqual(curve[0]["rms_max_mm"], 4.0)
        self.assertAlmostEqual(curve[1]["rms_mm"], 2.0)
        self.assertAlmostEqual(curve[1]["max_penetration_mm"], 0.1)

    def test_drops_checkpoints_that_not_every_pose_has(self):
        points = [point("a", "cold", 0, 10, 10.0, 4.0), point("a", "cold", 1, 10, 20.0, 2.0),
                  point("a", "cold", 0, 20, 20.0, 0.5)]
        curve = accuracy_report.convergence_curves(points)[("a", "cold")]
        self.assertEqual([p["iterations"] for p in curve], [10])

    def test_ignores_reference_and_resolution_points(self):
        points = [point("a", "cold", 0, 10, 10.0, 4.0), dict(point("a", "cold", 0, 99, 1.0, 0.0), kind="reference")]
        self.assertEqual(len(accuracy_report.convergence_curves(points)[("a", "cold")]), 1)


class FastestToTarget(unittest.TestCase):
    def setUp(self):
        # "slow" reaches 2 mm at 50 ms, "fast" at 30 ms but never reaches 1 mm; warm runs are separate.
        self.points = [point("slow", "cold", 0, 10, 50.0, 2.0), point("slow", "cold", 0, 40, 200.0, 0.9),
                       point("fast", "cold", 0, 10, 30.0, 1.5), point("fast", "cold", 0, 40, 120.0, 1.2),
                       point("slow", "warm", 0, 5, 5.0, 1.8)]
        self.curves = accuracy_report.convergence_curves(self.points)

    def test_picks_the_first_checkpoint_at_or_below_the_target(self):
        config, reached = accuracy_report.fastest_to_target(self.curves, 2.0, "cold")
        self.assertEqual((config, reached["iterations"], reached["wall_ms"]), ("fast", 10, 30.0))
        config, reached = accuracy_report.fastest_to_target(self.curves, 1.0, "cold")
        self.assertEqual((config, reached["iterations"]), ("slow", 40))

    def test_start_modes_are_separate_and_unreached_targets_say_so(self):
        config, reached = accuracy_report.fastest_to_target(self.curves, 2.0, "warm")
        self.assertEqual((config, reached["wall_ms"]), ("slow", 5.0))
        self.assertIsNone(accuracy_report.fastest_to_target(self.curves, 0.5, "cold"))
        lines, choices, _ = accuracy_report.defaults_table(self.points)
        self.assertIsNone(choices[(1.0, "warm")])
        self.assertEqual(choices[(1.0, "cold")][0], "slow")
        self.assertIn("| 1 mm | cold | `slow` | 40 | 200.0 |", "\n".join(lines))
        self.assertIn("| 1 mm | warm | none reached it |", "\n".join(lines))


class Plots(unittest.TestCase):
    def test_speed_error_section_writes_its_plots(self):
        points = [point("a", start, pose, it, it * 2.0, 8.0 / it) for start in ("cold", "warm") for pose in (0, 1)
                  for it in (1, 2, 4, 8)]
        points += [{"kind": "resolution", "pose": 0, "particles_per_fibre": ppf, "rms_mm": 80.0 / ppf}
                   for ppf in (20, 40, 80)]
        with tempfile.TemporaryDirectory() as directory:
            lines, _ = accuracy_report.speed_error_section(points, pathlib.Path(directory))
            for name in ("speed_vs_error.png", "error_vs_resolution.png"):
                self.assertGreater((pathlib.Path(directory) / name).stat().st_size, 1000, name)
        self.assertTrue(any("| 40 | 2.00 |" in line for line in lines))


def length_row(muscle, r, product_mm, reference_mm, slopes=None, reference_slopes=None):
    row = {"muscle": muscle, "reference": muscle + "_r", "r": r, "converged_r": r, "with_tendon_r": r,
           "range_mm_product": product_mm, "converged_range_mm_product": product_mm, "range_mm_reference": reference_mm,
           "range_ratio": product_mm / reference_mm}
    for joint in bench_report.LENGTH_JOINTS:
        row["mm_per_rad_product_" + joint] = (slopes or {}).get(joint, 0.0)
        row["converged_mm_per_rad_product_" + joint] = (slopes or {}).get(joint, 0.0)
        row["mm_per_rad_reference_" + joint] = (reference_slopes or {}).get(joint, 0.0)
    return row


class LengthTarget(unittest.TestCase):
    def test_a_muscle_meets_it_with_r_excursion_and_every_large_slopes_sign(self):
        row = length_row("a", 0.95, 40.0, 45.0, {"knee_angle_r": -30.0}, {"knee_angle_r": -40.0})
        self.assertEqual(bench_report.length_target_misses(row), [])

    def test_each_missed_part_is_named(self):
        row = length_row("b", 0.85, 20.0, 45.0, {"knee_angle_r": 3.0}, {"knee_angle_r": -40.0})
        misses = bench_report.length_target_misses(row)
        self.assertIn("r 0.85", misses)
        self.assertIn("excursion x0.44", misses)
        self.assertIn("knee_angle_r sign", misses)

    def test_small_references_are_judged_in_millimetres_and_small_slopes_not_at_all(self):
        self.assertEqual(bench_report.length_target_misses(
            length_row("c", 0.95, 7.0, 8.0, {"hip_flexion_r": 1.0}, {"hip_flexion_r": -4.0})), [])
        self.assertEqual(bench_report.length_target_misses(length_row("d", 0.95, 2.0, 8.0)), ["excursion -6.0 mm"])

    def test_the_section_counts_the_muscles_that_meet_it_and_lists_those_without_a_counterpart(self):
        rows = [length_row("a", 0.95, 40.0, 45.0), length_row("b", 0.5, 40.0, 45.0),
                {"muscle": "obturator", "reference": "none", "counterpart": "none in gait2392"}]
        text = "\n".join(bench_report.lengths_section(rows))
        self.assertIn("**1 of 2** muscles meet it streamed", text)
        self.assertIn("No counterpart in gait2392: obturator.", text)


class StabilityMotions(unittest.TestCase):
    def test_motions_get_their_own_table_with_the_gaits_yardstick(self):
        motion = {"case": "gait_1x", "description": "gait", "finite": 1.0, "restarts": 0.0, "strain_p99_median": 0.12,
                  "strain_p99_max": 0.2, "max_strain": 3.0, "max_particle_inside_bone_mm": 0.1,
                  "deepest_particle": "", "particle_volume_error_max_pct": 2.0, "held_poses_until_settled": 4.0,
                  "settled_converged": 1.0}
        still = dict(motion, case="kick", restarts=1.0)
        del still["held_poses_until_settled"]
        text = "\n".join(accuracy_report.stability_section([motion, still]))
        self.assertIn("2 x is 0.240", text)
        self.assertIn("| gait_1x | gait | yes | 0 | 0.120 / 0.200 |", text)
        self.assertIn("| kick | gait | yes | 1 |", text)
        self.assertIn("still refining", text)
        self.assertNotIn("| case | what | recoveries", text)



class RooflineTest(unittest.TestCase):
    def _row(self, **extra):
        row = {"scene": "all_26", "mode": "stream", "solver": "block_descent", "configuration": "node default",
               "threads": 0, "iterations": 1.0, "frame_ms_median": 20.0, "frame_ms_max": 30.0, "rms_mm_mean": 0.5,
               "rms_mm_max": 1.0, "bone_penetration_max_mm": 0.0, "residual_median": 0.3, "node_default": 1,
               "particles": 1000}
        row.update(extra)
        return row

    def test_the_floor_names_the_machine_and_judges_the_default_sweep(self):
        row = self._row(sweep_ms=10.0, sweep_bytes=20e6, sweep_flops=30e6, bandwidth_gbs=16.0, gflops=20.0,
                        floor_threads=2, roofline_ratio=6.0)
        text = "\n".join(realtime_report.floor_lines([row]))
        self.assertIn("on 2 threads 16.0 GB/s and 20.0 Gflop/s", text)
        self.assertIn("20.0 MB", text)
        self.assertIn("6.0x its floor; target <= 2.5x, missed by 2.4x", text)

    def test_rows_without_a_sweep_measure_say_nothing(self):
        self.assertEqual(realtime_report.floor_lines([self._row()]), [])


class SectionReplacementTest(unittest.TestCase):
    def test_a_section_is_replaced_in_place_and_a_new_one_appended(self):
        old = "# Benchmarks\n\nMachine: m.\n\n## A\n\nold a\n\n## B\n\nold b\n"
        text = bench_report.replace_sections(old, [["## B", "", "new b", ""], ["## C", "", "new c", ""]],
                                             "Regenerated separately: B, C.")
        self.assertLess(text.index("## A"), text.index("new b"))
        self.assertLess(text.index("new b"), text.index("## C"))
        self.assertNotIn("old b", text)
        self.assertIn("old a", text)
        self.assertIn("Regenerated separately: B, C.", text.split("## A")[0])

    def test_a_second_partial_run_replaces_the_first_note(self):
        first = bench_report.replace_sections("# B\n\n## A\n\na\n", [["## A", "", "a1"]], "Regenerated separately: 1")
        second = bench_report.replace_sections(first, [["## A", "", "a2"]], "Regenerated separately: 2")
        self.assertNotIn("separately: 1", second)
        self.assertEqual(second.count("## A"), 1)

if __name__ == "__main__":
    unittest.main()
