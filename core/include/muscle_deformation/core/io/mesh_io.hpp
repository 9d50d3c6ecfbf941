// Reading surfaces and fibre polylines from the file formats anatomy tools produce.
#pragma once

#include "muscle_deformation/core/geometry.hpp"

#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

// Thrown by every loader. what() names the file, the line (for text formats) or byte offset, and the problem,
// e.g. "data/fibres/sartorius.vtk line 12: expected 3 coordinates, got 2".
class LoadError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Reads a triangle surface. Format from the extension (case-insensitive):
//   .stl (binary or ASCII, detected from content), .vtk (legacy POLYDATA, ASCII or BINARY, POLYGONS; polygons
//   with more than three vertices are fanned into triangles), .vtp (VTK XML PolyData, ascii or base64 binary
//   DataArrays, Polys), .obj (v / f records; f may use v/vt/vn and negative indices).
// STL vertices are welded (exact coordinate matches) so that topology checks are meaningful.
// Coordinates are returned as stored, multiplied by scale_to_metres.
TriangleMesh loadTriangleMesh(const std::string& path, double scale_to_metres = 1.0);

// Like loadTriangleMesh, then requires a closed, 2-manifold, consistently oriented surface; throws LoadError
// naming the file and what is wrong (e.g. "... is not closed: 14 boundary edges") otherwise.
TriangleMesh loadClosedSurface(const std::string& path, double scale_to_metres = 1.0);

// Reads polylines (e.g. muscle fibres): .vtk legacy POLYDATA LINES (ASCII or BINARY), .vtp Lines, .obj 'l' records.
// Degenerate lines (fewer than 2 points) are returned as they are; buildMassSpringSystem skips them with a warning.
std::vector<Polyline> loadPolylines(const std::string& path, double scale_to_metres = 1.0);

// Writers used by tools and tests: ASCII legacy VTK POLYDATA with LINES, binary STL.
void savePolylinesVtk(const std::string& path, const std::vector<Polyline>& lines);
void saveTriangleMeshStl(const std::string& path, const TriangleMesh& mesh);

}  // namespace muscle_deformation
