#include "muscle_deformation/node/muscle_deformation_node.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include "muscle_deformation/node/conversions.hpp"
#include "muscle_deformation/node/scene_startup.hpp"

#include <algorithm>
#include <chrono>
#include <stdexcept>

namespace muscle_deformation::node {
namespace {

// A stamp this far ahead of the clock is a stamping or clock problem of the publisher, not latency.
constexpr double kFutureStampToleranceS = 0.5;
// While the input pauses, an unfinished frame is refined (and published) at most this often: a user watches it settle
// at 10 Hz, and an idle node takes about a tenth of the machine (a refinement costs a frame's budget) instead of every
// core for as long as the frame keeps improving, which starved other processes (a second node's stream dropped
// poses beside it).
constexpr double kIdleRefinementPeriodS = 0.1;

// The time between two poses at the expected rate (0: no rate expected, so nothing is judged against it).
double posePeriodMs(const NodeSettings& settings) {
  return settings.stream.expected_rate_hz > 0 ? 1000.0 / settings.stream.expected_rate_hz : 0.0;
}

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

}  // namespace

MuscleDeformationNode::MuscleDeformationNode(const ros::NodeHandle& node, const ros::NodeHandle& private_node)
    : node_(node),
      private_node_(private_node),
      settings_(readNodeSettings(private_node_, packageRoot())),
      pose_diagnostics_(settings_.stream.expected_rate_hz),
      sweep_budget_(posePeriodMs(settings_)),
      tf_buffer_(ros::Duration(30.0)),
      tf_listener_(tf_buffer_, node_),
      diagnostics_(node_, private_node_) {
  // Every solve ends at the node-wide ceiling, and within an iteration once shutdown begins.
  SolveLimits limits;
  limits.wall_time_limit_ms = 1000.0 * settings_.max_solve_time_s;
  limits.cancel = &shutting_down_;
  settings_.service.single_pose.limits = limits;
  limits.max_threads = &stream_thread_cap_;
  settings_.core.stream.stopping.sweeps.limits = limits;
  const auto start = std::chrono::steady_clock::now();
  loadScene();
  const double startup_ms = millisecondsSince(start);
  const DeformationPipeline& pipeline = stream_->pipeline();
  ROS_INFO_STREAM("muscle_deformation: scene " << settings_.scene_path << ", fixed frame '" << settings_.fixed_frame
                                               << "'; built " << pipeline.describe() << "; startup " << startup_ms
                                               << " ms");
  if (const auto& fit = stream_->resolutionFit()) {
    if (fit->changed()) ROS_WARN_STREAM("muscle_deformation: " << fit->describe());
    else ROS_INFO_STREAM("muscle_deformation: " << fit->describe());
    sweep_budget_ = SweepBudgetCheck(posePeriodMs(settings_), /*resolution_fitted=*/true);
  }
  for (const std::string& repair : scene_.repairs) ROS_WARN_STREAM("muscle_deformation: " << repair);
  for (const std::string& warning : scene_.warnings) ROS_WARN_STREAM("muscle_deformation: " << warning);
  for (const std::string& warning : pipeline.buildReport().warnings) ROS_WARN_STREAM("muscle_deformation: " << warning);
  if (!pipeline.skinning()) ROS_WARN_STREAM("muscle_deformation: ~surfaces disabled: " << pipeline.skinningProblem());
  // A figure a setting turned off is information; one that something broken keeps from being measured is a warning.
  for (const AbsentMetric& absent : absentStatsFigures(pipeline, settings_.stream.stats_metrics)) {
    if (absent.turned_off) ROS_INFO_STREAM("muscle_deformation: ~stats without " << absent.describe());
    else ROS_WARN_STREAM("muscle_deformation: ~stats without " << absent.describe());
  }
  advertise();
  worker_ = std::thread(&MuscleDeformationNode::workerLoop, this);
  joint_states_sub_ = node_.subscribe("joint_states", 10, &MuscleDeformationNode::onJointStates, this);
}

void MuscleDeformationNode::loadScene() {
  std::string urdf;
  if (!node_.getParam("robot_description", urdf) || urdf.empty()) {
    throw std::runtime_error("parameter " + node_.resolveName("robot_description") +
                             " is not set or empty: load the skeleton URDF into it (see launch/deform_service.launch)");
  }
  const UriResolver resolve = rosUriResolver(settings_.package_root);
  try {
    const Skeleton skeleton = Skeleton::fromUrdfString(urdf, node_.resolveName("robot_description"));
    scene_description_ = loadSceneDescription(settings_.scene_path);
    const std::string mismatch = describeSkeletonMismatch(scene_description_, skeleton, resolve);
    if (!mismatch.empty()) ROS_WARN_STREAM("muscle_deformation: " << mismatch);
    // Fails naming every link the scene needs that robot_description lacks.
    scene_ = muscle_deformation::loadScene(scene_description_, skeleton, resolve, settings_.muscles);
    if (scene_.muscles.empty()) throw std::runtime_error("the scene selects no muscle");
    requireFixedFrameAtSceneFrame(scene_, scene_description_.frame, settings_.fixed_frame);
    stream_ = std::make_unique<StreamSession>(scene_.muscle_descriptions, scene_.muscles, scene_.bones,
                                              settings_.core.pipeline, settings_.core.stream);
    // The stream's bone fields serve single poses too: building them is most of a pipeline's set-up.
    single_pose_ = std::make_unique<SinglePoseSession>(scene_description_, scene_, settings_.muscles,
                                                       settings_.core.pipeline, settings_.service.single_pose,
                                                       stream_->pipeline().boneFields());
  } catch (const std::exception& e) {
    throw std::runtime_error(std::string("cannot build the muscle model (scene ") + settings_.scene_path +
                             "): " + e.what());
  }
  std::vector<std::string> bone_links;
  for (const Bone& bone : stream_->bones()) bone_links.push_back(bone.name);
  bone_lookup_ = std::make_unique<TfBoneLookup>(tf_buffer_, scene_.skeleton, bone_links, settings_.fixed_frame);
}

void MuscleDeformationNode::advertise() {
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
  pose_diagnostics_.addTasks(diagnostics_);
  // force_update, not update: update() waits until ros::Time::now() passes its next due time, which a clock that jumps
  // back (a looping bag under sim time) pushes out of reach for good. This wall timer sets the rate instead.
  diagnostics_timer_ = node_.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
    diagnostics_.force_update();
  });
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
  // The service's rule: a NaN position gives no transforms (tf2 rejects them) and a joint named twice has no one
  // value; say so here rather than as a missing transform.
  bool duplicate = false;
  const std::string problem = jointStateProblem(*message, duplicate);
  if (!problem.empty()) {
    pose_diagnostics_.received(false);
    pose_diagnostics_.skipped(duplicate ? SkippedPose::duplicate_joint : SkippedPose::non_finite_joint, problem);
    ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: joint state at " << stamp << " skipped: " << problem);
    return;
  }
  const double ahead_s = (stamp - ros::Time::now()).toSec();
  if (ahead_s > kFutureStampToleranceS) {
    pose_diagnostics_.received(false);
    pose_diagnostics_.skipped(SkippedPose::future_stamp, std::to_string(ahead_s) + " s ahead");
    tf_holds_future_data_ = true;
    ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: pose at " << stamp << " skipped: its stamp is " << ahead_s
                                                                 << " s ahead of the clock");
    return;
  }
  const std::string outside_limits = jointLimitWarnings(scene_.skeleton, *message);
  if (!outside_limits.empty())
    ROS_WARN_STREAM_THROTTLE(5.0, "muscle_deformation: joint state at " << stamp << ": " << outside_limits);
  bool replaced = false;
  {
    std::lock_guard<std::mutex> lock(pending_mutex_);
    replaced = pending_.has_value();
    pending_replaced_ = pending_replaced_ || replaced;
    pending_ = stamp;
  }
  pending_changed_.notify_one();
  pose_diagnostics_.received(replaced);
}

