// Fibre generation, the checking step: the checks of a fibre set, FibreCheckReport::describe and checkFibres.
#include "muscle_deformation/preprocessing/fibre_generator.hpp"

#include "fibre_field.hpp"
#include "fibre_tracing.hpp"

#include "muscle_deformation/core/base/point_index.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>

namespace muscle_deformation {

namespace fibre_steps {

// The checks, with the coverage measured on `section` (the one the seeds were spread over).
FibreCheckReport runChecks(const TriangleMesh& surface, const AttachmentPatches& patches,
                           const std::vector<Polyline>& fibres, const Field& field, const CrossSection& section,
                           const FibreGeneratorOptions& options) {
  FibreCheckReport r;
  r.fibre_count = static_cast<int>(fibres.size());
  r.tolerance = field.grid.h;
  if (fibres.empty()) {
    r.failures.push_back("no fibres");
    return r;
  }
  if (r.fibre_count < options.fibre_count) {
    r.failures.push_back(std::to_string(r.fibre_count) + " fibres instead of " + std::to_string(options.fibre_count));
  }
  r.min_length = kInf;
  double total = 0;
  for (const Polyline& fibre : fibres) {
    const double length = polylineLength(fibre);
    r.min_length = std::min(r.min_length, length);
    r.max_length = std::max(r.max_length, length);
    total += length;
    r.points += fibre.cols();
  }
  r.mean_length = total / static_cast<double>(fibres.size());

  // Inside: exact winding number, and points outside measured to the surface.
  const SurfaceDistance distance(surface.vertices, surface.triangles);
  for (const Polyline& fibre : fibres) {
    for (Eigen::Index i = 0; i < fibre.cols(); ++i) {
      if (windingNumber(surface, fibre.col(i)) >= 0.5) continue;
      const double d = distance.distance(fibre.col(i));
      r.max_outside_distance = std::max(r.max_outside_distance, d);
      if (d > r.tolerance) ++r.points_outside;
    }
  }
  if (r.points_outside > 0) {
    r.failures.push_back(std::to_string(r.points_outside) + " fibre points more than a voxel (" + mm(r.tolerance) +
                         ") outside the surface");
  }

  // Ends: start on the origin patch, end on the insertion patch (within two voxels).
  const TriangleMesh origin = patchSurface(surface, patches.origin_vertices);
  const TriangleMesh insertion = patchSurface(surface, patches.insertion_vertices);
  const SurfaceDistance to_origin(origin.vertices, origin.triangles);
  const SurfaceDistance to_insertion(insertion.vertices, insertion.triangles);
  for (const Polyline& fibre : fibres) {
    const double ds = to_origin.distance(fibre.col(0));
    const double de = to_insertion.distance(fibre.col(fibre.cols() - 1));
    r.max_start_distance = std::max(r.max_start_distance, ds);
    r.max_end_distance = std::max(r.max_end_distance, de);
    if (ds > 2 * r.tolerance) ++r.bad_starts;
    if (de > 2 * r.tolerance) ++r.bad_ends;
  }
  if (r.bad_starts > 0) r.failures.push_back(std::to_string(r.bad_starts) + " fibres do not start on the origin patch");
  if (r.bad_ends > 0) r.failures.push_back(std::to_string(r.bad_ends) + " fibres do not end on the insertion patch");

  // Crossing: the closest approach of any two fibres.
  r.min_pairwise_distance = kInf;
  std::vector<AlignedBox> boxes;
  for (const Polyline& fibre : fibres) boxes.push_back(boundsOf(fibre));
  for (std::size_t a = 0; a < fibres.size(); ++a)
    for (std::size_t b = a + 1; b < fibres.size(); ++b)
      r.min_pairwise_distance =
          polylineDistance(fibres[a], fibres[b], boxes[a], boxes[b], r.min_pairwise_distance);
  if (fibres.size() < 2) r.min_pairwise_distance = 0;
  if (fibres.size() >= 2 && !(r.min_pairwise_distance > 0)) r.failures.push_back("two fibres touch or cross");

  // Coverage of the seeding cross-section.
  r.cross_section_area = section.area;
  r.section_level = section.level;
  r.section_volume_fraction = section.volume_fraction;
  r.coverage_radius = 1.5 * std::sqrt(section.area / (M_PI * static_cast<double>(fibres.size())));
  double covered = 0;
  for (std::size_t s = 0; s < section.points.size(); ++s) {
    double d_best = kInf;
    for (const Polyline& fibre : fibres)
      for (Eigen::Index i = 0; i + 1 < fibre.cols(); ++i)
        d_best = std::min(d_best, pointSegmentDistance(section.points[s], fibre.col(i), fibre.col(i + 1)));
    r.max_gap = std::max(r.max_gap, d_best);
    if (d_best <= r.coverage_radius) covered += section.areas[s];
  }
  r.coverage = section.area > 0 ? covered / section.area : 0;
  if (r.coverage < r.min_coverage) {
    std::ostringstream msg;
    msg << "fibres cover " << std::fixed << std::setprecision(1) << 100 * r.coverage << " % of the seeding cross-section";
    r.failures.push_back(msg.str());
  }
  return r;
}

}  // namespace fibre_steps

using fibre_steps::effectiveVoxel;
using fibre_steps::Field;
using fibre_steps::requireClosed;
using fibre_steps::runChecks;
using fibre_steps::seedingCrossSections;
using fibre_steps::solveField;
using fibre_steps::validateOptions;
using fibre_steps::validatePatches;

double windingNumber(const TriangleMesh& surface, const Eigen::Vector3d& p) {
  // Sum of the signed solid angles of the triangles seen from p (Van Oosterom & Strackee), over 4 pi.
  double total = 0;
  for (Eigen::Index t = 0; t < surface.triangleCount(); ++t) {
    const Eigen::Vector3d a = surface.vertices.col(surface.triangles(0, t)) - p;
    const Eigen::Vector3d b = surface.vertices.col(surface.triangles(1, t)) - p;
    const Eigen::Vector3d c = surface.vertices.col(surface.triangles(2, t)) - p;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    const double numerator = a.dot(b.cross(c));
    const double denominator = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
    total += 2.0 * std::atan2(numerator, denominator);
  }
  return std::abs(total / (4.0 * M_PI));
}

std::string FibreCheckReport::describe() const {
  std::ostringstream out;
  out << std::fixed << std::setprecision(1);
  out << fibre_count << " fibres, length " << min_length * 1e3 << "-" << max_length * 1e3 << " mm (mean "
      << mean_length * 1e3 << "); outside by > " << tolerance * 1e3 << " mm: " << points_outside << "/" << points
      << " points (max " << std::setprecision(2) << max_outside_distance * 1e3 << " mm); ends to patches max "
      << max_start_distance * 1e3 << " / " << max_end_distance * 1e3 << " mm; min fibre distance "
      << std::setprecision(1) << min_pairwise_distance * 1e6 << " um; seeding cross-section " << cross_section_area * 1e4
      << " cm^2 (field value " << std::setprecision(2) << section_level << ", " << std::setprecision(0)
      << 100 * section_volume_fraction << " % of the volume from the origin), coverage " << std::setprecision(1)
      << 100 * coverage << " % within " << coverage_radius * 1e3 << " mm, max gap " << max_gap * 1e3 << " mm";
  out << (failures.empty() ? "; checks passed" : "; FAILED:");
  for (const std::string& f : failures) out << " [" << f << "]";
  return out.str();
}

FibreCheckReport checkFibres(const TriangleMesh& surface, const AttachmentPatches& patches,
                             const std::vector<Polyline>& fibres, const FibreGeneratorOptions& options) {
  validateOptions(options);
  requireClosed(surface);
  validatePatches(surface, patches);
  for (const Polyline& fibre : fibres) {
    if (fibre.cols() < 2 || !fibre.allFinite()) {
      throw FibreGenerationError("a fibre needs at least two finite points");
    }
  }
  const Field field = solveField(surface, patches, effectiveVoxel(surface, options), options);
  return runChecks(surface, patches, fibres, field, seedingCrossSections(field, options).front(), options);
}

}  // namespace muscle_deformation
