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

namespace muscle_deformation::node {
namespace {

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
  std::string urdf;
  if (!node_.getParam("robot_description", urdf) || urdf.empty()) {
    throw std::runtime_error("parameter " + node_.resolveName("robot_description") +
                             " is not set or empty: load the skeleton URDF into it (see launch/deform_service.launch)");
  }
  try {
    const Skeleton skeleton = Skeleton::fromUrdfString(urdf, "robot_description");
    scene_description_ = loadSceneDescription(settings_.scene_path);
    scene_ = loadScene(scene_description_, skeleton, rosUriResolver(package_root), package_root, settings_.muscles);
    if (scene_.muscles.empty()) throw std::runtime_error("the scene selects no muscle");
    stream_ = std::make_unique<DeformationPipeline>(scene_.muscle_descriptions, scene_.muscles, scene_.bones,
                                                    settings_.pipeline);
  } catch (const std::exception& e) {
    throw std::runtime_error(std::string("cannot build the muscle model (scene ") + settings_.scene_path +
                             "): " + e.what());
  }
  bone_centres_ = boneRestCentroids(stream_->simulation().bones());
  const double startup_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  ROS_INFO_STREAM("muscle_deformation: scene " << settings_.scene_path << ", fixed frame '" << settings_.fixed_frame
                                               << "'");
  ROS_INFO_STREAM("muscle_deformation: built " << stream_->describe() << "; startup " << startup_ms << " ms");
  for (const std::string& warning : stream_->simulation().buildReport().warnings)
    ROS_WARN_STREAM("muscle_deformation: " << warning);
  if (!stream_->skinning()) ROS_WARN_STREAM("muscle_deformation: ~surfaces disabled: " << stream_->skinningProblem());
  if (!stream_->metrics() && settings_.pipeline.measure_fidelity)
    ROS_WARN_STREAM("muscle_deformation: surface fidelity metrics disabled: " << stream_->metricsProblem());

  fibres_pub_ = private_node_.advertise<visualization_msgs::MarkerArray>("fibres", 1);
  particles_pub_ = private_node_.advertise<sensor_msgs::PointCloud2>("particles", 1);
  surfaces_pub_ = private_node_.advertise<muscle_deformation::MuscleSurfaces>("surfaces", 1);
  surface_markers_pub_ = private_node_.advertise<visualization_msgs::MarkerArray>("surface_markers", 1);
  stats_pub_ = private_node_.advertise<muscle_deformation::DeformationStats>("stats", 10);
  deform_pose_srv_ = private_node_.advertiseService("deform_pose", &MuscleDeformationNode::onDeformPose, this);

  diagnostics_.setHardwareID("none");
  diagnostics_.add("Output rate", this, &MuscleDeformationNode::diagnoseOutputRate);
  diagnostics_.add("Solve time", this, &MuscleDeformationNode::diagnoseSolveTime);
  diagnostics_.add("Poses (tf failures, dropped)", this, &MuscleDeformationNode::diagnosePoses);
  window_start_ = ros::WallTime::now();
  diagnostics_timer_ = node_.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
    diagnostics_.update();
  });

  worker_ = std::thread(&MuscleDeformationNode::workerLoop, this);
  joint_states_sub_ = node_.subscribe("joint_states", 10, &MuscleDeformationNode::onJointStates, this);
}

MuscleDeformationNode::~MuscleDeformationNode() {
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
  if (replaced) {
    ++counters_.dropped;
    ++window_dropped_;
  }
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
      std::lock_guard<std::mutex> lock(counters_mutex_);
      if (error.empty()) {  // superseded by a newer pose while waiting for its transforms
        ++counters_.dropped;
        ++window_dropped_;
      } else {
        ++counters_.tf_failures;
        ++window_tf_failures_;
        last_tf_error_ = error;
        ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: pose at " << stamp << " skipped: " << error);
      }
      continue;
    }
    try {
      solveStreamFrame(link_poses);
    } catch (const std::exception& e) {
      ROS_ERROR_STREAM_THROTTLE(2.0, "muscle_deformation: solve of the pose at " << stamp << " failed: " << e.what());
      stream_->reset();
      has_previous_ = false;
    }
  }
}

