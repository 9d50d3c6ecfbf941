#include "muscle_deformation/node/muscle_deformation_node.hpp"

#include "muscle_deformation/node/conversions.hpp"

#include <ros/package.h>
#include <tf2_eigen/tf2_eigen.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <set>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace muscle_deformation::node {
namespace {

// Sets a thread cap for as long as it lives, and lifts it however the scope is left.
class ThreadCapHold {
 public:
  ThreadCapHold(std::atomic<int>& cap, int threads) : cap_(cap) { cap_ = threads; }
  ~ThreadCapHold() { cap_ = 0; }
  ThreadCapHold(const ThreadCapHold&) = delete;
  ThreadCapHold& operator=(const ThreadCapHold&) = delete;

 private:
  std::atomic<int>& cap_;
};

std::string packageRoot() {
  const std::string root = ros::package::getPath("muscle_deformation");
  if (root.empty())
    throw std::runtime_error("cannot find the package muscle_deformation (source devel/setup.bash of the workspace)");
  return root;
}

// package:// URIs of any ROS package, file:// and paths relative to the package root.
UriResolver rosUriResolver(const std::string& package_root) {
  return [package_root](const std::string& uri) {
    std::map<std::string, std::string> roots{{"muscle_deformation", package_root}};
    const std::string prefix = "package://";
    if (uri.rfind(prefix, 0) == 0) {
      const std::string package = uri.substr(prefix.size(), uri.find('/', prefix.size()) - prefix.size());
      if (!roots.count(package)) {
        const std::string path = ros::package::getPath(package);
        if (!path.empty()) roots[package] = path;
      }
    }
    return makeUriResolver(roots, package_root)(uri);
  };
}

// robot_description is what the node runs on; a scene made for another skeleton usually still names links that
// robot_description has, so compare the link sets with the scene's own `urdf:` file and say how they differ.
void warnIfTheSceneWasMadeForAnotherSkeleton(const SceneDescription& scene, const Skeleton& robot_description,
                                             const UriResolver& resolve) {
  try {
    const Skeleton scene_skeleton = Skeleton::fromUrdfFile(resolveScenePath(scene, scene.urdf_file, resolve));
    const std::string differences = describeLinkDifferences(scene_skeleton, robot_description);
    if (!differences.empty())
      ROS_WARN_STREAM("muscle_deformation: the scene " << scene.path << " was made for another skeleton than "
                                                       << robot_description.source() << " (" << differences
                                                       << "); the node uses " << robot_description.source());
  } catch (const std::exception& e) {
    ROS_WARN_STREAM("muscle_deformation: cannot compare " << robot_description.source()
                                                          << " with the scene's urdf: " << e.what());
  }
}

// Bones are looked up in the fixed frame while the scene's surfaces are given in the scene's own frame: at rest the two
// must coincide, or every bone would be moved by the offset between them. A fixed frame that is not a link of the
// skeleton (a frame above it in tf) cannot be checked here.
void requireFixedFrameAtSceneFrame(const Scene& scene, const std::string& scene_frame, const std::string& fixed_frame) {
  const auto fixed = scene.rest_link_poses.find(fixed_frame);
  if (fixed == scene.rest_link_poses.end()) return;
  constexpr double kCoincident = 1e-6;  // m, and rad in the rotation's entries
  if ((fixed->second.matrix() - Eigen::Matrix4d::Identity()).cwiseAbs().maxCoeff() <= kCoincident) return;
  throw std::runtime_error("fixed_frame '" + fixed_frame + "' does not coincide with the scene's frame '" + scene_frame +
                           "' at the URDF's zero configuration, so the bones would be moved by the offset between "
                           "them; set fixed_frame to '" + scene_frame + "' (gait_playback.launch fixed_frame:=" +
                           scene_frame + ")");
}

double median(std::vector<double> values) {
  if (values.empty()) return 0;
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

}  // namespace

MuscleDeformationNode::MuscleDeformationNode(const ros::NodeHandle& node, const ros::NodeHandle& private_node)
    : node_(node),
      private_node_(private_node),
      tf_buffer_(ros::Duration(30.0)),
      tf_listener_(tf_buffer_, node_),
      diagnostics_(node_, private_node_) {
  const auto start = std::chrono::steady_clock::now();
  const std::string package_root = packageRoot();
  try {
    settings_ = readNodeSettings(private_node_, package_root);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(e.what());
  }
  // Every solve ends at the node-wide ceiling, and within an iteration once shutdown begins.
  SolveLimits limits;
  limits.wall_time_limit_ms = 1000.0 * settings_.max_solve_time_s;
  limits.cancel = &shutting_down_;
  limits.max_threads = &stream_thread_cap_;
  settings_.pipeline.simulation.stopping.limits = limits;
  shareStoppingRule(settings_.pipeline.simulation);
  std::string urdf;
  if (!node_.getParam("robot_description", urdf) || urdf.empty()) {
    throw std::runtime_error("parameter " + node_.resolveName("robot_description") +
                             " is not set or empty: load the skeleton URDF into it (see launch/deform_service.launch)");
  }
  try {
    const Skeleton skeleton = Skeleton::fromUrdfString(urdf, node_.resolveName("robot_description"));
    scene_description_ = loadSceneDescription(settings_.scene_path);
    warnIfTheSceneWasMadeForAnotherSkeleton(scene_description_, skeleton, rosUriResolver(package_root));
    // Fails naming every link the scene needs that robot_description lacks.
    scene_ = loadScene(scene_description_, skeleton, rosUriResolver(package_root), settings_.muscles);
    if (scene_.muscles.empty()) throw std::runtime_error("the scene selects no muscle");
    requireFixedFrameAtSceneFrame(scene_, scene_description_.frame, settings_.fixed_frame);
    stream_ = std::make_unique<DeformationPipeline>(scene_.muscle_descriptions, scene_.muscles, scene_.bones,
                                                    settings_.pipeline);
  } catch (const std::exception& e) {
    throw std::runtime_error(std::string("cannot build the muscle model (scene ") + settings_.scene_path +
                             "): " + e.what());
  }
  bone_centres_ = boneRestCentroids(stream_->bones());
  stream_policy_ = std::make_unique<PoseStream>(bone_centres_, settings_.stream.policy);
  const double startup_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  ROS_INFO_STREAM("muscle_deformation: scene " << settings_.scene_path << ", fixed frame '" << settings_.fixed_frame
                                               << "'");
  ROS_INFO_STREAM("muscle_deformation: built " << stream_->describe() << "; startup " << startup_ms << " ms");
  for (const std::string& repair : scene_.repairs) ROS_WARN_STREAM("muscle_deformation: " << repair);
  for (const std::string& warning : scene_.warnings) ROS_WARN_STREAM("muscle_deformation: " << warning);
  for (const std::string& warning : stream_->simulation().buildReport().warnings)
    ROS_WARN_STREAM("muscle_deformation: " << warning);
  if (!stream_->skinning()) ROS_WARN_STREAM("muscle_deformation: ~surfaces disabled: " << stream_->skinningProblem());
  // A figure a setting turned off is information; one that something broken keeps from being measured is a warning.
  for (const AbsentMetric& absent : absentStatsFigures(*stream_, settings_.stream.stats_metrics)) {
    if (absent.turned_off)
      ROS_INFO_STREAM("muscle_deformation: ~stats without " << absent.describe());
    else
      ROS_WARN_STREAM("muscle_deformation: ~stats without " << absent.describe());
  }

  bones_pub_ = private_node_.advertise<visualization_msgs::MarkerArray>("bones", 1, /*latch=*/true);
  bones_pub_.publish(bonesToMarkers(stream_->bones(), scene_.rest_link_poses));
  fibres_pub_ = private_node_.advertise<visualization_msgs::MarkerArray>("fibres", 1);
  particles_pub_ = private_node_.advertise<sensor_msgs::PointCloud2>("particles", 1);
  surfaces_pub_ = private_node_.advertise<muscle_deformation::MuscleSurfaces>("surfaces", 1);
  surface_markers_pub_ = private_node_.advertise<visualization_msgs::MarkerArray>("surface_markers", 1);
  stats_pub_ = private_node_.advertise<muscle_deformation::DeformationStats>("stats", 10);
  ros::AdvertiseServiceOptions service_options;
  service_options.initBySpecType<ServiceEvent>(
      private_node_.resolveName("deform_pose"), [this](ServiceEvent& event) { return onDeformPose(event); });
  service_options.callback_queue = &service_queue_;
  deform_pose_srv_ = private_node_.advertiseService(service_options);
  // One thread more than the calls that may be in the service (one solving, max_queued waiting), so that the next
  // caller is answered "busy" at once instead of waiting unseen in the queue.
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(settings_.service.max_queued + 2, &service_queue_);
  service_spinner_->start();

  diagnostics_.setHardwareID("none");
  diagnostics_.add("Output rate", this, &MuscleDeformationNode::diagnoseOutputRate);
  diagnostics_.add("Solve time", this, &MuscleDeformationNode::diagnoseSolveTime);
  diagnostics_.add("Poses (tf failures, bad joint states, dropped)", this, &MuscleDeformationNode::diagnosePoses);
  window_start_ = ros::WallTime::now();
  // force_update, not update: update() waits until ros::Time::now() passes its next due time, which a clock that jumps
  // back (a looping bag under sim time) pushes out of reach for good. This wall timer sets the rate instead.
  diagnostics_timer_ = node_.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
    diagnostics_.force_update();
  });

  worker_ = std::thread(&MuscleDeformationNode::workerLoop, this);
  joint_states_sub_ = node_.subscribe("joint_states", 10, &MuscleDeformationNode::onJointStates, this);
}

