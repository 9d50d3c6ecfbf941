#!/usr/bin/env python3
"""The node, started with a broken parameter, must exit non-zero and say which parameter and why (rostest gives
the master; the node binary runs as a subprocess so its exit code and output can be checked)."""

import os
import re
import subprocess
import tempfile
import unittest

import rosunit
import rospkg
from catkin.find_in_workspaces import find_in_workspaces

PACKAGE = "muscle_deformation"


def node_binary():
    """The node in the catkin workspace this test runs from (its devel space's lib dir)."""
    found = find_in_workspaces(project=PACKAGE, path="muscle_deformation_node", first_match_only=True)
    if not found:
        raise RuntimeError("muscle_deformation_node not found in the catkin workspaces")
    return found[0]


class BadParameters(unittest.TestCase):
    def run_node(self, *parameters):
        name = "bad_parameters_node"
        subprocess.run(["rosparam", "delete", "/" + name], capture_output=True)
        result = subprocess.run([node_binary(), "__name:=" + name] + list(parameters), capture_output=True, text=True,
                                timeout=60)
        return result.returncode, result.stdout + result.stderr

    def test_out_of_range_value_names_the_parameter_and_range(self):
        code, output = self.run_node("_max_iterations:=-5")
        self.assertNotEqual(code, 0)
        self.assertIn("parameter /bad_parameters_node/max_iterations is -5, must be in [1, 1000000]", output)

    def test_unknown_solver_names_the_accepted_ones(self):
        code, output = self.run_node("_service_solver:=euler")
        self.assertNotEqual(code, 0)
        # The service's solver is read through the settings table, as every other choice is.
        self.assertIn("parameter /bad_parameters_node/service_solver 'euler' is not one of: verlet, local_global, "
                      "block_descent, newton_krylov", output)

    def test_conflicting_solver_options_are_refused(self):
        code, output = self.run_node("_solver:=local_global", "_lbfgs_history:=4", "_chebyshev_rho:=0.5")
        self.assertNotEqual(code, 0)
        self.assertIn("lbfgs_history and chebyshev_rho exclude each other", output)

    def test_non_integer_value_for_an_integer_parameter_is_refused_not_rounded(self):
        code, output = self.run_node("_max_iterations:=30.5")
        self.assertNotEqual(code, 0)
        self.assertIn("parameter /bad_parameters_node/max_iterations is 30.500000, must be an integer", output)

    def test_a_replaced_parameter_names_its_successors(self):
        code, output = self.run_node("_reset_translation_m:=0.05")
        self.assertNotEqual(code, 0)
        self.assertIn("reset_translation_m no longer exists", output)
        self.assertIn("max_bone_speed_m_per_s", output)

    def test_links_the_scene_needs_that_robot_description_lacks_are_all_named(self):
        # The bundled skeleton without its patella: the quadriceps' insertion bone is missing.
        package = rospkg.RosPack().get_path(PACKAGE)
        with open(os.path.join(package, "urdf", "right_hip_thigh.urdf")) as handle:
            urdf = handle.read()
        urdf = re.sub(r'<joint name="patella_slide_r"[\s\S]*?</joint>|<link name="patella_r">[\s\S]*?</link>', "", urdf)
        self.assertNotIn('name="patella_r"', urdf)
        with tempfile.NamedTemporaryFile("w", suffix=".urdf", delete=False) as handle:
            handle.write(urdf)
        try:
            subprocess.run(["rosparam", "set", "-t", handle.name, "/robot_description"], check=True)
            code, output = self.run_node()
        finally:
            subprocess.run(["rosparam", "delete", "/robot_description"], capture_output=True)
            os.remove(handle.name)
        self.assertNotEqual(code, 0)
        self.assertIn("the URDF (/robot_description) has no link 'patella_r'", output)
        self.assertIn("muscle 'rectus_femoris' names 'patella_r'", output)
        # Before failing, the node compares robot_description with the URDF the scene names and says how they differ.
        self.assertIn("was made for another skeleton than /robot_description", output)
        self.assertIn("right_hip_thigh.urdf has 'patella_r'", output)

    def test_a_fixed_frame_that_is_not_where_the_scene_frame_is_at_rest_is_refused(self):
        # The bundled scene is given in the pelvis frame; the femur's frame sits at the hip centre.
        package = rospkg.RosPack().get_path(PACKAGE)
        subprocess.run(["rosparam", "set", "-t", os.path.join(package, "urdf", "right_hip_thigh.urdf"),
                        "/robot_description"], check=True)
        try:
            code, output = self.run_node("_fixed_frame:=femur_r")
        finally:
            subprocess.run(["rosparam", "delete", "/robot_description"], capture_output=True)
        self.assertNotEqual(code, 0)
        self.assertIn("fixed_frame 'femur_r' does not coincide with the scene's frame 'pelvis'", output)
        self.assertIn("set fixed_frame to 'pelvis'", output)


if __name__ == "__main__":
    rosunit.unitrun(PACKAGE, "bad_parameters", BadParameters)
