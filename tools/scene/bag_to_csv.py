#!/usr/bin/env python3
"""Write the joint positions of a gait bag (sensor_msgs/JointState on /joint_states) as a CSV table, so that
ROS-free programs (benchmarks, core tests) can replay the same gait without rosbag.

  PYENV_VERSION=system /usr/bin/python3 tools/scene/bag_to_csv.py data/bags/gait_1cycle.bag data/gait/gait_1cycle.csv

Columns: time_s (header stamp, seconds), then one column per joint in the order of the first message (radians for
revolute joints, metres for prismatic ones). Every message must carry the same joints.
"""

import argparse
import sys

import rosbag


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("bag")
    parser.add_argument("csv")
    parser.add_argument("--topic", default="/joint_states")
    args = parser.parse_args()

    names = None
    rows = []
    with rosbag.Bag(args.bag) as bag:
        for _, message, _ in bag.read_messages(topics=[args.topic]):
            if names is None:
                names = list(message.name)
            elif list(message.name) != names:
                sys.exit("%s: message at %.3f s has joints %s, the first had %s"
                         % (args.bag, message.header.stamp.to_sec(), list(message.name), names))
            rows.append([message.header.stamp.to_sec()] + list(message.position))
    if names is None:
        sys.exit("%s: no messages on %s" % (args.bag, args.topic))
    with open(args.csv, "w") as out:
        out.write("# joint positions of %s (%s), written by tools/scene/bag_to_csv.py\n" % (args.bag, args.topic))
        out.write(",".join(["time_s"] + names) + "\n")
        for row in rows:
            out.write(",".join("%.9g" % value for value in row) + "\n")


if __name__ == "__main__":
    main()