MuscleDeformationNode::~MuscleDeformationNode() {
  shutting_down_ = true;  // running solves end after their current iteration
  if (service_spinner_) service_spinner_->stop();
  {
    std::lock_guard<std::mutex> lock(pending_mutex_);
    stopping_ = true;
  }
  pending_changed_.notify_all();
  if (worker_.joinable()) worker_.join();
}

// ---------------------------------------------------------------------------------------------------------------
// Streaming

void MuscleDeformationNode::onJointStates(const sensor_msgs::JointState::ConstPtr& message) {
  const ros::Time stamp = message->header.stamp.isZero() ? ros::Time::now() : message->header.stamp;
  // A NaN joint position gives no transforms (tf2 rejects them): say so here rather than as a missing transform.
  for (std::size_t j = 0; j < message->position.size(); ++j) {
    if (std::isfinite(message->position[j])) continue;
    const std::string joint = j < message->name.size() ? message->name[j] : "#" + std::to_string(j);
    std::lock_guard<std::mutex> lock(counters_mutex_);
    ++counters_.received;
    ++window_received_;
    ++counters_.non_finite_joint_states;
    ++window_non_finite_joint_states_;
    last_joint_state_error_ = "joint '" + joint + "' is " + std::to_string(message->position[j]);
    ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: joint state at " << stamp << " skipped: "
                                                                        << last_joint_state_error_);
    return;
  }
  warnAboutJointLimits(*message);
  bool replaced = false;
  {
    std::lock_guard<std::mutex> lock(pending_mutex_);
    replaced = pending_.has_value();
    pending_ = stamp;
  }
  pending_changed_.notify_one();
  std::lock_guard<std::mutex> lock(counters_mutex_);
  ++counters_.received;
  ++window_received_;
  if (replaced) {  // the worker was still busy with an earlier pose: the solver is slower than the input
    ++counters_.dropped;
    ++window_dropped_;
  }
}

