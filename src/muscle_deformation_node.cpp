// muscle_deformation_node: constructs the node and spins. Everything else is in src/node/.
#include "muscle_deformation/node/muscle_deformation_node.hpp"

#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "muscle_deformation");
  try {
    muscle_deformation::node::MuscleDeformationNode node(ros::NodeHandle(), ros::NodeHandle("~"));
    ros::MultiThreadedSpinner spinner(2);  // the service may solve while joint states keep arriving
    spinner.spin();
  } catch (const std::exception& e) {
    ROS_FATAL_STREAM("muscle_deformation: " << e.what());
    return 1;
  }
  return 0;
}