bool MuscleDeformationNode::lookupBones(const ros::Time& stamp, LinkPoses& out, std::string& error) {
  out.stamp = stamp;
  out.poses.clear();
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(settings_.stream.tf_wait_s);
  const std::vector<Bone>& bones = stream_->simulation().bones();
  std::size_t next = 0;  // bones before `next` are already looked up
  while (true) {
    for (; next < bones.size(); ++next) {
      std::string why;
      if (!tf_buffer_.canTransform(settings_.fixed_frame, bones[next].name, stamp, &why)) {
        error = "no transform from '" + bones[next].name + "' to '" + settings_.fixed_frame + "': " + why;
        break;
      }
      try {
        out.poses[bones[next].name] =
            tf2::transformToEigen(tf_buffer_.lookupTransform(settings_.fixed_frame, bones[next].name, stamp));
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
      if (stopping_ || pending_.has_value()) {
        error.clear();
        return false;
      }
    }
    if (ros::WallTime::now() > deadline) return false;
    ros::WallDuration(0.001).sleep();
  }
}

bool MuscleDeformationNode::anyOutputWanted() const {
  return fibres_pub_.getNumSubscribers() || particles_pub_.getNumSubscribers() || surfaces_pub_.getNumSubscribers() ||
         surface_markers_pub_.getNumSubscribers() || stats_pub_.getNumSubscribers();
}

void MuscleDeformationNode::solveStreamFrame(const LinkPoses& link_poses) {
  const Pose pose = poseFromLinkPoses(scene_, link_poses.poses);
  const BoneTransforms transforms = boneTransformsOf(stream_->simulation().bones(), pose);
  bool reset = false;
  if (has_previous_) {
    const BoneMotion motion = largestBoneMotion(previous_transforms_, transforms, bone_centres_);
    const double moved_m = motion.translation_m, turned_rad = motion.rotation_rad;
    if (link_poses.stamp < previous_stamp_) {
      ROS_INFO_STREAM("muscle_deformation: time jumped back from " << previous_stamp_ << " to " << link_poses.stamp
                                                                   << ": cold start");
      reset = true;
    } else if (moved_m > settings_.stream.reset_translation_m || turned_rad > settings_.stream.reset_rotation_rad) {
      ROS_INFO_STREAM("muscle_deformation: pose jumped (" << moved_m << " m, " << turned_rad
                                                          << " rad since the previous frame): cold start");
      reset = true;
    } else if (moved_m <= settings_.stream.unchanged_translation_m &&
               turned_rad <= settings_.stream.unchanged_rotation_rad) {
      std::lock_guard<std::mutex> lock(counters_mutex_);
      ++counters_.unchanged;
      return;
    }
  }
  if (reset) stream_->reset();

  const bool want_fibres = fibres_pub_.getNumSubscribers() > 0;
  const bool want_particles = particles_pub_.getNumSubscribers() > 0;
  const bool want_surfaces = surfaces_pub_.getNumSubscribers() > 0;
  const bool want_surface_markers = surface_markers_pub_.getNumSubscribers() > 0;
  const bool want_stats = stats_pub_.getNumSubscribers() > 0;
  const StartMode start = settings_.stream.warm_start ? StartMode::warm : StartMode::cold;
  const PipelineFrame& frame = stream_->solve(pose, start, want_surfaces || want_surface_markers,
                                              want_stats && settings_.stream.stats_metrics);
  has_previous_ = frame.solve.finite && !frame.solve.solve.diverged;
  previous_stamp_ = link_poses.stamp;
  previous_transforms_ = transforms;

  muscle_deformation::DeformationStats stats;
  {
    std::lock_guard<std::mutex> lock(counters_mutex_);
    ++counters_.solved;
    ++window_solved_;
    if (reset) ++counters_.resets;
    if (!frame.solve.finite) ++counters_.non_finite;
    counters_.divergence_recoveries += static_cast<std::uint32_t>(frame.solve.solve.divergence_recoveries);
    if (frame.solve.solve.diverged) ++counters_.diverged;
    window_solve_ms_.push_back(frame.solve.solve.total_ms);
    stats.poses_received = counters_.received;
    stats.poses_solved = counters_.solved;
    stats.poses_dropped = counters_.dropped;
    stats.poses_unchanged = counters_.unchanged;
    stats.tf_failures = counters_.tf_failures;
    stats.resets = counters_.resets;
  }
  if (frame.solve.solve.diverged)
    ROS_ERROR_STREAM_THROTTLE(2.0, "muscle_deformation: the solve at " << link_poses.stamp << " diverged at every time step down to "
                                                                       << frame.solve.solve.time_step_s
                                                                       << " s; publishing its starting state, next frame starts cold");
  else if (frame.solve.solve.divergence_recoveries > 0)
    ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: the solve at " << link_poses.stamp << " diverged and was re-run "
                                                                      << frame.solve.solve.divergence_recoveries
                                                                      << " time(s) with a halved time step, now "
                                                                      << frame.solve.solve.time_step_s << " s");
  if (!frame.solve.finite)
    ROS_ERROR_STREAM_THROTTLE(2.0, "muscle_deformation: the solve at " << link_poses.stamp
                                                                       << " gave non-finite positions; next frame starts cold");

  std_msgs::Header header;
  header.stamp = link_poses.stamp;
  header.frame_id = settings_.fixed_frame;
  const MassSpringSystem& system = stream_->simulation().system();
  const Eigen::Matrix3Xd& positions = stream_->simulation().state().position;
  const std::vector<MuscleDescription>& muscles = stream_->descriptions();
  if (want_fibres)
    fibres_pub_.publish(fibresToMarkers(system, positions, muscles, header, settings_.stream.colour_fibres_by_strain));
  if (want_particles) particles_pub_.publish(particlesToCloud(system, positions, header));
  if (frame.has_surfaces && want_surfaces)
    surfaces_pub_.publish(surfacesToMessage(*stream_->skinning(), frame.surfaces, muscles, header));
  if (frame.has_surfaces && want_surface_markers) {
    surface_markers_pub_.publish(
        surfacesToMarkers(*stream_->skinning(), frame.surfaces, muscles, header, settings_.stream.surface_alpha));
  }
  if (want_stats) {
    muscle_deformation::DeformationStats full = statsToMessage(frame, settings_.pipeline.simulation.solver, header);
    full.poses_received = stats.poses_received;
    full.poses_solved = stats.poses_solved;
    full.poses_dropped = stats.poses_dropped;
    full.poses_unchanged = stats.poses_unchanged;
    full.tf_failures = stats.tf_failures;
    full.resets = stats.resets;
    stats_pub_.publish(full);
  }
}

