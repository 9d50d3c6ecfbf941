// A stream of skeleton poses, as the node's /joint_states stream and the benchmarks that speak for it play one: each pose
// offered is decided on (warm, cold at a discontinuity, or unchanged), solved, and accepted or, if its solve failed,
// forgotten so that the next pose starts cold; a pose no bone moved in refines an unfinished frame instead. The one
// place the stream protocol lives: the node hands it poses and publishes what it returns.
#pragma once

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"

#include <cstdint>
#include <exception>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace muscle_deformation {

// When a pose starts warm, cold or is not solved again.
struct PoseStreamSettings {
  bool warm_start = true;  // false: every pose is solved cold
  // A bone centre moving faster than this between two poses is a teleport (m/s). The fastest human limb segments
  // reach a few m/s (a sprinter's foot about 20 m/s at most); the thigh and pelvis stay well below 10 m/s.
  double max_bone_speed_m_per_s = 20.0;
  // Same for rotation (rad/s); the fastest joint motions (a throwing arm) reach about 50 rad/s, the hip and knee less.
  double max_bone_angular_speed_rad_per_s = 50.0;
  double unchanged_translation_m = 1e-7;  // no bone moved more than this (and turned less than the next): skip
  double unchanged_rotation_rad = 1e-7;
};

// Checks the settings; returns a message naming the problem, or an empty string.
std::string validate(const PoseStreamSettings& settings);

struct StreamSessionSettings {
  PoseStreamSettings poses;
  FrameStopping stopping;  // how a frame's solve stops (a cold start: stopping.cold_start_iterations)
  // A pose no bone moved in, while the last frame has not met its residual criterion (solvers that measure one), is
  // spent on more sweeps of that frame, within the frame's stopping, until it converges or its residual stops falling
  // (ten refinements without one that lowers the frame's lowest residual by 1 %; refine()).
  bool refine_unfinished_frames = true;
  // The stream's model made coarser at construction until a one-sweep solve fits stopping.sweeps.time_budget_ms on
  // this machine, as measured there (StreamSession::resolutionFit()): a machine too slow for the configured model then
  // streams a lighter one instead of overrunning every frame. Needs the time_budget rule (the budget is what is fitted).
  bool auto_resolution = false;
};
std::string validate(const StreamSessionSettings& settings);

// What auto_resolution measured and chose: each model it built, coarsest last, with its one-sweep solve time.
struct ResolutionFit {
  // The coarsest model it builds: the coarsest the speed-against-error report measures (docs/BENCHMARKS.md).
  static constexpr int kCoarsestParticlesPerFibre = 10;
  static constexpr int kMostModels = 4;
  static constexpr int kTimedSolves = 7;  // warm one-sweep solves timed per model (the median counts)

  struct Model {
    int particles_per_fibre = 0;  // the model-wide value; a muscle with its own is scaled alike
    long particles = 0;
    double solve_ms = 0;  // median wall time of a warm one-sweep solve (no surfaces or metrics)
  };
  std::vector<Model> models;  // in the order built; the last is the stream's
  double budget_ms = 0;

  bool fits() const { return !models.empty() && models.back().solve_ms <= budget_ms; }
  bool changed() const { return models.size() > 1; }
  // One paragraph for the startup log: what was measured, what the stream uses, where the error it costs is reported.
  std::string describe() const;
};

enum class StreamOutcome {
  solved,     // a new pose was solved
  refined,    // the pose had not changed and the unfinished last frame was solved further
  unchanged,  // the pose had not changed and the last frame needs nothing more: nothing was solved
  failed,     // the solve threw (an exception of the core); the next pose starts cold
};

// What became of one pose offered to the stream.
struct StreamStep {
  StreamOutcome outcome = StreamOutcome::unchanged;
  bool cold = false;       // solved from the rigid pre-transform (the first pose, a discontinuity, warm starts off)
  bool restarted = false;  // a cold start of a stream that had solved before: a discontinuity (time going back, a
                           // jump) or a recovery after a failed frame
  std::string reason;      // why cold, unchanged or failed
  double elapsed_s = 0;    // since the previous solved pose (weighs the tissue drag)
  double stamp_s = 0;      // the stamp of the pose the frame solves (a refined frame: the pose it refines)
  // solved or refined: the frame (the session's own; valid until the next call that solves)
  const FrameResult* frame = nullptr;
};