void MuscleDeformationNode::warnAboutJointLimits(const sensor_msgs::JointState& message) {
  JointValues values;
  for (std::size_t j = 0; j < message.name.size() && j < message.position.size(); ++j)
    if (scene_.skeleton.joint(message.name[j])) values[message.name[j]] = message.position[j];
  std::vector<std::string> warnings;
  try {
    scene_.skeleton.linkPoses(values, &warnings);
  } catch (const std::exception&) {
    return;  // nothing to say about limits; the pose itself comes through tf
  }
  if (warnings.empty()) return;
  std::string text;
  for (const std::string& warning : warnings) text += (text.empty() ? "" : "; ") + warning;
  ROS_WARN_STREAM_THROTTLE(5.0, "muscle_deformation: joint state at " << message.header.stamp << ": " << text);
}

void MuscleDeformationNode::workerLoop() {
  while (true) {
    ros::Time stamp;
    {
      std::unique_lock<std::mutex> lock(pending_mutex_);
      pending_changed_.wait(lock, [this] { return stopping_ || pending_.has_value(); });
      if (stopping_) return;
      stamp = *pending_;
      pending_.reset();
    }
    LinkPoses link_poses;
    std::string error;
    if (!lookupBones(stamp, link_poses, error)) {
      countUnsolvedPose(stamp, error);
      continue;
    }
    try {
      solveStreamFrame(link_poses);
    } catch (const std::exception& e) {
      ROS_ERROR_STREAM_THROTTLE(2.0, "muscle_deformation: solve of the pose at " << stamp << " failed: " << e.what());
      stream_->reset();
      stream_policy_->reset();
    }
  }
}

void MuscleDeformationNode::countUnsolvedPose(const ros::Time& stamp, const std::string& error) {
  {
    std::lock_guard<std::mutex> lock(pending_mutex_);
    if (stopping_) return;
  }
  // A stamp ahead of the clock has no transforms yet and may never get them in time: a clock or stamping problem of
  // the publisher, not of tf.
  const bool future = stamp > ros::Time::now();
  std::lock_guard<std::mutex> lock(counters_mutex_);
  if (future) {
    ++counters_.future_stamps;
    ++window_future_stamps_;
    ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: pose at " << stamp << " skipped: its stamp is "
                                                                 << (stamp - ros::Time::now()).toSec()
                                                                 << " s ahead of the clock (" << error << ")");
  } else {
    ++counters_.tf_failures;
    ++window_tf_failures_;
    last_tf_error_ = error;
    ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: pose at " << stamp << " skipped: " << error);
  }
}

