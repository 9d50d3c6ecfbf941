// Fibre generation, the entry points: the checks of the input, generateFibres (the steps in order), saveFibresVtk.
// Fibres inside a closed surface (Choi & Blemker 2013): voxelise, solve Laplace's equation with Dirichlet patches at
// origin and insertion, trace gradient streamlines from seeds spread over a cross-section (an iso-surface); one file
// per step in this folder (fibre_steps.hpp lists them).
#include "muscle_deformation/preprocessing/fibre_generator.hpp"

#include "fibre_field.hpp"
#include "fibre_tracing.hpp"

#include "muscle_deformation/core/io/mesh_io.hpp"

#include <algorithm>
#include <iomanip>
#include <sstream>
#include <utility>

namespace muscle_deformation {

namespace fibre_steps {

std::string mm(double metres, int precision) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(precision) << metres * 1e3 << " mm";
  return out.str();
}

void requireClosed(const TriangleMesh& surface) {
  if (surface.vertexCount() == 0 || surface.triangleCount() == 0) {
    throw FibreGenerationError("the muscle surface is empty");
  }
  if (!surface.vertices.allFinite()) throw FibreGenerationError("the muscle surface has non-finite vertices");
  const SurfaceTopologyReport topology = checkSurfaceTopology(surface);
  if (!topology.closedManifold()) {
    throw FibreGenerationError("the muscle surface must be closed and 2-manifold to have an inside: " +
                               topology.describe());
  }
}

void validateOptions(const FibreGeneratorOptions& options) {
  if (options.fibre_count < 1) throw FibreGenerationError("the number of fibres must be at least 1");
  if (options.points_per_fibre < 2) throw FibreGenerationError("a fibre needs at least 2 points");
  if (!(options.attachment_distance > 0)) throw FibreGenerationError("the attachment distance must be positive");
  if (!(options.step_voxels > 0 && options.step_voxels <= 1)) {
    throw FibreGenerationError("the streamline step must be in (0, 1] voxels");
  }
}

void validatePatches(const TriangleMesh& surface, const AttachmentPatches& patches) {
  if (patches.origin_vertices.empty() || patches.insertion_vertices.empty()) {
    throw FibreGenerationError("both the origin and the insertion patch need at least one surface vertex");
  }
  std::vector<char> seen(static_cast<std::size_t>(surface.vertexCount()), 0);
  for (int v : patches.origin_vertices) {
    if (v < 0 || v >= surface.vertexCount()) throw FibreGenerationError("origin patch vertex index out of range");
    seen[static_cast<std::size_t>(v)] = 1;
  }
  for (int v : patches.insertion_vertices) {
    if (v < 0 || v >= surface.vertexCount()) throw FibreGenerationError("insertion patch vertex index out of range");
    if (seen[static_cast<std::size_t>(v)]) throw FibreGenerationError("the origin and insertion patches overlap");
  }
}

}  // namespace fibre_steps

using fibre_steps::CrossSection;
using fibre_steps::effectiveVoxel;
using fibre_steps::Field;
using fibre_steps::requireClosed;
using fibre_steps::runChecks;
using fibre_steps::seedingCrossSections;
using fibre_steps::solveField;
using fibre_steps::StreamlineTracer;
using fibre_steps::TracedFibres;
using fibre_steps::validateOptions;
using fibre_steps::validatePatches;

FibreGenerationResult generateFibres(const TriangleMesh& surface, const TriangleMesh* origin_bone,
                                     const TriangleMesh* insertion_bone, const FibreGeneratorOptions& options) {
  requireClosed(surface);
  const AttachmentPatches patches = findAttachmentPatches(surface, origin_bone, insertion_bone, options);
  FibreGenerationResult result = generateFibres(surface, patches, options);
  // Not a failure: the fibres still run end to end along the muscle, but where they start or end is a guess.
  for (const auto& [role, from_bone] : {std::pair{"origin", patches.origin_from_bone},
                                        std::pair{"insertion", patches.insertion_from_bone}}) {
    if (from_bone) continue;
    std::string why;
    for (const std::string& note : patches.notes)
      if (note.rfind(role, 0) == 0) why += (why.empty() ? "" : "; ") + note;
    result.warnings.push_back(std::string("no usable ") + role + " bone region (" + why + "): the " + role +
                              " patch is the muscle's end along its principal axis");
  }
  return result;
}

