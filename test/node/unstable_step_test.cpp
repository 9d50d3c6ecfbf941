// A running muscle_deformation_node given an unstable time step (unstable_step.test): every frame it publishes is
// finite, and it says that it recovered from divergence.
#include "muscle_deformation/core/scene/scene.hpp"

#include <muscle_deformation/DeformPose.h>
#include <muscle_deformation/DeformationStats.h>

#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/JointState.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <cmath>
#include <mutex>
#include <string>
#include <vector>

namespace md = muscle_deformation;

namespace {

const char* kService = "/muscle_deformation/deform_pose";
double configured_step_s = 0;
std::vector<std::string> movable_joints;

std::mutex stats_mutex;
std::vector<md::DeformationStats> received_stats;

void onStats(const md::DeformationStats::ConstPtr& stats) {
  std::lock_guard<std::mutex> lock(stats_mutex);
  received_stats.push_back(*stats);
}

// Every movable joint at 0 but hip and knee flexion (gait2392: knee flexion is a negative knee_angle_r).
sensor_msgs::JointState jointState(double hip_flexion_rad, double knee_flexion_rad) {
  sensor_msgs::JointState state;
  state.header.stamp = ros::Time::now();
  for (const std::string& name : movable_joints) {
    state.name.push_back(name);
    state.position.push_back(name == "hip_flexion_r" ? hip_flexion_rad : name == "knee_angle_r" ? -knee_flexion_rad : 0.0);
  }
  return state;
}

bool cloudFinite(const sensor_msgs::PointCloud2& cloud) {
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
  for (; x != x.end(); ++x, ++y, ++z)
    if (!std::isfinite(*x) || !std::isfinite(*y) || !std::isfinite(*z)) return false;
  return true;
}

bool statsFinite(const md::DeformationStats& stats) {
  for (const double value : {stats.mss_ms, stats.collision_ms, stats.solve_ms, stats.total_ms,
                             stats.spring_deviation_ratio, stats.mean_strain, stats.max_strain, stats.time_step_s,
                             stats.max_penetration_sphere_bone_m, stats.max_penetration_sphere_muscle_m})
    if (!std::isfinite(value)) return false;
  return stats.finite;
}

}  // namespace

TEST(UnstableStep, ServiceRecoversAndAnswersFinitePositions) {
  md::DeformPose srv;
  srv.request.joint_state = jointState(0.5, 1.0);
  ASSERT_TRUE(ros::service::call(kService, srv));
  EXPECT_TRUE(srv.response.success) << srv.response.message;
  EXPECT_GT(srv.response.stats.divergence_recoveries, 0u);
  EXPECT_FALSE(srv.response.stats.diverged);
  EXPECT_LT(srv.response.stats.time_step_s, configured_step_s);
  EXPECT_TRUE(statsFinite(srv.response.stats));
  // This node runs with surface_metrics false: those figures are absent and say why, never 0.
  EXPECT_FALSE(srv.response.stats.has_surface_metrics);
  EXPECT_TRUE(std::isnan(srv.response.stats.volume_error_max_pct));
  EXPECT_EQ(srv.response.stats.surface_vertices_inside_bone, -1);
  EXPECT_NE(srv.response.stats.surface_metrics_absent_reason.find("surface_metrics is false"), std::string::npos)
      << srv.response.stats.surface_metrics_absent_reason;
  EXPECT_TRUE(cloudFinite(srv.response.particles));
}

TEST(UnstableStep, StreamingKeepsPublishingFiniteFrames) {
  ros::NodeHandle node;
  ros::Publisher joints = node.advertise<sensor_msgs::JointState>("/joint_states", 10);
  // The node and robot_state_publisher must be connected, or the first poses are lost.
  const ros::WallTime connect_deadline = ros::WallTime::now() + ros::WallDuration(30);
  while (joints.getNumSubscribers() < 2 && ros::WallTime::now() < connect_deadline) ros::WallDuration(0.1).sleep();
  ASSERT_GE(joints.getNumSubscribers(), 2u) << "node and robot_state_publisher should subscribe to /joint_states";
  // Poses a little apart, a few per second: slower than a frame's solve is not needed, newer poses replace older.
  const int poses = 8;
  for (int i = 1; i <= poses && ros::ok(); ++i) {  // not the rest pose, where nothing moves and nothing can diverge
    joints.publish(jointState(0.05 * i, 0.1 * i));
    ros::Duration(0.5).sleep();
  }
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(120);
  while (ros::WallTime::now() < deadline) {
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      if (!received_stats.empty() && received_stats.back().poses_received >= static_cast<std::uint32_t>(poses) &&
          received_stats.back().poses_solved + received_stats.back().poses_dropped +
                  received_stats.back().poses_unchanged + received_stats.back().tf_failures >=
              received_stats.back().poses_received)
        break;
    }
    ros::WallDuration(0.2).sleep();
  }
  std::lock_guard<std::mutex> lock(stats_mutex);
  ASSERT_GE(received_stats.size(), 2u) << "the node stopped publishing";
  std::uint32_t recoveries = 0;
  for (const md::DeformationStats& stats : received_stats) {
    EXPECT_TRUE(statsFinite(stats)) << "frame at " << stats.header.stamp;
    EXPECT_FALSE(stats.diverged) << "frame at " << stats.header.stamp;
    recoveries += stats.divergence_recoveries;
  }
  EXPECT_GT(recoveries, 0u);
  // The halved step is kept: only the first frame had to find it.
  EXPECT_GT(received_stats.front().divergence_recoveries, 0u);
  EXPECT_EQ(received_stats.back().divergence_recoveries, 0u);
  EXPECT_LT(received_stats.back().time_step_s, configured_step_s);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "unstable_step_test");
  ros::NodeHandle node, private_node("~");
  private_node.param("dt_s", configured_step_s, 0.0);
  std::string urdf;
  if (!node.getParam("/robot_description", urdf)) {
    ADD_FAILURE() << "robot_description is not set";
    return 1;
  }
  movable_joints = md::Skeleton::fromUrdfString(urdf, "robot_description").movableJointNames();
  ros::AsyncSpinner spinner(1);
  spinner.start();
  ros::Subscriber stats = node.subscribe("/muscle_deformation/stats", 100, onStats);
  if (!ros::service::waitForService(kService, ros::Duration(300))) {
    ADD_FAILURE() << kService << " did not appear within 300 s";
    return 1;
  }
  return RUN_ALL_TESTS();
}