bool MuscleDeformationNode::lookupBones(const ros::Time& stamp, LinkPoses& out, std::string& error) {
  out.stamp = stamp;
  out.poses.clear();
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(settings_.stream.tf_wait_s);
  const std::vector<Bone>& bones = stream_->bones();
  std::size_t next = 0;  // bones before `next` are already looked up
  while (true) {
    for (; next < bones.size(); ++next) {
      std::string why;
      if (!tf_buffer_.canTransform(settings_.fixed_frame, bones[next].name, stamp, &why)) {
        error = "no transform from '" + bones[next].name + "' to '" + settings_.fixed_frame + "': " + why;
        break;
      }
      try {
        double quaternion_length = 1;
        out.poses[bones[next].name] = rigidTransformFromMessage(
            tf_buffer_.lookupTransform(settings_.fixed_frame, bones[next].name, stamp).transform, quaternion_length);
        if (std::abs(quaternion_length - 1.0) > kUnitQuaternionTolerance) {
          ROS_WARN_STREAM_THROTTLE(5.0, "muscle_deformation: the transform of '"
                                            << bones[next].name << "' at " << stamp << " has a rotation quaternion of length "
                                            << quaternion_length << "; normalised");
        }
      } catch (const tf2::TransformException& e) {
        error = e.what();
        break;
      }
    }
    if (next == bones.size()) {
      error.clear();
      return true;
    }
    {
      std::lock_guard<std::mutex> lock(pending_mutex_);
      if (stopping_) return false;
      if (pending_.has_value()) {
        error = "transforms not available before a newer pose arrived (" + error + ")";
        return false;
      }
    }
    if (ros::WallTime::now() > deadline) {
      error = "transforms not available within tf_wait_s = " + std::to_string(settings_.stream.tf_wait_s) + " s (" +
              error + ")";
      return false;
    }
    ros::WallDuration(0.001).sleep();
  }
}

bool MuscleDeformationNode::anyOutputWanted() const {
  return fibres_pub_.getNumSubscribers() || particles_pub_.getNumSubscribers() || surfaces_pub_.getNumSubscribers() ||
         surface_markers_pub_.getNumSubscribers() || stats_pub_.getNumSubscribers();
}

void MuscleDeformationNode::solveStreamFrame(const LinkPoses& link_poses) {
  const Pose pose = poseFromLinkPoses(scene_, link_poses.poses);
  const BoneTransforms transforms = boneTransformsOf(stream_->bones(), pose);
  const StreamDecision decision = stream_policy_->decide(link_poses.stamp.toSec(), transforms);
  if (decision.start == StreamStart::unchanged) {
    std::lock_guard<std::mutex> lock(counters_mutex_);
    ++counters_.unchanged;
    return;
  }
  const bool reset = decision.start == StreamStart::cold && stream_policy_->hasPrevious() &&
                     settings_.stream.policy.warm_start;
  if (reset) ROS_INFO_STREAM("muscle_deformation: pose at " << link_poses.stamp << ": cold start: " << decision.reason);
  if (decision.start == StreamStart::cold) stream_->reset();

  const bool want_fibres = fibres_pub_.getNumSubscribers() > 0;
  const bool want_particles = particles_pub_.getNumSubscribers() > 0;
  const bool want_surfaces = surfaces_pub_.getNumSubscribers() > 0;
  const bool want_surface_markers = surface_markers_pub_.getNumSubscribers() > 0;
  const bool want_stats = stats_pub_.getNumSubscribers() > 0;
  const StartMode start = decision.start == StreamStart::warm ? StartMode::warm : StartMode::cold;
  // The tissue drag relaxes over the time the stamps say passed since the previous solved pose (poses dropped while
  // the solver was busy included).
  const FrameResult& frame = stream_->solve(transforms, start, want_surfaces || want_surface_markers,
                                            want_stats && settings_.stream.stats_metrics, decision.elapsed_s);
  if (frame.stats.finite && !frame.stats.solver.diverged)
    stream_policy_->accept(link_poses.stamp.toSec(), transforms);
  else
    stream_policy_->reset();  // never warm-start from a broken state
  if (frame.stats.solver.time_limit_reached)
    ROS_WARN_STREAM_THROTTLE(5.0, "muscle_deformation: the solve at " << link_poses.stamp << " reached max_solve_time_s = "
                                                                      << settings_.max_solve_time_s << " s");

  Counters counters;  // as of this frame, for ~stats
  {
    std::lock_guard<std::mutex> lock(counters_mutex_);
    ++counters_.solved;
    ++window_solved_;
    if (reset) ++counters_.resets;
    if (!frame.stats.finite) ++counters_.non_finite;
    counters_.divergence_recoveries += static_cast<std::uint32_t>(frame.stats.solver.divergence_recoveries);
    if (frame.stats.solver.diverged) ++counters_.diverged;
    window_solve_ms_.push_back(frame.stats.solver.total_ms);
    counters = counters_;
  }
  if (frame.stats.solver.diverged)
    ROS_ERROR_STREAM_THROTTLE(2.0, "muscle_deformation: the solve at " << link_poses.stamp << " diverged at every time step down to "
                                                                       << frame.stats.solver.time_step_s
                                                                       << " s; publishing its starting state, next frame starts cold");
  else if (frame.stats.solver.divergence_recoveries > 0)
    ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: the solve at " << link_poses.stamp << " diverged and was re-run "
                                                                      << frame.stats.solver.divergence_recoveries
                                                                      << " time(s) with a halved time step, now "
                                                                      << frame.stats.solver.time_step_s << " s");
  if (!frame.stats.finite)
    ROS_ERROR_STREAM_THROTTLE(2.0, "muscle_deformation: the solve at " << link_poses.stamp
                                                                       << " gave non-finite positions; next frame starts cold");

  std_msgs::Header header;
  header.stamp = link_poses.stamp;
  header.frame_id = settings_.fixed_frame;
  if (want_fibres) fibres_pub_.publish(fibresToMarkers(frame, header, settings_.stream.colour_fibres_by_strain));
  if (want_particles) particles_pub_.publish(particlesToCloud(frame, header));
  if (frame.has_surfaces && want_surfaces) surfaces_pub_.publish(surfacesToMessage(frame, header));
  if (frame.has_surfaces && want_surface_markers)
    surface_markers_pub_.publish(surfacesToMarkers(frame, header, settings_.stream.surface_alpha));
  if (want_stats) {
    muscle_deformation::DeformationStats stats = statsToMessage(frame, header);
    if (!stats.has_surface_metrics && stream_->metrics() && !settings_.stream.stats_metrics)
      stats.surface_metrics_absent_reason = "stats_metrics is false";
    stats.poses_received = counters.received;
    stats.poses_solved = counters.solved;
    stats.poses_dropped = counters.dropped;
    stats.poses_unchanged = counters.unchanged;
    stats.tf_failures = counters.tf_failures;
    stats.poses_non_finite = counters.non_finite_joint_states;
    stats.poses_future_stamp = counters.future_stamps;
    stats.resets = counters.resets;
    stats_pub_.publish(stats);
  }
}

