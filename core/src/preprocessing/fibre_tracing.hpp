// Fibre generation, the tracing step (private header): geometry helpers, streamlines traced from a cross-section.
#pragma once

#include "fibre_field.hpp"

#include "muscle_deformation/core/base/point_index.hpp"

#include <Eigen/Core>

#include <vector>

namespace muscle_deformation::fibre_steps {

// Geometry helpers (fibre_tracing.cpp), also used by the checks.
double pointSegmentDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b);
double polylineDistance(const Polyline& a, const Polyline& b, const AlignedBox& box_a, const AlignedBox& box_b,
                        double bound);
TriangleMesh patchSurface(const TriangleMesh& surface, const std::vector<int>& vertices);

// The fibres traced from seeds spread over one cross-section, and what it took.
struct TracedFibres {
  std::vector<Polyline> fibres;
  int failed_seeds = 0, merged_fibres = 0, reseed_rounds = 0;  // as in FibreGenerationResult
};

// Streamlines of a field from seeds on a cross-section to both patches, finished on the surface and resampled.
class StreamlineTracer {
 public:
  StreamlineTracer(const Field& field, const TriangleMesh& surface, const AttachmentPatches& patches,
                   const FibreGeneratorOptions& options);

  // Seeds whose streamline misses a patch (it runs into the rim or a stagnation point) are excluded with their
  // neighbourhood and the seeds are spread again, up to five times.
  TracedFibres traceFrom(const CrossSection& section) const;

 private:
  // The fibre through `start`, origin first; false if its streamline misses a patch either way.
  bool traceFibre(const Eigen::Vector3d& start, Polyline& fibre) const;

  const Field& field_;
  const TriangleMesh& surface_;
  const FibreGeneratorOptions& options_;
  double h_, step_;
  int max_steps_ = 0;
  TriangleMesh origin_surface_, insertion_surface_;
  SurfaceDistance origin_distance_, insertion_distance_;
};

}  // namespace muscle_deformation::fibre_steps
