#!/usr/bin/env python3
"""SIGINT ends the node promptly even while a service call is solving without limit (rostest gives the master and
robot_description; the node binary runs as a subprocess so its exit can be timed)."""

import signal
import subprocess
import threading
import time
import unittest

import rospy
import rosunit
from catkin.find_in_workspaces import find_in_workspaces
from muscle_deformation.srv import DeformPose, DeformPoseRequest

PACKAGE = "muscle_deformation"
NAME = "shutdown_node"
# A solve has no bound here but this one (an hour): only the shutdown can end it in time.
MAX_SOLVE_TIME_S = 3600
PROMPT_EXIT_S = 5.0


def node_binary():
    found = find_in_workspaces(project=PACKAGE, path="muscle_deformation_node", first_match_only=True)
    if not found:
        raise RuntimeError("muscle_deformation_node not found in the catkin workspaces")
    return found[0]


class Shutdown(unittest.TestCase):
    def test_sigint_mid_solve_ends_the_node_promptly(self):
        subprocess.run(["rosparam", "delete", "/" + NAME], capture_output=True)
        node = subprocess.Popen([node_binary(), "__name:=" + NAME, "_muscles:=adductor_longus",
                                 "_max_solve_time_s:=%d" % MAX_SOLVE_TIME_S], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        try:
            service = "/%s/deform_pose" % NAME
            started = time.monotonic()
            while True:
                if node.poll() is not None:
                    self.fail("the node exited before its service appeared:\n" + node.stdout.read())
                try:
                    rospy.wait_for_service(service, timeout=1)
                    break
                except rospy.ROSException:
                    self.assertLess(time.monotonic() - started, 120, "the service did not appear within 120 s")
            request = DeformPoseRequest()
            request.joint_state.name = ["hip_flexion_r"]
            request.joint_state.position = [0.5]
            request.max_iterations = 2**31 - 1
            answers = []

            def call():
                try:
                    answers.append(rospy.ServiceProxy(service, DeformPose)(request))
                except Exception as error:  # the connection may close as the node exits
                    answers.append(error)

            caller = threading.Thread(target=call, daemon=True)
            caller.start()
            time.sleep(2.0)  # the solve is under way
            self.assertIsNone(node.poll(), "the node exited before the signal")
            signalled = time.monotonic()
            node.send_signal(signal.SIGINT)
            node.wait(timeout=60)
            exit_s = time.monotonic() - signalled
            self.assertLess(exit_s, PROMPT_EXIT_S, "the node took %.1f s to exit after SIGINT" % exit_s)
            caller.join(timeout=10)
            if answers and not isinstance(answers[0], Exception):
                self.assertFalse(answers[0].success)
                self.assertIn("shutting down", answers[0].message)
        finally:
            if node.poll() is None:
                node.kill()
                node.wait()


if __name__ == "__main__":
    rospy.init_node("shutdown_test", anonymous=True)
    rosunit.unitrun(PACKAGE, "shutdown", Shutdown)