// ---------------------------------------------------------------------------------------------------------------
// Service

bool MuscleDeformationNode::onDeformPose(ServiceEvent& event) {
  muscle_deformation::DeformPose::Response& response = event.getResponse();
  // Counts this call while it is being served or waits; refuses it at once when too many are ahead of it.
  struct CallCount {
    std::atomic<int>& count;
    int value;
    explicit CallCount(std::atomic<int>& c) : count(c), value(++c) {}
    ~CallCount() { --count; }
  } calls(service_calls_);
  const int capacity = settings_.service.max_queued + 1;
  auto refuse = [&](const std::string& why) {
    response = muscle_deformation::DeformPose::Response();
    response.success = false;
    response.message = why;
    ROS_WARN_STREAM("muscle_deformation: ~deform_pose refused: " << why);
    return true;  // the answer (success or not) is in the response
  };
  if (calls.value > capacity) {
    return refuse("busy: " + std::to_string(calls.value - 1) + " calls are being served or waiting (one solves at a "
                  "time, service_max_queued = " + std::to_string(settings_.service.max_queued) +
                  " may wait); try again later");
  }
  std::lock_guard<std::mutex> lock(service_mutex_);
  if (shutting_down_) return refuse("the node is shutting down");
  try {
    deformPose(event.getRequest(), event.getCallerName(), response);
  } catch (const std::exception& e) {
    refuse(e.what());
  }
  return true;
}

std::map<std::string, Eigen::Isometry3d> MuscleDeformationNode::linkPosesFromRequest(
    const muscle_deformation::DeformPose::Request& request, std::string& frame_id,
    std::vector<std::string>& warnings) const {
  const Skeleton& skeleton = scene_.skeleton;
  if (!request.joint_state.name.empty()) {
    const JointValues values = jointValuesFromMessage(request.joint_state);
    for (const auto& [name, value] : values) {
      (void)value;
      if (!skeleton.joint(name)) throw std::invalid_argument("joint '" + name + "' is not a joint of the URDF");
    }
    std::map<std::string, Eigen::Isometry3d> root_poses = skeleton.linkPoses(values, &warnings);
    // Express the links in the fixed frame when it is a link of the skeleton (as tf would), else in the root.
    const auto fixed = root_poses.find(settings_.fixed_frame);
    frame_id = fixed == root_poses.end() ? skeleton.rootLink() : settings_.fixed_frame;
    if (fixed != root_poses.end()) {
      const Eigen::Isometry3d root_to_fixed = fixed->second.inverse();
      for (auto& [name, pose] : root_poses) pose = root_to_fixed * pose;
    }
    return root_poses;
  }
  if (request.bone_poses.empty()) {
    throw std::invalid_argument(
        "the request has no pose: give joint_state (names and positions) or bone_poses (link poses)");
  }
  std::map<std::string, Eigen::Isometry3d> poses;
  frame_id = settings_.fixed_frame;
  for (std::size_t i = 0; i < request.bone_poses.size(); ++i) {
    const geometry_msgs::TransformStamped& bone = request.bone_poses[i];
    const std::string what = "bone_poses[" + std::to_string(i) + "] ('" + bone.child_frame_id + "')";
    if (!bone.header.frame_id.empty() && bone.header.frame_id != settings_.fixed_frame) {
      throw std::invalid_argument(what + " is given in frame '" + bone.header.frame_id +
                                  "'; give bone poses in the node's fixed frame '" + settings_.fixed_frame + "'");
    }
    if (!skeleton.link(bone.child_frame_id))
      throw std::invalid_argument(what + ": child_frame_id is not a link of the URDF");
    double quaternion_length = 1;
    if (!poses.emplace(bone.child_frame_id, isometryFromMessage(bone.transform, what, &quaternion_length)).second)
      throw std::invalid_argument(what + " is given twice");
    if (std::abs(quaternion_length - 1.0) > kUnitQuaternionTolerance)
      warnings.push_back(what + ": rotation quaternion of length " + std::to_string(quaternion_length) + " normalised");
  }
  return poses;
}

