#!/usr/bin/env python3
"""Specifications of the committed gait bags: message counts, topic, type, joint names and rate.

Run from anywhere with the system interpreter (Debian's rosbag module lives there):
    PYENV_VERSION=system /usr/bin/python3 test/bags_test.py
Exits non-zero on any failure.
"""

import os
import sys
import unittest
import xml.etree.ElementTree as ET

import rosbag

PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
URDF = os.path.join(PACKAGE, "urdf", "right_hip_thigh.urdf")
BAGS = {"gait_1cycle.bag": 73, "gait_3cycles.bag": 211}
RATE_HZ = 60.0


def movable_joints(urdf_path):
    """Names of the joints a pose sets, in document order (the order of JointState.name): neither fixed nor
    mimicking another joint (robot_state_publisher derives those)."""
    root = ET.parse(urdf_path).getroot()
    return [j.get("name") for j in root.findall("joint") if j.get("type") != "fixed" and j.find("mimic") is None]


class GaitBags(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.joints = movable_joints(URDF)
        cls.messages = {}
        for name in BAGS:
            with rosbag.Bag(os.path.join(PACKAGE, "data", "bags", name)) as bag:
                info = bag.get_type_and_topic_info()
                cls.messages[name] = (info, [(topic, msg, t) for topic, msg, t in bag.read_messages()])

    def test_urdf_has_the_gait2392_joints(self):
        self.assertEqual(len(self.joints), 12)
        for name in ("pelvis_tilt", "hip_flexion_r", "knee_angle_r", "knee_tx_r", "knee_ty_r"):
            self.assertIn(name, self.joints)

    def test_each_bag_has_the_expected_number_of_messages(self):
        for name, count in BAGS.items():
            with self.subTest(bag=name):
                self.assertEqual(len(self.messages[name][1]), count)

    def test_every_message_is_a_joint_state_on_joint_states(self):
        for name in BAGS:
            with self.subTest(bag=name):
                info, messages = self.messages[name]
                self.assertEqual(set(info.topics), {"/joint_states"})
                self.assertEqual(info.topics["/joint_states"].msg_type, "sensor_msgs/JointState")
                self.assertTrue(all(topic == "/joint_states" for topic, _, _ in messages))

    def test_joint_names_are_the_urdf_movable_joints_in_order(self):
        for name in BAGS:
            with self.subTest(bag=name):
                for _, msg, _ in self.messages[name][1]:
                    self.assertEqual(list(msg.name), self.joints)
                    self.assertEqual(len(msg.position), len(self.joints))
                    self.assertTrue(all(abs(p) < 10 for p in msg.position), "radians and metres expected")

    def test_messages_come_at_60_hz(self):
        for name in BAGS:
            with self.subTest(bag=name):
                stamps = [msg.header.stamp.to_sec() for _, msg, _ in self.messages[name][1]]
                steps = [b - a for a, b in zip(stamps, stamps[1:])]
                self.assertTrue(all(abs(s - 1.0 / RATE_HZ) < 1e-6 for s in steps),
                                "header stamp steps %.6f..%.6f s" % (min(steps), max(steps)))
                record = [t.to_sec() for _, _, t in self.messages[name][1]]
                self.assertAlmostEqual((record[-1] - record[0]) / (len(record) - 1), 1.0 / RATE_HZ, places=6)


if __name__ == "__main__":
    result = unittest.main(argv=[sys.argv[0], "-v"] + sys.argv[1:], exit=False).result
    sys.exit(0 if result.wasSuccessful() else 1)
