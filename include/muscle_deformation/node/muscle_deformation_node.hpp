// The roscpp node: skeleton poses from tf in, deformed fibres, particles, surfaces and statistics out, plus the
// ~deform_pose service. Parameters in config/muscle_deformation.yaml, topics in the README.
//
// Threads: joint_states and the diagnostics timer run on the global callback queue (main's spinner); the streaming solve
// runs on a worker thread of its own that always takes the newest pending pose, so a slow solve never builds a
// backlog. The service runs on a callback queue and spinner of its own, solves on its own DeformationPipeline one call
// at a time and never touches the streaming one, so no number of service calls can hold up the stream or the
// diagnostics. Every solve is bounded in time (~max_solve_time_s) and ends within an iteration at shutdown.
#pragma once

#include "muscle_deformation/core/pipeline/pose_stream.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/node/parameters.hpp"

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
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

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
  // Why a pose was not solved is counted per cause, so that the diagnostics say what happened.
  struct Counters {
    std::uint32_t received = 0, solved = 0, dropped = 0, unchanged = 0, tf_failures = 0, non_finite_joint_states = 0,
                  future_stamps = 0, resets = 0, non_finite = 0, divergence_recoveries = 0, diverged = 0;
  };
  struct LinkPoses {
    ros::Time stamp;
    std::map<std::string, Eigen::Isometry3d> poses;  // bone links in the fixed frame
  };
  using ServiceEvent = ros::ServiceEvent<muscle_deformation::DeformPose::Request, muscle_deformation::DeformPose::Response>;

  // Streaming
  void onJointStates(const sensor_msgs::JointState::ConstPtr& message);
  void workerLoop();
  // Waits (wall time, up to tf_wait_s, or until a newer pose arrives) until every bone's transform at `stamp` is
  // available. Returns false, with `error` naming the missing transform, if they did not all arrive.
  bool lookupBones(const ros::Time& stamp, LinkPoses& out, std::string& error);
  void countUnsolvedPose(const ros::Time& stamp, const std::string& error);
  // Warns (throttled) about joint values outside their URDF limits.
  void warnAboutJointLimits(const sensor_msgs::JointState& message);
  void solveStreamFrame(const LinkPoses& link_poses);
  bool anyOutputWanted() const;

  // Service
  bool onDeformPose(ServiceEvent& event);
  // Throws std::invalid_argument (bad request) or a core error; fills the response on success.
  void deformPose(const muscle_deformation::DeformPose::Request& request, const std::string& caller,
                  muscle_deformation::DeformPose::Response& response);
  // `warnings` collects joint values outside their URDF limits.
  std::map<std::string, Eigen::Isometry3d> linkPosesFromRequest(const muscle_deformation::DeformPose::Request& request,
                                                                std::string& frame_id,
                                                                std::vector<std::string>& warnings) const;

  // Diagnostics
  void diagnoseOutputRate(diagnostic_updater::DiagnosticStatusWrapper& status);
  void diagnoseSolveTime(diagnostic_updater::DiagnosticStatusWrapper& status);
  void diagnosePoses(diagnostic_updater::DiagnosticStatusWrapper& status);

  ros::NodeHandle node_, private_node_;
  NodeSettings settings_;
  SceneDescription scene_description_;
  Scene scene_;
  std::vector<Eigen::Vector3d> bone_centres_;  // rest centroid of each bone (for the pose-jump measure)
  std::unique_ptr<DeformationPipeline> stream_;

  // Service: its own queue and threads. One call solves at a time; up to ~service_max_queued wait for it, further
  // calls are refused at once.
  ros::CallbackQueue service_queue_;
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;
  std::atomic<int> service_calls_{0};  // being served or waiting
  std::mutex service_mutex_;           // guards everything below
  std::unique_ptr<DeformationPipeline> service_pipeline_;
  std::string service_pipeline_key_;
  // Warm starts continue the previous call of the same caller only (see deformPose).
  std::string service_previous_caller_;
  BoneTransforms service_previous_transforms_;
  bool service_has_previous_ = false;

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
  bool stopping_ = false;

  // Counters and the solve times since the last diagnostics update (guarded by counters_mutex_).
  mutable std::mutex counters_mutex_;
  Counters counters_;
  std::vector<double> window_solve_ms_;
  std::uint32_t window_solved_ = 0, window_dropped_ = 0, window_tf_failures_ = 0, window_received_ = 0,
                window_non_finite_joint_states_ = 0, window_future_stamps_ = 0;
  ros::WallTime window_start_;
  std::string last_tf_error_, last_joint_state_error_;

  // Worker-only state of the stream: warm, cold or unchanged for each new pose.
  std::unique_ptr<PoseStream> stream_policy_;

  std::thread worker_;
};

}  // namespace muscle_deformation::node
