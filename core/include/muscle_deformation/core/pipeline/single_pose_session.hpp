// Single poses, as the node's ~deform_pose service solves them: each request on its own copy of the model (the stream's
// state is never touched), by default cold from the rest shape moved by the rigid pre-transform, with the solver and
// stopping rule of single poses; optionally warm from the same caller's previous answer on the same muscles. One
// pipeline is kept per muscle selection (the last one asked for), built on the stream's bone fields. The reply's
// wording lives here, so that every client of the core words it alike.
#pragma once

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include <map>
#include <memory>
#include <string>
#include <vector>

namespace muscle_deformation {

// Single poses are solved cold where the stream runs warm: the fastest solver for each differs (docs/BENCHMARKS.md,
// real-time section), so single poses have their own.
struct SinglePoseSettings {
  SolverKind solver_kind = SolverKind::block_descent;
  int lbfgs_history = 16;    // local_global only: quasi-Newton curvature pairs
  int max_iterations = 20;   // a request's max_iterations wins
  // force_residual: stop at stopping.residual_tolerance (block descent and Newton-Krylov; the others run
  // max_iterations); anything else: max_iterations, unless a request gives a displacement tolerance.
  StoppingRule rule = StoppingRule::iterations;
  double residual_tolerance = 1e-3;     // what "converged" means for block descent and Newton-Krylov
  double warm_max_translation_m = 0.05;  // a warm start further away starts cold
  double warm_max_rotation_rad = 0.5;
  SolveLimits limits;  // every call's ceiling (wall time, cancellation); a request's time budget may only lower it
};
std::string validate(const SinglePoseSettings& settings);

struct SinglePoseRequest {
  std::map<std::string, Eigen::Isometry3d> link_poses;  // URDF links in the scene frame; links left out stay at rest
  std::vector<std::string> muscles;  // names or scene tags; empty: the session's default selection
  std::string caller;                // who asks (a warm start continues the same caller's previous answer only)
  bool warm_start = false;
  int max_iterations = 0;               // 0: the session's
  double displacement_tolerance_m = 0;  // > 0: stop (converged) once the mean step falls below it
  double time_budget_ms = 0;            // > 0: wall-time bound of this call (never above the session's ceiling)
  FrameWants wants{true, true};
  std::vector<std::string> warnings;    // about the pose (joint limits, quaternions), appended to the reply's message
};

struct SinglePoseReply {
  bool success = false;
  std::string message;  // what was done (start, iterations, convergence, which limit ended it) or what went wrong
  const FrameResult* frame = nullptr;  // the session's own, valid until its next solve
};

class SinglePoseSession {
 public:
  // `scene` and `description` must outlive the session. `pipeline`: the stream's pipeline settings, of which the
  // solver is replaced by settings.solver_kind. `bone_fields`: the bones' distance fields already built (the stream's).
  SinglePoseSession(const SceneDescription& description, const Scene& scene,
                    std::vector<std::string> default_selection, const PipelineSettings& pipeline,
                    SinglePoseSettings settings, BoneFields bone_fields = {});
  ~SinglePoseSession();

  // Throws std::invalid_argument naming the field of a request that cannot be served (an unknown muscle, a negative
  // limit); a solve that fails is a reply with success false and why.
  SinglePoseReply solve(const SinglePoseRequest& request);

  const SinglePoseSettings& settings() const { return settings_; }

 private:
  // The pipeline of the muscles `request` selects, built when the selection changes.
  DeformationPipeline& pipelineFor(const SinglePoseRequest& request);
  FrameStopping stoppingFor(const SinglePoseRequest& request) const;
  // Why a warm start is refused (empty: it is not).
  std::string coldReason(const SinglePoseRequest& request, const BoneTransforms& transforms) const;

  const SceneDescription& description_;
  const Scene& scene_;
  std::vector<std::string> default_selection_;
  PipelineSettings pipeline_settings_;
  SinglePoseSettings settings_;
  BoneFields bone_fields_;
  std::vector<Eigen::Vector3d> bone_centres_;  // rest centroid of each bone (for the warm-start distance)
  std::unique_ptr<DeformationPipeline> pipeline_;
  std::string pipeline_key_;
  // Warm starts continue the previous call of the same caller only.
  bool has_previous_ = false;
  std::string previous_caller_;
  BoneTransforms previous_transforms_;
};

}  // namespace muscle_deformation