// ---------------------------------------------------------------------------------------------------------------
// Service

bool MuscleDeformationNode::onDeformPose(muscle_deformation::DeformPose::Request& request,
                                         muscle_deformation::DeformPose::Response& response) {
  std::lock_guard<std::mutex> lock(service_mutex_);
  try {
    deformPose(request, response);
  } catch (const std::exception& e) {
    response = muscle_deformation::DeformPose::Response();
    response.success = false;
    response.message = e.what();
    ROS_WARN_STREAM("muscle_deformation: ~deform_pose refused: " << e.what());
  }
  return true;  // the answer (success or not) is in the response
}

std::map<std::string, Eigen::Isometry3d> MuscleDeformationNode::linkPosesFromRequest(
    const muscle_deformation::DeformPose::Request& request, std::string& frame_id) const {
  const Skeleton& skeleton = scene_.skeleton;
  if (!request.joint_state.name.empty()) {
    const JointValues values = jointValuesFromMessage(request.joint_state);
    for (const auto& [name, value] : values) {
      (void)value;
      if (!skeleton.joint(name)) throw std::invalid_argument("joint '" + name + "' is not a joint of the URDF");
    }
    std::map<std::string, Eigen::Isometry3d> root_poses = skeleton.linkPoses(values);
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
    if (!poses.emplace(bone.child_frame_id, isometryFromMessage(bone.transform, what)).second)
      throw std::invalid_argument(what + " is given twice");
  }
  return poses;
}