void MuscleDeformationNode::deformPose(const muscle_deformation::DeformPose::Request& request,
                                       const std::string& caller, muscle_deformation::DeformPose::Response& response) {
  if (request.max_iterations < 0) {
    throw std::invalid_argument("max_iterations is " + std::to_string(request.max_iterations) +
                                "; it must be >= 0 (0 = node default)");
  }
  if (!(request.displacement_tolerance_m >= 0) || !std::isfinite(request.displacement_tolerance_m)) {
    throw std::invalid_argument("displacement_tolerance_m is " + std::to_string(request.displacement_tolerance_m) +
                                "; it must be a finite number >= 0 (0 = node default)");
  }
  if (!(request.time_budget_ms >= 0) || !std::isfinite(request.time_budget_ms)) {
    throw std::invalid_argument("time_budget_ms is " + std::to_string(request.time_budget_ms) +
                                "; it must be a finite number >= 0 (0 = node default)");
  }
  std::string frame_id;
  std::vector<std::string> warnings;
  const std::map<std::string, Eigen::Isometry3d> link_poses = linkPosesFromRequest(request, frame_id, warnings);

  // Muscles: the request's selection, else the node's; always from the scene already in memory.
  const std::vector<std::string>& selection = request.muscles.empty() ? settings_.muscles : request.muscles;
  std::vector<MuscleDescription> selected;
  try {
    selected = selectMuscles(scene_description_, selection);
  } catch (const std::exception& e) {
    throw std::invalid_argument(std::string("muscles: ") + e.what());
  }
  std::vector<std::size_t> indices;
  for (const MuscleDescription& m : selected) {
    const auto loaded = std::find_if(scene_.muscle_descriptions.begin(), scene_.muscle_descriptions.end(),
                                     [&](const MuscleDescription& d) { return d.name == m.name; });
    if (loaded == scene_.muscle_descriptions.end()) {
      throw std::invalid_argument("muscles: '" + m.name + "' is in the scene but not loaded by this node (its ~muscles "
                                  "selection); the service simulates loaded muscles only");
    }
    indices.push_back(static_cast<std::size_t>(loaded - scene_.muscle_descriptions.begin()));
  }
  if (indices.empty()) throw std::invalid_argument("muscles: the selection names no muscle");

  std::ostringstream key;
  for (std::size_t index : indices) key << index << ',';
  if (!service_pipeline_ || service_pipeline_key_ != key.str()) {
    service_pipeline_.reset();
    service_has_previous_ = false;
    PipelineSettings settings = settings_.pipeline;
    settings.simulation.solver_kind = settings_.service.solver_kind;
    settings.simulation.local_global.lbfgs_history = settings_.service.lbfgs_history;
    // Only block descent and Newton-Krylov measure a force residual; another service solver runs its iteration count
    // instead.
    if (settings.simulation.stopping.rule == StoppingRule::force_residual &&
        !measuresForceResidual(settings_.service.solver_kind)) {
      settings.simulation.stopping.rule = StoppingRule::iterations;
      shareStoppingRule(settings.simulation);
    }
    std::vector<MuscleDescription> descriptions;
    std::vector<Muscle> muscles;
    for (std::size_t index : indices) {
      descriptions.push_back(scene_.muscle_descriptions[index]);
      muscles.push_back(scene_.muscles[index]);
    }
    // The stream's bone fields serve the service too: building them is most of a pipeline's set-up.
    service_pipeline_ = std::make_unique<DeformationPipeline>(std::move(descriptions), std::move(muscles), scene_.bones,
                                                              settings, stream_->simulation().boneFields());
    service_pipeline_key_ = key.str();
  }
  DeformationPipeline& pipeline = *service_pipeline_;

  // Every limit the request gives is honoured, whatever the node's stopping rule: a displacement tolerance makes the
  // solve stop when it is met (the only convergence criterion), a time budget bounds its wall time, and the node's
  // max_solve_time_s bounds every call.
  const StoppingSettings& node_stopping = settings_.pipeline.simulation.stopping;
  StoppingRule rule = request.displacement_tolerance_m > 0 ? StoppingRule::displacement : node_stopping.rule;
  // A frame's time budget is the stream's (a request bounds its own time with time_budget_ms), and only block descent
  // and Newton-Krylov measure a force residual: the service runs its iteration count instead.
  if (rule == StoppingRule::time_budget ||
      (rule == StoppingRule::force_residual && !measuresForceResidual(settings_.service.solver_kind)))
    rule = StoppingRule::iterations;
  const int max_iterations = request.max_iterations > 0 ? request.max_iterations : settings_.service.max_iterations;
  const double tolerance_m =
      request.displacement_tolerance_m > 0 ? request.displacement_tolerance_m : node_stopping.displacement_tolerance_m;
  const double ceiling_ms = 1000.0 * settings_.max_solve_time_s;
  const double budget_ms = request.time_budget_ms > 0 ? request.time_budget_ms : node_stopping.time_budget_ms;
  SolveLimits limits;
  limits.wall_time_limit_ms = request.time_budget_ms > 0 ? std::min(request.time_budget_ms, ceiling_ms) : ceiling_ms;
  limits.cancel = &shutting_down_;
  pipeline.setStopping(rule, max_iterations, tolerance_m, budget_ms, limits);

  // Warm starts: only from this caller's own previous answer, on the same muscles, and only if no bone moved further
  // than service_warm_max_*; otherwise cold, and the message says why.
  const Pose pose = poseFromLinkPoses(scene_, link_poses);
  const BoneTransforms transforms = boneTransformsOf(pipeline.bones(), pose);
  std::string cold_reason;
  if (request.warm_start) {
    if (!service_has_previous_) {
      cold_reason = "there is no previous answer on these muscles";
    } else if (service_previous_caller_ != caller) {
      cold_reason = "the previous call came from another client (" + service_previous_caller_ + ")";
    } else {
      const BoneMotion motion = largestBoneMotion(service_previous_transforms_, transforms, bone_centres_);
      if (motion.translation_m > settings_.service.warm_max_translation_m ||
          motion.rotation_rad > settings_.service.warm_max_rotation_rad) {
        std::ostringstream why;
        why << "a bone moved " << motion.translation_m << " m and turned " << motion.rotation_rad
            << " rad since the previous call (service_warm_max_translation_m " << settings_.service.warm_max_translation_m
            << ", service_warm_max_rotation_rad " << settings_.service.warm_max_rotation_rad << ")";
        cold_reason = why.str();
      }
    }
    if (!cold_reason.empty()) pipeline.reset();
  }
  // The stream leaves this call a core while it solves (the default block descent stream otherwise takes them all);
  // put back whatever way the solve ends.
  const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const ThreadCapHold stream_cap(stream_thread_cap_, std::max(1, cores - 1));
  const FrameResult& frame = pipeline.solve(transforms, request.warm_start && cold_reason.empty() ? StartMode::warm
                                                                                             : StartMode::cold,
                                            true, pipeline.metrics() != nullptr);
  service_has_previous_ = frame.stats.finite && !frame.stats.solver.diverged && !frame.stats.solver.cancelled;
  service_previous_caller_ = caller;
  service_previous_transforms_ = transforms;

  std_msgs::Header header;
  header.stamp = ros::Time::now();
  header.frame_id = frame_id;
  response.fibres = fibresToMarkers(frame, header, settings_.stream.colour_fibres_by_strain);
  response.particles = particlesToCloud(frame, header);
  for (const Bone& bone : frame.bones()) response.bone_names.push_back(bone.name);
  response.surfaces = surfacesToMessage(frame, header);
  response.stats = statsToMessage(frame, header);
  const SolveStats& solve = frame.stats.solver;
  response.success = frame.stats.finite && !solve.diverged && !solve.cancelled;
  std::ostringstream message;
  if (!frame.stats.finite) {
    message << "the solve gave non-finite particle positions";
  } else if (solve.diverged) {
    message << "the solve diverged at every time step down to " << solve.time_step_s
            << " s; the particles are its starting state";
  } else if (solve.cancelled) {
    message << "the node is shutting down; the solve was stopped after " << solve.iterations << " iterations";
  } else {
    message << "solved " << frame.particles().muscleCount() << " muscles, " << frame.particles().particleCount()
            << " particles in "
            << solve.iterations << " iterations, " << solve.total_ms << " ms ("
            << (frame.stats.warm_started ? "warm start from this client's previous call" : "cold start");
    if (!cold_reason.empty()) message << "; warm start refused: " << cold_reason;
    message << ")";
    if (solve.converged && solve.no_descent_left)
      message << "; converged (no step lowers the energy any more: a minimum within the contacts)";
    else if (solve.converged && rule == StoppingRule::force_residual)
      message << "; converged (force residual below " << settings_.pipeline.simulation.block_descent.residual_tolerance
              << " of the springs' material constant)";
    else if (solve.converged)
      message << "; converged (mean step below " << tolerance_m << " m)";
    else if (solve.time_limit_reached)
      message << "; not converged: stopped at the time limit of " << limits.wall_time_limit_ms << " ms ("
              << (request.time_budget_ms > 0 && request.time_budget_ms <= ceiling_ms ? "the request's time_budget_ms"
                                                                                     : "the node's max_solve_time_s")
              << ")";
    else if (rule == StoppingRule::time_budget && solve.stopping_rule_met)
      message << "; not converged: the time budget of " << budget_ms << " ms ran out";
    else
      message << "; not converged: " << max_iterations << " iterations run";
    if (solve.divergence_recoveries > 0)
      message << "; after " << solve.divergence_recoveries << " divergence recoveries (time step halved to "
              << solve.time_step_s << " s)";
    if (!frame.has_surfaces) message << "; no surfaces: " << pipeline.skinningProblem();
  }
  for (const std::string& warning : warnings) message << "; warning: " << warning;
  response.message = message.str();
}

