// A surface rebuilt from the volume it encloses, for the defects a local repair cannot undo: a non-manifold edge that
// filling holes re-creates (two lobes of a segmentation touching along an edge), a fold through itself, fins on fins.
// The triangles' signed distance field is built with OpenVDB (inside decided by flood fill from outside, so the
// triangles need not be manifold, consistently wound or free of self-intersections, only closed), its zero iso-surface
// is extracted, the largest piece kept, and it is decimated (VTK's quadric decimation, volume preserving) to about
// the triangle count the caller asks for. What it changed is measured: the volume, and how far the new surface lies
// from the old one and the old from the new.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

// The triangles enclose no volume (a sheet, a single fin, a surface open beyond repair); the message says which.
class NoEnclosedVolumeError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct LevelSetRebuildReport {
  double voxel_m = std::numeric_limits<double>::quiet_NaN();
  long input_triangles = 0;
  long iso_surface_triangles = 0;  // of the zero iso-surface, before decimation
  long triangles = 0;              // of the result
  // Why the result has another count than asked ("" when decimated as asked): decimating to it broke the surface (a
  // non-manifold edge, a flip, a crossing) or moved it more than a voxel.
  std::string decimation_note;
  double volume_m3 = std::numeric_limits<double>::quiet_NaN();  // enclosed by the result
  // Enclosed by the surface rebuilt (divergence theorem), when it has no hole and no flipped triangle for that to be
  // meaningful; absent otherwise.
  std::optional<double> input_volume_m3;
  double pieces_dropped_volume_m3 = 0;  // of iso-surface pieces apart from the largest (loose specks, split lobes)
  // Largest distance from a vertex of the result to the input's triangles: how far the rebuild moved the surface.
  double max_distance_to_input_m = std::numeric_limits<double>::quiet_NaN();
  // Largest distance from a vertex of the input to the result: what the rebuild left out (a fin's tip, a fold).
  double max_input_distance_m = std::numeric_limits<double>::quiet_NaN();

  // Relative change of the enclosed volume (result / input - 1), when the input volume was measured.
  std::optional<double> volumeChange() const;
  // e.g. "rebuilt from a level set (voxel 0.50 mm, 1,284 triangles): volume 113.10 ml against 113.04 ml (+0.05 %),
  // every vertex within 0.21 mm of the input, the input within 0.83 mm of it".
  std::string describe() const;
};

// The voxel the rebuild uses for `mesh` unless told otherwise: half its median edge, so the level set resolves what
// the triangles do; no coarser than a 40th of the thinnest side of its bounding box (coarse meshes of simple shapes) nor
// than a fifth of its mean thickness (volume over area, when it encloses one: thin plates of bone); and no finer than
// keeps the iso-surface within 8 times `target_triangles` (at least 200,000 triangles) and the narrow band within 20
// million voxels.
double levelSetVoxelFor(const TriangleMesh& mesh, long target_triangles);

// The closed, consistently outward-wound 2-manifold surface of the volume `mesh` encloses, with about
// `target_triangles` triangles (0: the iso-surface as extracted; more when decimating to that count would move the
// surface more than a voxel, said in decimation_note). `voxel_m` <= 0: levelSetVoxelFor(mesh, target_triangles).
// Throws NoEnclosedVolumeError when the triangles enclose no volume deeper than 1.5 voxels (at the voxel and at a half
// and a quarter of it), std::invalid_argument for non-finite vertices or an out-of-range index.
TriangleMesh rebuildFromLevelSet(const TriangleMesh& mesh, long target_triangles, LevelSetRebuildReport& report,
                                 double voxel_m = 0);

// `mesh` minus the volumes of `cutters` grown by `clearance_m`, as a closed, outward-wound 2-manifold surface (the
// largest piece; pieces cut off are reported), decimated to about `target_triangles` (0: as extracted) without moving
// further than a voxel from the carved iso-surface. For a bone copy that gives way to the muscles a segmentation put
// inside it: the cutters stay as they are. Every surface in the same frame and unit; `voxel_m` in that unit too. The
// report's distances are to `mesh`: max_distance_to_input_m is how far the surface moved (the deepest carve), and
// max_input_distance_m how far any input vertex is from it. Throws std::invalid_argument for a surface that is not
// closed or a voxel that is not positive, and NoEnclosedVolumeError when nothing is left.
TriangleMesh carvedFromLevelSet(const TriangleMesh& mesh, const std::vector<TriangleMesh>& cutters, double clearance_m,
                                double voxel_m, long target_triangles, LevelSetRebuildReport& report);

}  // namespace muscle_deformation
