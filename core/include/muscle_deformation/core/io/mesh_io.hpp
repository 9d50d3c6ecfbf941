// Reading surfaces and fibre polylines from the file formats anatomy tools produce.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <cstddef>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

// Thrown by every loader. what() names the file and the problem, and the line where the format's reader knows it,
// e.g. "muscle.obj line 12: vertex index 9 is out of range: the file defines only 8 vertices" or
// "muscle.vtk: cannot be read as legacy VTK polydata: Error reading binary cell data!".
class LoadError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Reads a triangle surface. Format from the extension (case-insensitive):
//   .stl (binary or ASCII, detected from content), .ply (ASCII or binary), .vtk (legacy POLYDATA, ASCII or BINARY,
//   POLYGONS and TRIANGLE_STRIPS), .vtp (VTK XML PolyData: any encoding and compression VTK reads, Polys and Strips),
//   .obj (v / f records; f may use v/vt/vn and negative indices). Polygons with more than three vertices are fanned
//   into triangles from their first vertex.
// STL vertices are welded (exact coordinate matches) so that topology checks are meaningful.
// Coordinates are returned as stored, multiplied by scale_to_metres. Text coordinates of a 32-bit float type are
// rounded to float in ASCII STL and PLY files and in legacy .vtk POINTS declared float (VTK's readers), not in .vtp
// or .obj files.
TriangleMesh loadTriangleMesh(const std::string& path, double scale_to_metres = 1.0);

// Like loadTriangleMesh, then requires a closed, 2-manifold, consistently oriented surface; throws LoadError
// naming the file and what is wrong (e.g. "... is not closed: 14 boundary edges") otherwise.
TriangleMesh loadClosedSurface(const std::string& path, double scale_to_metres = 1.0);

// Reads polylines (e.g. muscle fibres): .vtk legacy POLYDATA LINES (ASCII or BINARY), .vtp Lines, .obj 'l' records.
// Degenerate lines (fewer than 2 points) are returned as they are; buildMassSpringSystem skips them with a warning.
std::vector<Polyline> loadPolylines(const std::string& path, double scale_to_metres = 1.0);

// Fibre files say in their title line (the second line of a legacy VTK file) when their checks failed as they were
// generated: "...; fibre checks failed: 13 fibres instead of 64". The failures a file records, or "" when it records
// none (checks passed, or a file made elsewhere). Never throws: a file that cannot be read records nothing.
inline constexpr char kFibreChecksFailedMark[] = "fibre checks failed: ";
std::string recordedFibreCheckFailures(const std::string& path);

// The longest title line a legacy VTK file may have (the format's readers stop there).
inline constexpr std::size_t kLegacyVtkTitleLimit = 255;

// The polyline writer (fibres and any other lines, e.g. saveFibresVtk's files): legacy VTK POLYDATA with LINES, with
// `title` as its title line (one line of at most kLegacyVtkTitleLimit characters). decimals 0: binary, coordinates
// read back exactly. decimals 1..17: ASCII with every coordinate rounded to that many decimal places and trailing
// zeros dropped (small, diffable files such as the committed fibres). Throws std::invalid_argument for a bad title or
// decimals, and std::runtime_error naming the file for a line of fewer than 2 or non-finite points or a failed write.
inline constexpr char kDefaultPolylinesVtkTitle[] = "muscle_deformation polylines (metres)";
void savePolylinesVtk(const std::string& path, const std::vector<Polyline>& lines,
                      const std::string& title = kDefaultPolylinesVtkTitle, int decimals = 0);

// Binary STL, for tools and tests.
void saveTriangleMeshStl(const std::string& path, const TriangleMesh& mesh);

}  // namespace muscle_deformation
