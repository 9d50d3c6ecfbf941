// Each muscle modelled only as finely as an error target needs: the coarsest particles per fibre whose skinned surface
// stays within the target of the finest model's at every checked pose (the speed-against-error report's resolution
// error, docs/BENCHMARKS.md). The models are the scene's muscles at one resolution each, solved cold to convergence
// at poses that bend the joints each muscle crosses; each muscle's error is the RMS distance of its skinned surface's
// vertices (before the bone contact and the volume projection) to the same vertices of the finest model.
#pragma once

#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/pipeline/settings_table.hpp"
#include "muscle_deformation/core/scene/skeleton.hpp"

#include <Eigen/Geometry>

#include <functional>
#include <map>
#include <string>
#include <vector>

namespace muscle_deformation {

struct ResolutionChoiceRequest {
  double surface_error_m = 0;                  // the target: worst RMS over the checked poses (> 0)
  std::vector<int> candidates{10, 15, 20, 40};  // particles per fibre, tried coarse to fine
  int finest = 80;                              // the reference resolution
  // Each joint a muscle crosses (between its origin and insertion links) is bent to +/- this, within its limits, one
  // at a time: the checked poses.
  double bend_rad = 0.5;
  // Each model solves each pose cold until its residual is below this, or this many sweeps.
  double residual_tolerance = 0.01;
  int max_sweeps = 300;
};

struct MuscleResolution {
  std::string muscle;
  std::vector<double> worst_rms_m;  // per candidate (request order): the largest per-pose RMS to the finest model
  std::vector<double> worst_max_m;  // per candidate: the largest vertex distance
  int chosen = 0;                   // particles per fibre: the coarsest candidate within the target
  bool met = false;                 // false: no candidate met it; `chosen` is then the finest candidate
};

struct ResolutionChoice {
  std::vector<std::string> poses;  // e.g. "hip_flexion_r +0.50 rad"
  std::vector<MuscleResolution> muscles;
  std::vector<int> resolutions;         // particles per fibre: the candidates, then the finest
  std::vector<double> model_particles;  // per resolution: particles of the whole model
  double seconds = 0;
};

// Chooses each muscle's particles per fibre. `muscles` and `bones` at rest in the scene frame (the scene's frame link
// at the skeleton's zero configuration); `settings` the node's (its model resolution is replaced per candidate).
// Throws std::invalid_argument for a target that is not positive, candidates that are not increasing and below
// `finest`, or muscles that cross no joint (nothing to check), and what the pipeline throws.
ResolutionChoice chooseResolutions(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones,
                                   const Skeleton& skeleton, const std::string& frame, const CoreSettings& settings,
                                   const ResolutionChoiceRequest& request,
                                   const std::function<void(const std::string&)>& progress = {});

}  // namespace muscle_deformation