void MuscleDeformationNode::workerLoop() {
  // Once the input has paused for two expected frame periods, an unfinished frame is refined every
  // kIdleRefinementPeriodS (a live stream never pauses that long; a slow recording or a held skeleton does).
  const double rate_hz = settings_.stream.expected_rate_hz > 0 ? settings_.stream.expected_rate_hz : 60.0;
  const auto idle_period = std::chrono::duration<double>(1.0 / rate_hz);
  const auto refinement_period = std::chrono::duration<double>(kIdleRefinementPeriodS);
  auto last_pose = std::chrono::steady_clock::now(), last_refinement = last_pose;
  while (true) {
    std::optional<ros::Time> stamp;
    bool late = false;
    {
      std::unique_lock<std::mutex> lock(pending_mutex_);
      const auto ready = [this] { return stopping_ || pending_.has_value(); };
      if (stream_->wantsRefinement())
        pending_changed_.wait_for(lock, std::max<std::chrono::duration<double>>(idle_period, refinement_period), ready);
      else
        pending_changed_.wait(lock, ready);
      if (stopping_) return;
      stamp = pending_;
      late = pending_replaced_;
      pending_.reset();
      pending_replaced_ = false;
    }
    const auto now = std::chrono::steady_clock::now();
    if (stamp) {
      last_pose = now;
      solvePose(*stamp, late);
    } else if (now - last_pose > 2 * idle_period && now - last_refinement >= refinement_period &&
               anyOutputWanted()) {
      last_refinement = now;
      const StreamStep step = stream_->refine(frameWants());
      publish(step, ros::Time(step.stamp_s));
    }
  }
}

