#!/usr/bin/env python3
"""prepare_scene end to end, as a user runs it: the small synthetic hip of test/data/prepare_scene (bone meshes in
millimetres, the femur's with a hole), a muscle segmented in millimetres with the defects segmentations have (a
non-manifold edge, degenerate and duplicated triangles) and a muscle that cannot be repaired. The tool must prepare the
first, refuse the second saying why, and write a scene directory whose paths are relative to it. Runs in seconds."""
import json
import math
import os
import shutil
import subprocess
import tempfile
import unittest

PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.environ.get("PREPARE_SCENE", os.path.join(PACKAGE, ".ws", "devel", "lib", "muscle_deformation",
                                                   "prepare_scene"))
GENERATE_FIBRES = os.path.join(os.path.dirname(TOOL), "generate_fibres")  # built beside it


def write_obj(path, vertices, triangles):
    with open(path, "w") as out:
        for v in vertices:
            out.write("v %.6f %.6f %.6f\n" % tuple(v))
        for t in triangles:
            out.write("f %d %d %d\n" % tuple(i + 1 for i in t))


def ellipsoid(centre, radii, rings=24, segments=32):
    """Closed UV ellipsoid, outward winding: poles along z."""
    vertices = [(centre[0], centre[1], centre[2] - radii[2])]
    for r in range(1, rings):
        polar = math.pi * r / rings
        for s in range(segments):
            azimuth = 2 * math.pi * s / segments
            vertices.append((centre[0] + radii[0] * math.sin(polar) * math.cos(azimuth),
                             centre[1] + radii[1] * math.sin(polar) * math.sin(azimuth),
                             centre[2] - radii[2] * math.cos(polar)))
    vertices.append((centre[0], centre[1], centre[2] + radii[2]))
    top = len(vertices) - 1

    def at(ring, s):
        return 1 + ring * segments + s % segments

    triangles = [(0, at(0, s + 1), at(0, s)) for s in range(segments)]
    for r in range(rings - 2):
        for s in range(segments):
            triangles += [(at(r, s), at(r, s + 1), at(r + 1, s + 1)), (at(r, s), at(r + 1, s + 1), at(r + 1, s))]
    triangles += [(top, at(rings - 2, s), at(rings - 2, s + 1)) for s in range(segments)]
    return vertices, triangles


SMALL_HIP = os.path.join(PACKAGE, "test", "data", "prepare_scene", "small_hip.urdf")


