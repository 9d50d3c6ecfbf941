// The roscpp node: skeleton poses from tf in, deformed fibres, particles, surfaces and statistics out, plus the
// ~deform_pose service. Parameters in config/muscle_deformation.yaml, topics in the README. A thin adapter: the stream
// protocol is the core's StreamSession, single poses the core's SinglePoseSession; the node turns messages into their
// inputs and their frames into messages.
//
// Threads: joint_states and the diagnostics timer run on the global callback queue (main's spinner); the streaming solve
// runs on a worker thread of its own that always takes the newest pending pose, so a slow solve never builds a
// backlog, and refines an unfinished frame while no pose comes. The service runs on a callback queue and spinner of
// its own, solves on its own session one call at a time and never touches the stream's, so no number of service
// calls can hold up the stream or the diagnostics. Every solve is bounded in time (~max_solve_time_s) and ends within
// an iteration at shutdown.
#pragma once

#include "muscle_deformation/core/pipeline/single_pose_session.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/pipeline/sweep_budget_check.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/node/parameters.hpp"
#include "muscle_deformation/node/pose_diagnostics.hpp"
#include "muscle_deformation/node/tf_bone_lookup.hpp"

#include <muscle_deformation/DeformPose.h>

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <ros/spinner.h>
#include <sensor_msgs/JointState.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

namespace muscle_deformation::node {

class MuscleDeformationNode {
 public:
  // Reads the parameters, robot_description and the scene, builds the model and starts the worker. Throws
  // std::runtime_error with a message naming the missing or broken input.
  MuscleDeformationNode(const ros::NodeHandle& node, const ros::NodeHandle& private_node);
  ~MuscleDeformationNode();
  MuscleDeformationNode(const MuscleDeformationNode&) = delete;
  MuscleDeformationNode& operator=(const MuscleDeformationNode&) = delete;

 private:
  using ServiceEvent = ros::ServiceEvent<muscle_deformation::DeformPose::Request, muscle_deformation::DeformPose::Response>;

  void loadScene();
  void advertise();
  // Streaming
  void onJointStates(const sensor_msgs::JointState::ConstPtr& message);
  void workerLoop();
  void solvePose(const ros::Time& stamp, bool late);
  bool anyOutputWanted() const;
  FrameWants frameWants() const;
  void publish(const StreamStep& step, const ros::Time& stamp);
  // Service
  bool onDeformPose(ServiceEvent& event);

  ros::NodeHandle node_, private_node_;
  NodeSettings settings_;
  SceneDescription scene_description_;
  Scene scene_;
  std::unique_ptr<StreamSession> stream_;  // the worker's only
  std::unique_ptr<TfBoneLookup> bone_lookup_;
  PoseDiagnostics pose_diagnostics_;
  SweepBudgetCheck sweep_budget_;  // says once when one sweep does not fit between two poses

  // Service: its own queue and threads. One call solves at a time (service_mutex_); up to ~service_max_queued wait
  // for it, further calls are refused at once.
  ros::CallbackQueue service_queue_;
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;
  std::atomic<int> service_calls_{0};  // being served or waiting
  std::mutex service_mutex_;
  std::unique_ptr<SinglePoseSession> single_pose_;

  // Raised at shutdown: every running solve ends after its current iteration.
  std::atomic<bool> shutting_down_{false};
  // The stream's solver threads while a service call solves (0 = no cap): the call keeps one core, so that neither
  // solve's threads wait at barriers for a descheduled partner.
  std::atomic<int> stream_thread_cap_{0};

  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  ros::Publisher fibres_pub_, particles_pub_, surfaces_pub_, surface_markers_pub_, stats_pub_;
  ros::Publisher bones_pub_;  // latched: the bones at rest, once, moved by rviz with tf
  ros::Subscriber joint_states_sub_;
  ros::ServiceServer deform_pose_srv_;
  diagnostic_updater::Updater diagnostics_;
  ros::WallTimer diagnostics_timer_;

  // Newest pending pose (guarded by pending_mutex_).
  std::mutex pending_mutex_;
  std::condition_variable pending_changed_;
  std::optional<ros::Time> pending_;
  // A newer pose replaced a pending one since the worker last took one: the pose it takes next is late (FrameWants).
  bool pending_replaced_ = false;
  bool stopping_ = false;
  // A pose stamped ahead of the clock came in: robot_state_publisher's transforms at that stamp displace every older
  // one from tf's buffer (its cache keeps ~30 s behind the newest), so the buffer is cleared when a pose stamped on
  // time then finds no transforms.
  std::atomic<bool> tf_holds_future_data_{false};

  std::thread worker_;
};

}  // namespace muscle_deformation::node