FibreGenerationResult generateFibres(const TriangleMesh& surface, const AttachmentPatches& patches,
                                     const FibreGeneratorOptions& options) {
  validateOptions(options);
  requireClosed(surface);
  validatePatches(surface, patches);
  FibreGenerationResult result;
  result.patches = patches;
  result.voxel_size = effectiveVoxel(surface, options);
  const Field field = solveField(surface, patches, result.voxel_size, options);
  result.inside_voxels = field.inside;
  result.dropped_voxels = field.dropped;
  result.solver_iterations = field.iterations;
  result.solver_error = field.error;
  if (field.dropped > 0) {
    result.warnings.push_back(std::to_string(field.dropped) +
                              " inside voxels lie in pieces not joining both patches and get no fibres");
  }

  // The preferred cross-section first; the next ones only if it gives fewer fibres than asked for (its seeds' streamlines
  // ran too close together or missed a patch in every reseeding round).
  constexpr std::size_t kSeedSectionAttempts = 3;
  const std::vector<CrossSection> sections = seedingCrossSections(field, options);
  const StreamlineTracer tracer(field, surface, patches, options);
  std::size_t used = 0;
  for (std::size_t attempt = 0; attempt < std::min(sections.size(), kSeedSectionAttempts); ++attempt) {
    TracedFibres traced = tracer.traceFrom(sections[attempt]);
    if (attempt == 0 || traced.fibres.size() > result.fibres.size()) {
      used = attempt;
      result.fibres = std::move(traced.fibres);
      result.failed_seeds = traced.failed_seeds;
      result.merged_fibres = traced.merged_fibres;
      result.reseed_rounds = traced.reseed_rounds;
    }
    if (result.fibres.size() >= static_cast<std::size_t>(options.fibre_count)) break;
  }
  if (used > 0) {
    std::ostringstream note;
    note << std::fixed << std::setprecision(1) << "the largest cross-section (" << sections[0].area * 1e4
         << " cm^2) gave fewer fibres than asked for: seeded on the one of " << sections[used].area * 1e4 << " cm^2";
    result.warnings.push_back(note.str());
  }
  if (result.failed_seeds > 0) {
    result.warnings.push_back(std::to_string(result.failed_seeds - result.merged_fibres) + " seeds missed a patch and " +
                              std::to_string(result.merged_fibres) + " fibres ran too close to another; reseeded " +
                              std::to_string(result.reseed_rounds) + " times");
  }
  if (result.fibres.empty()) throw FibreGenerationError("no streamline joined the two patches");
  result.checks = runChecks(surface, patches, result.fibres, field, sections[used], options);
  return result;
}

void saveFibresVtk(const std::string& path, const std::vector<Polyline>& fibres, int decimals,
                   const std::vector<std::string>& failed_checks) {
  if (decimals < 1 || decimals > 17) throw std::invalid_argument("saveFibresVtk: decimals must be in 1..17");
  std::string title = "muscle fibres, origin to insertion (metres)";
  if (!failed_checks.empty()) {
    title += std::string("; ") + kFibreChecksFailedMark;
    for (std::size_t i = 0; i < failed_checks.size(); ++i) title += (i ? "; " : "") + failed_checks[i];
    // The format's limit (kLegacyVtkTitleLimit): the rest of the list is cut.
    std::replace(title.begin(), title.end(), '\n', ' ');
    if (title.size() > kLegacyVtkTitleLimit) title = title.substr(0, kLegacyVtkTitleLimit - 3) + "...";
  }
  savePolylinesVtk(path, fibres, title, decimals);
}

}  // namespace muscle_deformation