class PrepareSceneEndToEnd(unittest.TestCase):
    def setUp(self):
        self.raw = tempfile.mkdtemp(prefix="md_prepare_scene_")
        self.out = os.path.join(self.raw, "my scene")  # a space: paths are quoted
        vertices, triangles = ellipsoid((0, 0, 50), (12, 12, 50))
        a, b = triangles[40][0], triangles[40][1]
        vertices.append(tuple(1.3 * c for c in vertices[a]))  # the tip of a fin on edge a-b: a non-manifold edge
        triangles += [(a, b, len(vertices) - 1), (a, a, b), (b, b, a), triangles[70]]  # 2 degenerate, 1 duplicated
        write_obj(os.path.join(self.raw, "belly_mm.obj"), vertices, triangles)
        shutil.copy(os.path.join(PACKAGE, "test", "data", "nonmanifold.obj"), os.path.join(self.raw, "broken.obj"))

    def tearDown(self):
        shutil.rmtree(self.raw)

    def prepare(self, *muscles, options=()):
        command = [TOOL, "--urdf", SMALL_HIP, "--package-dir", PACKAGE, "--out", self.out, "--scale", "0.001",
                   "--fibres", "16", "--min-voxels", "20000"] + list(options)
        for muscle in muscles:
            command += ["--muscle", muscle]
        return subprocess.run(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True,
                              timeout=120)

    def read(self, name):
        with open(os.path.join(self.out, name)) as f:
            return f.read()

    def test_a_defective_muscle_is_repaired_and_one_that_cannot_be_is_refused_after_the_others_are_prepared(self):
        run = self.prepare("broken:%s/broken.obj:pelvis:femur_r" % self.raw,
                           "belly:%s/belly_mm.obj:pelvis:femur_r" % self.raw)
        self.assertEqual(run.returncode, 1, run.stdout + run.stderr)
        self.assertIn("muscle 'broken' NOT prepared", run.stdout)
        self.assertIn("enclose no volume", run.stdout)
        self.assertIn("muscle 'belly': repaired", run.stdout)
        self.assertIn("1 of 2 muscles prepared", run.stdout)
        for name in ("scene.yaml", "report.md", "view.rviz", "meshes/muscles/belly.stl", "fibres/belly.vtk"):
            self.assertTrue(os.path.isfile(os.path.join(self.out, name)), name)
        self.assertFalse(os.path.exists(os.path.join(self.out, "fibres", "broken.vtk")))

        report = self.read("report.md")
        self.assertIn("1 of 2 muscles prepared", report)
        self.assertIn("triangles on non-manifold edges removed: 3", report)
        self.assertIn("degenerate triangles removed: 2", report)
        self.assertIn("duplicate triangles removed: 1", report)
        self.assertIn("**Not prepared**", report)

    def test_the_scene_names_its_files_relative_to_itself_and_a_closed_copy_of_the_bone_with_a_hole(self):
        run = self.prepare("belly:%s/belly_mm.obj:pelvis:femur_r" % self.raw)
        self.assertEqual(run.returncode, 0, run.stdout + run.stderr)
        self.assertIn("bone 'femur_r'", run.stdout)
        scene = self.read("scene.yaml")
        self.assertIn('urdf: "%s"' % os.path.relpath(SMALL_HIP, self.out), scene)
        self.assertIn('frame: "pelvis"', scene)
        self.assertIn('surface: "meshes/muscles/belly.stl"', scene)
        self.assertIn('fibres: "fibres/belly.vtk"', scene)
        self.assertIn('- mesh: "package://muscle_deformation/test/data/prepare_scene/femur_mm.obj"\n'
                      '  surface: "meshes/bones/femur_r_femur_mm.stl"', scene)
        self.assertTrue(os.path.isfile(os.path.join(self.out, "meshes", "bones", "femur_r_femur_mm.stl")))
        self.assertIn("Fixed Frame: pelvis", self.read("view.rviz"))
        self.assertIn("roslaunch muscle_deformation gait_playback.launch scene:=%s/scene.yaml" % self.out, run.stdout)

    def test_a_bad_command_line_is_refused_naming_the_problem(self):
        run = self.prepare("belly_without_links:%s/belly_mm.obj" % self.raw)
        self.assertEqual(run.returncode, 1)
        self.assertIn("is not NAME:MESH:ORIGIN_LINK:INSERTION_LINK", run.stderr)
        self.assertIn("usage: prepare_scene", run.stderr)

    def test_attachment_sites_from_the_command_line_and_from_an_opensim_model_go_into_the_scene(self):
        osim = os.path.join(PACKAGE, "data", "opensim", "gait2392_millard2012muscle.osim")
        run = self.prepare("belly:%s/belly_mm.obj:pelvis@0,0.04,0.115:femur_r" % self.raw,
                           "twin:%s/belly_mm.obj:pelvis:femur_r" % self.raw,
                           options=["--osim", osim, "--osim-muscle", "twin=add_long_r"])
        self.assertEqual(run.returncode, 0, run.stdout + run.stderr)
        self.assertIn("muscle 'belly': repaired", run.stdout)
        self.assertIn("1 attachment site\n", run.stdout)
        # the small hip is not gait2392's skeleton: its sites lie far from the bones, and the tool says so
        self.assertIn("2 attachment sites (2 of them more than 10 mm from their bone", run.stdout)
        scene = self.read("scene.yaml")
        self.assertIn('  origin_path:\n  - {link: "pelvis", point: [0, 0.04, 0.115]}\n  insertion_path: []', scene)
        self.assertIn('  origin_path:\n  - {link: "pelvis", point: [-0.0316, -0.0836, 0.0169]}\n'
                      '  insertion_path:\n  - {link: "femur_r", point: [0.005, -0.2111, 0.0234]}\n'
                      '  reference_muscles: ["add_long_r"]', scene)
        self.assertIn('osim: "%s"' % os.path.relpath(osim, self.out), scene)
        self.assertIn("add_long_r-P2 (add_long_r) on `femur_r`", self.read("report.md"))

    def test_a_surface_error_target_gives_each_muscle_its_resolution_in_the_scene(self):
        run = self.prepare("belly:%s/belly_mm.obj:pelvis:femur_r" % self.raw, options=["--surface-error-mm", "500"])
        self.assertEqual(run.returncode, 0, run.stdout + run.stderr)
        self.assertIn("resolution 80 particles per fibre: 2 poses solved", run.stdout)
        self.assertIn("  particles_per_fibre: 10  # chosen for the surface error target", self.read("scene.yaml"))
        report = self.read("report.md")
        self.assertIn("## Resolution per muscle", report)
        self.assertIn("hip_flexion_r +0.50 rad, hip_flexion_r -0.50 rad", report)

    def test_bad_site_and_overlap_options_are_refused_naming_the_problem(self):
        belly = "belly:%s/belly_mm.obj:pelvis:femur_r" % self.raw
        osim = os.path.join(PACKAGE, "data", "opensim", "gait2392_millard2012muscle.osim")
        for muscles, options, expected in [
                (["belly:%s/belly_mm.obj:pelvis@1,2:femur_r" % self.raw], [], "LINK@x,y,z"),
                ([belly], ["--osim-muscle", "belly=add_long_r"], "--osim-muscle needs --osim"),
                ([belly], ["--osim", osim, "--osim-muscle", "belly"], "is not NAME=OTHER"),
                ([belly], ["--osim", osim, "--osim-muscle", "belly=nothing_r"], "has no muscle 'nothing_r'"),
                ([belly], ["--osim", os.path.join(self.raw, "none.osim")], "none.osim"),
                ([belly], ["--rest-overlaps", "push-out"], "report or carve-bones"),
                ([belly], ["--surface-error-mm", "-1"], "--surface-error-mm")]:
            run = self.prepare(*muscles, options=options)
            self.assertEqual(run.returncode, 1, expected)
            self.assertIn(expected, run.stderr)

    def test_generate_fibres_remakes_a_scenes_fibres_past_a_muscle_that_fails_and_finds_packages_on_its_own(self):
        self.assertEqual(self.prepare("belly:%s/belly_mm.obj:pelvis:femur_r" % self.raw).returncode, 0)
        with open(os.path.join(self.out, "scene.yaml"), "a") as scene:
            scene.write('- name: "lost"\n  surface: "meshes/muscles/nowhere.stl"\n  fibres: "fibres/lost.vtk"\n'
                        '  origin_bone: "pelvis"\n  insertion_bone: "femur_r"\n')
        fibres = os.path.join(self.out, "fibres", "belly.vtk")
        os.remove(fibres)
        report = os.path.join(self.raw, "fibres.json")
        # No --package-dir: the URDF's package:// meshes are found under ROS_PACKAGE_PATH, as rosrun sets it.
        run = subprocess.run([GENERATE_FIBRES, "--scene", os.path.join(self.out, "scene.yaml"), "--fibres", "16",
                              "--min-voxels", "20000", "--report", report], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, universal_newlines=True, timeout=120,
                             env=dict(os.environ, ROS_PACKAGE_PATH=PACKAGE))
        self.assertEqual(run.returncode, 1, run.stdout + run.stderr)
        self.assertIn("muscle 'lost' FAILED", run.stderr)
        self.assertIn("nowhere.stl", run.stderr)
        self.assertTrue(os.path.isfile(fibres))
        with open(report) as f:
            entries = json.load(f)
        self.assertTrue(entries["belly"]["passed"])
        self.assertIn("nowhere.stl", entries["lost"]["error"])


class RosrunOnAFreshCheckout(unittest.TestCase):
    """`rosrun` searches the package's folder with `find -L`: a workspace whose package folder links back to the
    repository that holds the workspace made it print "File system loop detected" on every run."""

    def test_rosrun_runs_the_tool_without_a_word_on_stderr(self):
        if not os.environ.get("ROS_PACKAGE_PATH"):
            self.skipTest("no ROS environment (source the workspace's devel/setup.bash): rosrun cannot find packages")
        rosrun = shutil.which("rosrun")
        self.assertIsNotNone(rosrun, "rosrun is not installed (tools/setup.sh installs it)")
        run = subprocess.run([rosrun, "muscle_deformation", "prepare_scene", "--help"], capture_output=True, text=True,
                             timeout=120)
        self.assertEqual(run.returncode, 0, run.stderr)
        self.assertIn("usage: prepare_scene", run.stdout)
        self.assertEqual(run.stderr, "")


if __name__ == "__main__":
    unittest.main()
