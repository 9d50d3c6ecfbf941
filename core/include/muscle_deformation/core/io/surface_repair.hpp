// Repairing the defects real segmented surfaces have, so that they bound a volume: first locally (coincident
// vertices, degenerate and duplicated triangles, triangles on non-manifold edges, holes, loose pieces and flipped
// triangles), and where that leaves defects, or the surface crosses itself, by rebuilding it from the volume it encloses
// (io/level_set_rebuild.hpp). Only triangles that enclose no volume are refused. Off by default in the loaders (a
// surface is used as it is, or refused naming what is wrong); the scene's `repair_surfaces: true`, generate_fibres and
// prepare_scene turn it on, and every change is reported.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/io/level_set_rebuild.hpp"

#include <optional>
#include <string>

namespace muscle_deformation {

struct SurfaceRepairReport {
  long welded_vertices = 0;                 // vertices at exactly the position of another, merged into it
  long degenerate_triangles_removed = 0;    // a repeated vertex (after welding) or zero area
  long duplicate_triangles_removed = 0;     // the same three vertices as another triangle
  long non_manifold_triangles_removed = 0;  // on an edge of three or more triangles; the hole left is filled
  long hole_triangles_added = 0;            // triangles closing holes
  long shell_triangles_dropped = 0;         // in pieces apart from the largest one
  long triangles_flipped = 0;               // wound against their neighbours or the whole surface inside out
  // Set when the local repairs above left defects or a fold (pairs of triangles crossing each other) and the surface
  // was rebuilt from a level set instead: what that changed. The local repairs' counts then say what was tried first.
  std::optional<LevelSetRebuildReport> level_set;
  std::string left_by_local_repair;         // what the local repairs left, when the level set took over

  bool changed() const;
  // e.g. "vertices welded: 3, triangles on non-manifold edges removed: 2, triangles added to close holes: 4"; with
  // the level set, what the local repairs left and what the rebuild changed; "nothing changed" when the surface was
  // fine.
  std::string describe() const;
};

// The local repairs only: returns the repaired surface (vertices not used by any triangle are dropped) and fills
// `report`. The result is meant to pass checkSurfaceTopology(); callers check (closedOrRepaired rebuilds what it
// leaves from a level set).
TriangleMesh repairSurface(const TriangleMesh& mesh, SurfaceRepairReport& report);

// `mesh` exactly as it is when it is closed, 2-manifold and does not cross itself (`report` says nothing changed);
// otherwise its local repair when that is all of these, otherwise its level-set rebuild, decimated to about the triangle
// count of `mesh`. Throws LoadError naming `source` (its file), the defects found and why only when the triangles
// enclose no volume. `defects`, if given, receives what was wrong with the surface ("" when nothing was).
TriangleMesh closedOrRepaired(const TriangleMesh& mesh, const std::string& source, SurfaceRepairReport& report,
                              std::string* defects = nullptr);

// loadClosedSurface with the repair: a surface that is already closed is returned exactly as stored (`report` says
// nothing changed); any other is repaired (closedOrRepaired) and `report` says how. Throws LoadError naming the file
// and why when the triangles enclose no volume.
TriangleMesh loadRepairedClosedSurface(const std::string& path, double scale_to_metres, SurfaceRepairReport& report);

}  // namespace muscle_deformation