void MuscleDeformationNode::solvePose(const ros::Time& stamp, bool late) {
  // The transforms sent with poses stamped ahead make tf drop every transform stamped on time: this pose's are gone,
  // the next poses find theirs once the buffer is cleared.
  if (tf_holds_future_data_.exchange(false) && bone_lookup_->clearDataAheadOf(stamp, kFutureStampToleranceS)) {
    ROS_WARN_STREAM("muscle_deformation: pose at " << stamp << ": tf had dropped its transforms for those of poses "
                    "stamped ahead of the clock; tf's buffer cleared");
    return pose_diagnostics_.skipped(SkippedPose::tf_failure, "transforms dropped for poses stamped ahead");
  }
  TfBoneLookup::Result bones;
  const auto give_up = [this] {
    std::lock_guard<std::mutex> lock(pending_mutex_);
    return stopping_ || pending_.has_value();
  };
  if (!bone_lookup_->lookup(stamp, settings_.stream.tf_wait_s, give_up, bones)) {
    std::lock_guard<std::mutex> lock(pending_mutex_);
    if (stopping_) return;
    pose_diagnostics_.skipped(SkippedPose::tf_failure, bones.error);
    ROS_WARN_STREAM_THROTTLE(2.0, "muscle_deformation: pose at " << stamp << " skipped: " << bones.error);
    return;
  }
  for (const std::string& warning : bones.warnings) ROS_WARN_STREAM_THROTTLE(5.0, "muscle_deformation: " << warning);
  const BoneTransforms transforms = boneTransformsOf(stream_->bones(), poseFromLinkPoses(scene_, bones.link_poses));
  FrameWants wants = frameWants();
  wants.late = late;  // poses were dropped while the frame before was solved
  const StreamStep step = stream_->offer(stamp.toSec(), transforms, wants);
  if (step.restarted) ROS_INFO_STREAM("muscle_deformation: pose at " << stamp << ": cold start: " << step.reason);
  // A refined frame (the pose had not changed) carries the stamp of the pose it refines.
  publish(step, step.outcome == StreamOutcome::refined ? ros::Time(step.stamp_s) : stamp);
}

bool MuscleDeformationNode::anyOutputWanted() const {
  return fibres_pub_.getNumSubscribers() || particles_pub_.getNumSubscribers() || surfaces_pub_.getNumSubscribers() ||
         surface_markers_pub_.getNumSubscribers() || stats_pub_.getNumSubscribers();
}

FrameWants MuscleDeformationNode::frameWants() const {
  FrameWants wants;
  wants.surfaces = surfaces_pub_.getNumSubscribers() > 0 || surface_markers_pub_.getNumSubscribers() > 0;
  wants.metrics = stats_pub_.getNumSubscribers() > 0 && settings_.stream.stats_metrics;
  return wants;
}