// ---------------------------------------------------------------------------------------------------------------
// Diagnostics

void MuscleDeformationNode::diagnoseOutputRate(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(counters_mutex_);
  const double seconds = std::max(1e-3, (ros::WallTime::now() - window_start_).toSec());
  const double solved_hz = window_solved_ / seconds;
  const double received_hz = window_received_ / seconds;
  const double expected = settings_.stream.expected_rate_hz;
  if (window_received_ == 0)
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "idle: no poses received");
  else if (expected > 0 && solved_hz < 0.8 * std::min(expected, received_hz))
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "solving %.1f Hz of %.1f Hz received", solved_hz,
                    received_hz);
  else
    status.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "solving %.1f Hz", solved_hz);
  status.add("Poses received (Hz)", received_hz);
  status.add("Frames solved (Hz)", solved_hz);
  status.add("Expected rate (Hz)", expected);
}

void MuscleDeformationNode::diagnoseSolveTime(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(counters_mutex_);
  const double budget_ms = settings_.stream.expected_rate_hz > 0 ? 1000.0 / settings_.stream.expected_rate_hz : 0;
  const double median_ms = median(window_solve_ms_);
  const double max_ms = window_solve_ms_.empty() ? 0 : *std::max_element(window_solve_ms_.begin(),
                                                                          window_solve_ms_.end());
  if (window_solve_ms_.empty())
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "no frame solved since the last update");
  else if (budget_ms > 0 && median_ms > budget_ms)
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "median solve %.1f ms exceeds %.1f ms", median_ms,
                    budget_ms);
  else
    status.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "median solve %.1f ms", median_ms);
  status.add("Median solve (ms)", median_ms);
  status.add("Max solve (ms)", max_ms);
  status.add("Frame budget (ms)", budget_ms);
  status.add("Non-finite frames (total)", counters_.non_finite);
  status.add("Divergence recoveries (total)", counters_.divergence_recoveries);
  status.add("Diverged frames (total)", counters_.diverged);
}