// Running counts of what the stream did with the poses it was offered.
struct StreamCounters {
  std::uint32_t offered = 0;    // poses offered
  std::uint32_t solved = 0;     // new poses solved
  std::uint32_t refined = 0;    // refinement solves of an unfinished frame (a held pose, or idle time)
  std::uint32_t unchanged = 0;  // poses no bone moved in, not solved
  std::uint32_t resets = 0;     // cold restarts of a running stream
  std::uint32_t failed = 0;     // solves that threw
  std::uint32_t non_finite = 0;           // frames whose solve left non-finite positions
  std::uint32_t divergence_recoveries = 0;
  std::uint32_t diverged = 0;             // frames that diverged at every time step
};

class PoseStream;  // the warm / cold / unchanged decision (core/src/pipeline/pose_stream.hpp)

class StreamSession {
 public:
  // Builds the pipeline (throws ModelError / std::invalid_argument on bad settings or input, as DeformationPipeline).
  StreamSession(std::vector<MuscleDescription> descriptions, std::vector<Muscle> muscles, std::vector<Bone> bones,
                const PipelineSettings& pipeline, const StreamSessionSettings& settings,
                const BoneFields& bone_fields = {});
  ~StreamSession();
  StreamSession(const StreamSession&) = delete;
  StreamSession& operator=(const StreamSession&) = delete;

  // The pose at `stamp_s` (seconds, any epoch; a stream's stamps) given as bone transforms (boneTransformsOf(bones(),
  // pose)): decided on, solved if it needs it, accepted or forgotten. Never throws for a solve that fails: the step
  // says `failed` and why, and the next pose starts cold. Throws std::invalid_argument for transforms that do not fit
  // the bones.
  StreamStep offer(double stamp_s, const BoneTransforms& transforms, const FrameWants& wants);
  // Whether the last frame has not met its residual criterion and refine() would solve it further.
  bool wantsRefinement() const;
  // More of the last frame's solve at the same pose (within the frame's stopping), when wantsRefinement(): for the
  // time between poses when the input holds still or stops. Otherwise `unchanged` and nothing is solved.
  StreamStep refine(const FrameWants& wants);
  // Forget the stream: the next pose starts cold (e.g. after the caller lost poses it cannot account for).
  void restart();
  // Continue from a known result (benchmarks start compared streams from one converged frame): `position` solved at
  // `transforms`, the pose at `stamp_s`.
  void continueFrom(double stamp_s, const BoneTransforms& transforms, const Eigen::Matrix3Xd& position);

  const StreamCounters& counters() const { return counters_; }
  // What auto_resolution measured and chose (absent when it is off).
  const std::optional<ResolutionFit>& resolutionFit() const { return resolution_fit_; }
  const DeformationPipeline& pipeline() const { return *pipeline_; }
  const std::vector<Bone>& bones() const { return pipeline_->bones(); }
  const StreamSessionSettings& settings() const { return settings_; }

 private:
  StreamStep solveFrame(double stamp_s, const BoneTransforms& transforms, StartMode start, double elapsed_s,
                        const FrameWants& wants, StreamStep step);
  void count(const FrameResult& frame);
  // Builds pipeline_ at the configured resolution, then coarser ones while a one-sweep solve overruns the budget.
  void buildFittedPipeline(const std::vector<MuscleDescription>& descriptions, const std::vector<Muscle>& muscles,
                           const std::vector<Bone>& bones, const PipelineSettings& pipeline,
                           const BoneFields& bone_fields);
  void failed(StreamStep& step, const std::exception& error);

  StreamSessionSettings settings_;
  std::unique_ptr<DeformationPipeline> pipeline_;
  std::unique_ptr<PoseStream> poses_;
  std::optional<ResolutionFit> resolution_fit_;
  StreamCounters counters_;
  bool last_frame_unfinished_ = false;  // the last solved frame measured a residual above its tolerance
  double best_residual_ = -1;           // the lowest residual of the current frame so far (-1: not measured)
  // Refinements of the current frame since one lowered best_residual_ by at least kMinRefinementGain of it; after
  // kStalledRefinementsToStop of them the frame is left unfinished and the session stops refining it.
  int stalled_refinements_ = 0;
  static constexpr double kMinRefinementGain = 0.01;
  static constexpr int kStalledRefinementsToStop = 10;
  double last_stamp_s_ = 0;             // of the last pose solved
  bool recovering_ = false;  // a frame failed or diverged since the last good one: the next cold start is a restart
};

}  // namespace muscle_deformation