void MuscleDeformationNode::deformPose(const muscle_deformation::DeformPose::Request& request,
                                       muscle_deformation::DeformPose::Response& response) {
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
  const std::map<std::string, Eigen::Isometry3d> link_poses = linkPosesFromRequest(request, frame_id);

  // Muscles: the request's selection, else the node's.
  const std::vector<std::string>& selection = request.muscles.empty() ? settings_.muscles : request.muscles;
  std::vector<MuscleDescription> selected;
  try {
    selected = selectMuscles(scene_description_, selection);
  } catch (const std::exception& e) {
    throw std::invalid_argument(std::string("muscles: ") + e.what());
  }
  if (selected.empty()) throw std::invalid_argument("muscles: the selection names no muscle");

  PipelineSettings settings = settings_.pipeline;
  settings.simulation.solver_kind = settings_.service.solver_kind;
  settings.simulation.local_global.lbfgs_history = settings_.service.lbfgs_history;
  SolverSettings& solver = settings.simulation.solver;
  solver.max_iterations = settings_.service.max_iterations;
  if (request.max_iterations > 0) solver.max_iterations = request.max_iterations;
  if (request.displacement_tolerance_m > 0) solver.displacement_tolerance_m = request.displacement_tolerance_m;
  if (request.time_budget_ms > 0) solver.time_budget_ms = request.time_budget_ms;
  shareStoppingRule(settings.simulation);
  std::ostringstream key;
  for (const MuscleDescription& m : selected) key << m.name << ',';
  key << '|' << solver.max_iterations << '|' << solver.displacement_tolerance_m << '|' << solver.time_budget_ms;
  if (!service_pipeline_ || service_pipeline_key_ != key.str()) {
    service_pipeline_.reset();
    std::vector<std::string> names;
    for (const MuscleDescription& m : selected) names.push_back(m.name);
    const bool same_muscles = names.size() == scene_.muscle_descriptions.size() &&
                              std::equal(names.begin(), names.end(), scene_.muscle_descriptions.begin(),
                                         [](const std::string& n, const MuscleDescription& d) { return n == d.name; });
    if (same_muscles) {
      service_pipeline_ =
          std::make_unique<DeformationPipeline>(scene_.muscle_descriptions, scene_.muscles, scene_.bones, settings);
    } else {
      Scene subset = loadScene(scene_description_, scene_.skeleton, rosUriResolver(settings_.package_root),
                               settings_.package_root, names);
      service_pipeline_ = std::make_unique<DeformationPipeline>(subset.muscle_descriptions, std::move(subset.muscles),
                                                                std::move(subset.bones), settings);
    }
    service_pipeline_key_ = key.str();
  }
  DeformationPipeline& pipeline = *service_pipeline_;
  const Pose pose = poseFromLinkPoses(scene_, link_poses);
  const PipelineFrame& frame =
      pipeline.solve(pose, request.warm_start ? StartMode::warm : StartMode::cold, true, pipeline.metrics() != nullptr);

  std_msgs::Header header;
  header.stamp = ros::Time::now();
  header.frame_id = frame_id;
  const MassSpringSystem& system = pipeline.simulation().system();
  const Eigen::Matrix3Xd& positions = pipeline.simulation().state().position;
  response.fibres = fibresToMarkers(system, positions, pipeline.descriptions(), header,
                                    settings_.stream.colour_fibres_by_strain);
  response.particles = particlesToCloud(system, positions, header);
  for (const Bone& bone : pipeline.simulation().bones()) response.bone_names.push_back(bone.name);
  if (frame.has_surfaces) response.surfaces = surfacesToMessage(*pipeline.skinning(), frame.surfaces,
                                                                pipeline.descriptions(), header);
  response.surfaces.header = header;
  response.stats = statsToMessage(frame, solver, header);
  response.success = frame.solve.finite && !frame.solve.solve.diverged;
  std::ostringstream message;
  if (!frame.solve.finite) {
    message << "the solve gave non-finite particle positions";
  } else if (frame.solve.solve.diverged) {
    message << "the solve diverged at every time step down to " << frame.solve.solve.time_step_s
            << " s; the particles are its starting state";
  } else {
    message << "solved " << system.muscleCount() << " muscles, " << system.particleCount() << " particles in "
            << frame.solve.solve.iterations << " iterations, " << frame.solve.solve.total_ms << " ms ("
            << (frame.solve.warm_started ? "warm" : "cold") << " start)";
    if (frame.solve.solve.divergence_recoveries > 0)
      message << " after " << frame.solve.solve.divergence_recoveries
              << " divergence recoveries (time step halved to " << frame.solve.solve.time_step_s << " s)";
    if (!frame.has_surfaces) message << "; no surfaces: " << pipeline.skinningProblem();
  }
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
  if (window_tf_failures_ > 0)
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "%u poses without transforms: %s", window_tf_failures_,
                    last_tf_error_.c_str());
  else if (window_dropped_ > 0)
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "%u poses dropped (solver slower than the input)",
                    window_dropped_);
  else
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "every pose handled");
  status.add("Poses received (total)", counters_.received);
  status.add("Frames solved (total)", counters_.solved);
  status.add("Poses dropped (total)", counters_.dropped);
  status.add("Poses unchanged (total)", counters_.unchanged);
  status.add("tf failures (total)", counters_.tf_failures);
  status.add("Cold restarts (total)", counters_.resets);
  // This task runs last: start the next window.
  window_solve_ms_.clear();
  window_solved_ = window_dropped_ = window_tf_failures_ = window_received_ = 0;
  window_start_ = ros::WallTime::now();
}

}  // namespace muscle_deformation::node