void MuscleDeformationNode::diagnosePoses(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(counters_mutex_);
  // Each cause on its own: a missing transform, a broken joint state or a clock problem is not a slow solver.
  std::vector<std::string> problems;
  if (window_tf_failures_ > 0)
    problems.push_back(std::to_string(window_tf_failures_) + " poses without transforms: " + last_tf_error_);
  if (window_non_finite_joint_states_ > 0)
    problems.push_back(std::to_string(window_non_finite_joint_states_) + " joint states with non-finite positions (" +
                       last_joint_state_error_ + ")");
  if (window_future_stamps_ > 0)
    problems.push_back(std::to_string(window_future_stamps_) + " poses stamped ahead of the clock");
  if (window_dropped_ > 0)
    problems.push_back(std::to_string(window_dropped_) + " poses dropped (solver slower than the input)");
  if (problems.empty()) {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "every pose handled");
  } else {
    std::string summary;
    for (const std::string& problem : problems) summary += (summary.empty() ? "" : "; ") + problem;
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, summary);
  }
  status.add("Poses received (total)", counters_.received);
  status.add("Frames solved (total)", counters_.solved);
  status.add("Poses dropped (total)", counters_.dropped);
  status.add("Poses unchanged (total)", counters_.unchanged);
  status.add("tf failures (total)", counters_.tf_failures);
  status.add("Non-finite joint states (total)", counters_.non_finite_joint_states);
  status.add("Future stamps (total)", counters_.future_stamps);
  status.add("Cold restarts (total)", counters_.resets);
  // This task runs last: start the next window.
  window_solve_ms_.clear();
  window_solved_ = window_dropped_ = window_tf_failures_ = window_received_ = 0;
  window_non_finite_joint_states_ = window_future_stamps_ = 0;
  window_start_ = ros::WallTime::now();
}

}  // namespace muscle_deformation::node
