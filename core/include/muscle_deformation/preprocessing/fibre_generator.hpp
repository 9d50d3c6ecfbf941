// Fibres for any closed muscle surface, after Choi & Blemker 2013: a harmonic (Laplace) field is solved on the voxels
// inside the surface, 0 on the origin patch and 1 on the insertion patch, zero flux elsewhere; fibres are streamlines
// of its gradient, seeded evenly over one of the field's iso-surfaces (a cross-section of the muscle: by default its
// largest, in the belly), oriented origin -> insertion.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

// Bad input or a surface the generator cannot work on; the message says what and how to fix it.
class FibreGenerationError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Which iso-surface of the field the seeds are spread over (and the coverage check measures).
enum class SeedSection {
  // The largest of the iso-surfaces at 10, 15, ... 90 % of the muscle's volume from the origin: the belly. A thin
  // tendon carries most of the field's drop (like a narrow conductor), so elsewhere its mid-value falls there.
  largest,
  // The field's 0.5 iso-surface: how the bundled fibres (data/fibres/) were made.
  mid_value,
};

struct FibreGeneratorOptions {
  int fibre_count = 64;
  SeedSection seed_section = SeedSection::largest;
  double voxel_size = 0.002;        // m: the coarsest voxel edge used
  long min_inside_voxels = 50000;   // small muscles get finer voxels until their interior holds this many (0 = off)
  long max_grid_cells = 12000000;   // refuse grids larger than this (memory), rather than thrash
  double attachment_distance = 0.005;  // m: bone patch = vertices within this of the muscle's closest approach
  double max_attachment_gap = 0.02;    // m: a bone whose closest approach is farther is "too far" (fallback)
  int min_patch_vertices = 6;          // smaller bone regions are not used (fallback)
  double bone_patch_reach = 0.25;      // a bone region must reach this close (fraction of length) to its end
  double end_fraction = 0.05;          // fallback patch: vertices within this fraction of the length from an end
  double patch_gap_fraction = 0.05;    // bone regions are cut apart along the principal axis, this far apart
  int points_per_fibre = 30;           // output resampling by arc length (>= 2)
  double min_separation = 2e-5;        // m: of two fibres closer than this, one is reseeded; 2x the 10 um precision
                                       // of saveFibresVtk, so fibres stay apart once written
  double step_voxels = 0.4;            // streamline RK4 step, in voxels
};

// Where the field is 0 (origin) and 1 (insertion): surface vertex indices, disjoint, both non-empty.
struct AttachmentPatches {
  std::vector<int> origin_vertices;
  std::vector<int> insertion_vertices;
  bool origin_from_bone = false;     // false: fallback (an end along the principal axis)
  bool insertion_from_bone = false;
  std::vector<std::string> notes;    // why a fallback was used, etc.
};

// Patches from the surface regions nearest the bones (either bone may be null). First the muscle's principal axis is
// oriented: origin at the end that puts each given bone nearer its own end (no bones: origin = the end with greater Z,
// i.e. proximal in a Z-up frame). A bone's patch is the set of vertices within attachment_distance of the muscle's
// closest approach to it, cut to its half of the muscle; a bone that is missing, too far, or whose region is too small
// or does not reach its end is replaced by the tip of the muscle at that end (end_fraction of the length).
// Throws FibreGenerationError on an empty surface.
AttachmentPatches findAttachmentPatches(const TriangleMesh& surface, const TriangleMesh* origin_bone,
                                        const TriangleMesh* insertion_bone, const FibreGeneratorOptions& options = {});

// Measured properties of a fibre set (lengths in m, areas in m^2).
struct FibreCheckReport {
  int fibre_count = 0;
  double min_length = 0, max_length = 0, mean_length = 0;
  double tolerance = 0;             // m: one voxel; points may lie this far outside, ends this far (x2) from patches
  long points = 0;
  long points_outside = 0;          // outside the surface by more than `tolerance`
  double max_outside_distance = 0;  // largest distance outside the surface of any point
  int bad_starts = 0, bad_ends = 0; // fibres not starting near the origin patch / not ending near the insertion patch
  double max_start_distance = 0, max_end_distance = 0;  // to the respective patch
  double min_pairwise_distance = 0; // smallest distance between two different fibres (segment to segment)
  double cross_section_area = 0;    // area of the seeding cross-section (the field's iso-surface at section_level)
  double section_level = 0;         // field value of the seeding cross-section (0 origin, 1 insertion)
  double section_volume_fraction = 0;  // share of the muscle's volume between the origin and that cross-section
  double coverage_radius = 0;       // 1.5 * sqrt(area / (pi * fibres)): a disc per fibre, with overlap
  double coverage = 0;              // fraction of the cross-section within coverage_radius of a fibre
  double max_gap = 0;               // largest distance of a cross-section point to its nearest fibre
  double min_coverage = 0.9;        // required coverage
  std::vector<std::string> failures;

  bool passed() const { return failures.empty(); }
  std::string describe() const;  // one line with every number, then the failures
};

struct FibreGenerationResult {
  std::vector<Polyline> fibres;  // origin -> insertion, scene units (m)
  AttachmentPatches patches;
  double voxel_size = 0;         // m, as used
  long inside_voxels = 0;        // in the solved region
  long dropped_voxels = 0;       // inside voxels in pieces touching neither or only one patch (field undefined)
  int solver_iterations = 0;
  double solver_error = 0;
  int failed_seeds = 0;          // streamlines that missed a patch or ran too close to another, all reseeded
  int merged_fibres = 0;         // of those, the ones too close to another fibre
  int reseed_rounds = 0;
  FibreCheckReport checks;
  std::vector<std::string> warnings;
};

// Generates options.fibre_count fibres inside `surface` (closed, 2-manifold; FibreGenerationError otherwise) and
// checks them. Bones are optional (see findAttachmentPatches).
FibreGenerationResult generateFibres(const TriangleMesh& surface, const TriangleMesh* origin_bone,
                                     const TriangleMesh* insertion_bone, const FibreGeneratorOptions& options = {});

// Same, with patches chosen by the caller (e.g. painted in a modelling tool).
FibreGenerationResult generateFibres(const TriangleMesh& surface, const AttachmentPatches& patches,
                                     const FibreGeneratorOptions& options = {});

// The checks of generateFibres on any fibre set (e.g. a committed file), with the same options and patches.
FibreCheckReport checkFibres(const TriangleMesh& surface, const AttachmentPatches& patches,
                             const std::vector<Polyline>& fibres, const FibreGeneratorOptions& options = {});

// Generalised winding number of a closed surface at p: ~1 inside, ~0 outside (any orientation gives |w|).
double windingNumber(const TriangleMesh& surface, const Eigen::Vector3d& p);

// ASCII legacy VTK polylines (savePolylinesVtk's ASCII form, io/mesh_io.hpp) with coordinates rounded to `decimals`
// places, 1..17 (5 = 10 um in metres, 1/50 of the finest voxel used for the bundled muscles): the fibre files are
// committed, and exact coordinates would more than double their size for no useful precision. Checks that failed are
// written into the file's title line (see recordedFibreCheckFailures in io/mesh_io.hpp), so that whoever loads the
// file hears of them.
void saveFibresVtk(const std::string& path, const std::vector<Polyline>& fibres, int decimals = 5,
                   const std::vector<std::string>& failed_checks = {});

}  // namespace muscle_deformation
