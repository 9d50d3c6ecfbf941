#!/usr/bin/env python3
"""Specifications of the benchmark report's arithmetic (tools/accuracy_report.py): averaging convergence curves over
poses, and picking the fastest configuration per error target, on small hand-made inputs.

    PYENV_VERSION=system /usr/bin/python3 test/report_test.py
"""

import os
import pathlib
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))
import accuracy_report  # noqa: E402


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


if __name__ == "__main__":
    unittest.main()
