// Repairing the small defects real segmented surfaces have, so that they bound a volume: coincident vertices,
// degenerate and duplicated triangles, triangles on non-manifold edges, holes, loose pieces and flipped triangles.
// Off by default in the loaders (a surface is used as it is, or refused naming what is wrong); the scene's
// `repair_surfaces: true` and generate_fibres turn it on, and every change is reported.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

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

  bool changed() const;
  // e.g. "welded 3 vertices, removed 2 triangles on non-manifold edges, added 4 triangles closing holes";
  // "nothing changed" when the surface was fine.
  std::string describe() const;
};

// Returns the repaired surface (vertices not used by any triangle are dropped) and fills `report`. The result is
// meant to pass checkSurfaceTopology(); callers check, since a defect too large to repair (a missing half) is left
// visible rather than hidden behind an invented surface.
TriangleMesh repairSurface(const TriangleMesh& mesh, SurfaceRepairReport& report);

// `mesh` exactly as it is when it is closed (`report` says nothing changed), otherwise its repair; throws LoadError
// naming `source` (its file), the defects found and what the repair left when it cannot close it. `defects`, if given,
// receives what made the surface not closed ("" when it was).
TriangleMesh closedOrRepaired(const TriangleMesh& mesh, const std::string& source, SurfaceRepairReport& report,
                              std::string* defects = nullptr);

// loadClosedSurface with the repair: a surface that is already closed is returned exactly as stored (`report` says
// nothing changed); any other is repaired and `report` says how. Throws LoadError naming the file, the defects found
// and what the repair left when it cannot close the surface.
TriangleMesh loadRepairedClosedSurface(const std::string& path, double scale_to_metres, SurfaceRepairReport& report);

}  // namespace muscle_deformation