void MuscleDeformationNode::publish(const StreamStep& step, const ros::Time& stamp) {
  pose_diagnostics_.stepped(stream_->counters(), step.frame ? step.frame->stats.solve_ms : -1.0);
  if (step.outcome == StreamOutcome::failed)
    ROS_ERROR_STREAM_THROTTLE(2.0, "muscle_deformation: solve of the pose at " << stamp << " failed: " << step.reason);
  if (!step.frame) return;
  const FrameResult& frame = *step.frame;
  const SolveStats& solve = frame.stats.solver;
  const std::string at = "muscle_deformation: the solve at " + std::to_string(stamp.toSec()) + " s ";
  if (solve.time_limit_reached)
    ROS_WARN_STREAM_THROTTLE(5.0, at << "reached max_solve_time_s = " << settings_.max_solve_time_s << " s");
  if (solve.diverged)
    ROS_ERROR_STREAM_THROTTLE(2.0, at << "diverged at every time step down to " << solve.time_step_s
                                      << " s; publishing its starting state, next frame starts cold");
  else if (solve.divergence_recoveries > 0)
    ROS_WARN_STREAM_THROTTLE(2.0, at << "diverged and was re-run " << solve.divergence_recoveries
                                     << " time(s) with a halved time step, now " << solve.time_step_s << " s");
  if (!frame.stats.finite) ROS_ERROR_STREAM_THROTTLE(2.0, at << "gave non-finite positions; next frame starts cold");
  if (step.outcome == StreamOutcome::solved)
    if (const std::string slow = sweep_budget_.add(frame.stats, frame.stats.warm_started); !slow.empty())
      ROS_WARN_STREAM("muscle_deformation: " << slow);
  std_msgs::Header header;
  header.stamp = stamp;
  header.frame_id = settings_.fixed_frame;
  if (fibres_pub_.getNumSubscribers()) fibres_pub_.publish(fibresToMarkers(frame, header, settings_.stream.colour_fibres_by_strain));
  if (particles_pub_.getNumSubscribers()) particles_pub_.publish(particlesToCloud(frame, header));
  if (frame.has_surfaces && surfaces_pub_.getNumSubscribers()) surfaces_pub_.publish(surfacesToMessage(frame, header));
  if (frame.has_surfaces && surface_markers_pub_.getNumSubscribers())
    surface_markers_pub_.publish(surfacesToMarkers(frame, header, settings_.stream.surface_alpha));
  if (!stats_pub_.getNumSubscribers()) return;
  muscle_deformation::DeformationStats stats = statsToMessage(frame, header);
  if (!stats.has_surface_metrics && stream_->pipeline().metrics() && !settings_.stream.stats_metrics)
    stats.surface_metrics_absent_reason = "stats_metrics is false";
  const PoseTotals totals = pose_diagnostics_.totals();
  stats.refined = step.outcome == StreamOutcome::refined;
  stats.poses_received = totals.received;
  stats.poses_solved = totals.stream.solved;
  stats.poses_refined = totals.stream.refined;
  stats.poses_dropped = totals.dropped;
  stats.poses_unchanged = totals.stream.unchanged;
  stats.tf_failures = totals.tf_failures;
  stats.poses_non_finite = totals.non_finite_joints;
  stats.poses_duplicate_joint = totals.duplicate_joints;
  stats.poses_future_stamp = totals.future_stamps;
  stats.resets = totals.stream.resets;
  stats_pub_.publish(stats);
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
  auto refuse = [&](const std::string& why) {
    response = muscle_deformation::DeformPose::Response();
    response.success = false;
    response.message = why;
    ROS_WARN_STREAM("muscle_deformation: ~deform_pose refused: " << why);
    return true;  // the answer (success or not) is in the response
  };
  if (calls.value > settings_.service.max_queued + 1) {
    return refuse("busy: " + std::to_string(calls.value - 1) + " calls are being served or waiting (one solves at a "
                  "time, service_max_queued = " + std::to_string(settings_.service.max_queued) +
                  " may wait); try again later");
  }
  std::lock_guard<std::mutex> lock(service_mutex_);
  if (shutting_down_) return refuse("the node is shutting down");
  try {
    std::string frame_id;
    SinglePoseRequest request =
        singlePoseRequestFromMessage(event.getRequest(), scene_.skeleton, settings_.fixed_frame, frame_id);
    request.caller = event.getCallerName();
    // The stream leaves this call a core while it solves (the default stream otherwise takes them all); put back
    // whatever way the solve ends.
    const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    const ThreadCapHold stream_cap(stream_thread_cap_, std::max(1, cores - 1));
    const SinglePoseReply reply = single_pose_->solve(request);
    std_msgs::Header header;
    header.stamp = ros::Time::now();
    header.frame_id = frame_id;
    const FrameResult& frame = *reply.frame;
    response.fibres = fibresToMarkers(frame, header, settings_.stream.colour_fibres_by_strain);
    response.particles = particlesToCloud(frame, header);
    for (const Bone& bone : frame.bones()) response.bone_names.push_back(bone.name);
    response.surfaces = surfacesToMessage(frame, header);
    response.stats = statsToMessage(frame, header);
    response.success = reply.success;
    response.message = reply.message;
  } catch (const std::exception& e) {
    refuse(e.what());
  }
  return true;
}

}  // namespace muscle_deformation::node
