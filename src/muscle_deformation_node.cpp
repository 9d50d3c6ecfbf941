// muscle_deformation_node: constructs the node and spins. Everything else is in src/node/.
#include "muscle_deformation/node/muscle_deformation_node.hpp"

#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "muscle_deformation");
  // Held outside the try: ROS shuts down, and stops logging, when its last NodeHandle goes, so a node that fails to
  // construct must not take the handles with it before its error is logged.
  ros::NodeHandle node_handle, private_node_handle("~");
  try {
    muscle_deformation::node::MuscleDeformationNode node(node_handle, private_node_handle);
    ros::spin();  // joint states and diagnostics; the service has a spinner of its own
  } catch (const std::exception& e) {
    ROS_FATAL_STREAM("muscle_deformation: " << e.what());
    return 1;
  }
  return 0;
}
