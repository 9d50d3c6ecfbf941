// Specifications of the mesh and polyline loaders: what they read, and how they refuse what they cannot.
#include "muscle_deformation/core/io/mesh_io.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#ifndef MD_TEST_DATA_DIR
#define MD_TEST_DATA_DIR "test/data"
#endif

namespace md = muscle_deformation;

namespace {

std::string data(const std::string& name) { return std::string(MD_TEST_DATA_DIR) + "/" + name; }

const char* const kFemur = "/work/shared/data/raw/opensim/Geometry/femur_r.vtp";



// Unit cube [0,1]^3 as written in the cube_* files, whatever the triangulation.
void expectUnitCube(const md::TriangleMesh& mesh) {
  EXPECT_EQ(mesh.vertexCount(), 8);
  EXPECT_EQ(mesh.triangleCount(), 12);
  EXPECT_TRUE(md::checkSurfaceTopology(mesh).closedManifold()) << md::checkSurfaceTopology(mesh).describe();
  EXPECT_NEAR(md::enclosedVolume(mesh), 1.0, 1e-12);
  const md::AlignedBox box = md::boundsOf(mesh.vertices);
  EXPECT_EQ(box.min, Eigen::Vector3d::Zero());
  EXPECT_EQ(box.max, Eigen::Vector3d::Ones());
}

// The three fibres in the fibres_* files, lengths 2, 6 and 0.5.
void expectThreeFibres(const std::vector<md::Polyline>& fibres) {
  ASSERT_EQ(fibres.size(), 3u);
  EXPECT_EQ(fibres[0].cols(), 3);
  EXPECT_EQ(fibres[1].cols(), 3);
  EXPECT_EQ(fibres[2].cols(), 2);
  EXPECT_DOUBLE_EQ(md::polylineLength(fibres[0]), 2.0);
  EXPECT_DOUBLE_EQ(md::polylineLength(fibres[1]), 6.0);
  EXPECT_DOUBLE_EQ(md::polylineLength(fibres[2]), 0.5);
  EXPECT_EQ(fibres[1].col(1), Eigen::Vector3d(1, 3, 4));
}

std::string tempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() / ("md_mesh_io_test_" + name)).string();
}

}  // namespace

// ----- STL

TEST(LoadStl, AsciiTetrahedronIsWeldedIntoFourVertices) {
  const md::TriangleMesh mesh = md::loadTriangleMesh(data("tetra_ascii.stl"));
  EXPECT_EQ(mesh.vertexCount(), 4);
  EXPECT_EQ(mesh.triangleCount(), 4);
  EXPECT_TRUE(md::checkSurfaceTopology(mesh).closedManifold());
  EXPECT_NEAR(md::enclosedVolume(mesh), 1.0 / 6.0, 1e-12);
}

TEST(LoadStl, BinaryStartingWithSolidIsReadAsBinary) {
  const md::TriangleMesh mesh = md::loadTriangleMesh(data("tetra_binary.stl"));
  EXPECT_EQ(mesh.vertexCount(), 4);
  EXPECT_EQ(mesh.triangleCount(), 4);
  EXPECT_NEAR(md::enclosedVolume(mesh), 1.0 / 6.0, 1e-7);
}

TEST(LoadStl, TruncatedBinaryNamesDeclaredAndActualSize) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("truncated_binary.stl")); });
  EXPECT_CONTAINS(msg, "truncated_binary.stl");
  EXPECT_CONTAINS(msg, "declares 4 triangles");
  EXPECT_CONTAINS(msg, "284 bytes");
  EXPECT_CONTAINS(msg, "254 bytes");
}

TEST(LoadStl, EmptyFileIsAnError) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("empty.stl")); });
  EXPECT_CONTAINS(msg, "empty.stl: file is empty");
}

TEST(LoadStl, SolidWithoutFacetsHasZeroTrianglesError) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("no_facets.stl")); });
  EXPECT_CONTAINS(msg, "no_facets.stl");
  EXPECT_CONTAINS(msg, "no triangles");
}

TEST(LoadStl, NanCoordinateInBinaryIsRejected) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("nan_binary.stl")); });
  EXPECT_CONTAINS(msg, "nan_binary.stl: triangle 2 has a NaN or infinite vertex coordinate");
}

TEST(LoadStl, AsciiVertexWithTwoCoordinatesNamesLine) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("bad_vertex.stl")); });
  EXPECT_CONTAINS(msg, "bad_vertex.stl: cannot be read as STL:");
  EXPECT_CONTAINS(msg, "line 5");  // VTK's STL reader counts lines
  EXPECT_CONTAINS(msg, "error reading STL vertex");
}

TEST(SaveStl, BinaryRoundTripKeepsTopologyAndCoordinates) {
  const md::TriangleMesh original = md::loadTriangleMesh(data("cube.obj"));
  const std::string path = tempPath("cube.stl");
  md::saveTriangleMeshStl(path, original);
  const md::TriangleMesh copy = md::loadTriangleMesh(path);
  std::remove(path.c_str());
  expectUnitCube(copy);
}

// ----- OBJ

TEST(LoadObj, CubeQuadsAreFannedIntoTwelveTriangles) { expectUnitCube(md::loadTriangleMesh(data("cube.obj"))); }

TEST(LoadObj, EveryFaceIndexFormAndNegativeIndicesGiveTheSameCube) {
  const md::TriangleMesh plain = md::loadTriangleMesh(data("cube.obj"));
  const md::TriangleMesh forms = md::loadTriangleMesh(data("cube_index_forms.obj"));
  expectUnitCube(forms);
  EXPECT_EQ(forms.triangles, plain.triangles);
}

TEST(LoadObj, IndexOutOfRangeNamesFileAndLine) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("bad_index.obj")); });
  EXPECT_CONTAINS(msg, "bad_index.obj line 12: vertex index 9 is out of range: the file defines only 8 vertices");
}

TEST(LoadObj, NanCoordinateNamesLine) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("nan_coordinate.obj")); });
  EXPECT_CONTAINS(msg, "nan_coordinate.obj line 3: vertex coordinate 'nan' is not finite");
}

TEST(LoadObj, NonNumericCoordinateNamesLineAndToken) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("non_numeric.obj")); });
  EXPECT_CONTAINS(msg, "non_numeric.obj line 3: vertex coordinate '1.0x' is not a number");
}

TEST(LoadObj, PolylineFileIsNotASurface) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("fibres.obj")); });
  EXPECT_CONTAINS(msg, "fibres.obj: contains no triangles, only 3 lines");
}

// ----- legacy VTK

TEST(LoadVtk, AsciiCubeSkipsVerticesAndAttributeData) { expectUnitCube(md::loadTriangleMesh(data("cube_ascii.vtk"))); }

TEST(LoadVtk, BinaryBigEndianCube) { expectUnitCube(md::loadTriangleMesh(data("cube_binary.vtk"))); }

TEST(LoadVtk, Version51OffsetsAndConnectivityAscii) {
  expectUnitCube(md::loadTriangleMesh(data("cube_ascii_v51.vtk")));
}

TEST(LoadVtk, Version51OffsetsAndConnectivityBinary) {
  expectUnitCube(md::loadTriangleMesh(data("cube_binary_v51.vtk")));
}

// VTK's legacy reader gives no line numbers: the messages name the file and the problem.
TEST(LoadVtk, BadCoordinateCountNamesFileAndProblem) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("bad_coordinates.vtk")); });
  EXPECT_CONTAINS(msg, "bad_coordinates.vtk: cannot be read as legacy VTK polydata:");
  EXPECT_CONTAINS(msg, "mismatch of datasize with declaration");
}

TEST(LoadVtk, NonNumericCoordinateNamesFileAndProblem) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("non_numeric.vtk")); });
  EXPECT_CONTAINS(msg, "non_numeric.vtk: cannot be read as legacy VTK polydata:");
  EXPECT_CONTAINS(msg, "Error reading ascii data");
}

// VTK's reader accepts the id; the loader's own check of the output refuses it.
TEST(LoadVtk, IndexOutOfRangeNamesPolygonAndPoint) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("bad_index.vtk")); });
  EXPECT_CONTAINS(msg, "bad_index.vtk: polygon 5 refers to point 8 but there are only 8 points (valid: 0 to 7)");
}

TEST(LoadVtk, ListSizeThatDoesNotMatchTheCellsIsAnError) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("wrong_count.vtk")); });
  EXPECT_CONTAINS(msg, "wrong_count.vtk: cannot be read as legacy VTK polydata:");
  EXPECT_CONTAINS(msg, "Unrecognized keyword: 5");  // the cell left over once the declared size is read
}

// VTK 9.1's legacy reader crashes a step after this error if it is let go on; the loader stops it at the message.
TEST(LoadVtk, TruncatedBinaryIsAnError) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("truncated_binary.vtk")); });
  EXPECT_CONTAINS(msg, "truncated_binary.vtk: cannot be read as legacy VTK polydata:");
  EXPECT_CONTAINS(msg, "Error reading binary cell data");
}

TEST(LoadVtk, FibreFileIsNotASurface) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("fibres_ascii.vtk")); });
  EXPECT_CONTAINS(msg, "read it with loadPolylines");
}

// ----- VTK XML PolyData

TEST(LoadVtp, AsciiCubeIgnoresPointData) { expectUnitCube(md::loadTriangleMesh(data("cube.vtp"))); }

TEST(LoadVtp, Base64WithUInt32HeaderEncodedSeparately) {
  expectUnitCube(md::loadTriangleMesh(data("cube_base64.vtp")));
}

TEST(LoadVtp, Base64WithUInt64HeaderEncodedWithTheData) {
  expectUnitCube(md::loadTriangleMesh(data("cube_base64_uint64.vtp")));
}

TEST(LoadVtp, ZlibCompressedMultiBlockArrays) { expectUnitCube(md::loadTriangleMesh(data("cube_zlib.vtp"))); }

TEST(LoadVtp, AppendedRawData) { expectUnitCube(md::loadTriangleMesh(data("cube_appended_raw.vtp"))); }

TEST(LoadVtp, AppendedBase64CompressedData) {
  expectUnitCube(md::loadTriangleMesh(data("cube_appended_base64_zlib.vtp")));
}

// VTK reads LZ4-compressed files; this one claims LZ4 but its arrays are not compressed.
TEST(LoadVtp, DataThatDoesNotMatchItsCompressorIsAnError) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("cube_lz4.vtp")); });
  EXPECT_CONTAINS(msg, "cube_lz4.vtp: cannot be read as VTK XML PolyData:");
  EXPECT_CONTAINS(msg, "compression header");
}

TEST(LoadVtp, PointsArrayWithTooFewValuesNamesFileAndProblem) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("bad_points.vtp")); });
  EXPECT_CONTAINS(msg, "bad_points.vtp: cannot be read as VTK XML PolyData:");
  EXPECT_CONTAINS(msg, "Cannot read points array from Points in piece 0");
}

TEST(LoadVtp, UnclosedElementNamesItsLine) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("unclosed.vtp")); });
  EXPECT_CONTAINS(msg, "unclosed.vtp: cannot be read as VTK XML PolyData:");
  EXPECT_CONTAINS(msg, "line 23");  // the XML parser counts lines
  EXPECT_CONTAINS(msg, "mismatched tag");
}

TEST(LoadVtp, OpenSimFemurLoads) {
  if (!std::filesystem::exists(kFemur)) GTEST_SKIP() << kFemur << " not present";
  const md::TriangleMesh femur = md::loadTriangleMesh(kFemur);
  EXPECT_EQ(femur.vertexCount(), 456);
  EXPECT_EQ(femur.triangleCount(), 908);
  // Its Float32 points are written as decimal text, and the text's value is returned, not the nearest float.
  EXPECT_EQ(femur.vertices(0, 0), -0.002485);
  const md::AlignedBox box = md::boundsOf(femur.vertices);
  EXPECT_GT((box.max - box.min).maxCoeff(), 0.3);  // a femur is roughly 0.4 m long
  EXPECT_LT((box.max - box.min).maxCoeff(), 0.6);
}

// ----- PLY

TEST(LoadPly, AsciiAndBinaryCubesGiveTheObjCubesTriangles) {
  const md::TriangleMesh obj = md::loadTriangleMesh(data("cube.obj"));
  for (const char* name : {"cube_ascii.ply", "cube_binary.ply"}) {
    const md::TriangleMesh ply = md::loadTriangleMesh(data(name));
    expectUnitCube(ply);
    EXPECT_EQ(ply.triangles, obj.triangles) << name;
    EXPECT_EQ(ply.vertices, obj.vertices) << name;
  }
}

TEST(LoadPly, NoVertexCoordinatesIsAnError) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("cube.ply")); });
  EXPECT_CONTAINS(msg, "cube.ply: cannot be read as PLY: Cannot read geometry");
}

TEST(LoadPly, FacesCutShortAreAnError) {
  std::ifstream in(data("cube_binary.ply"), std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string path = tempPath("cut_short.ply");
  std::ofstream(path, std::ios::binary) << bytes.substr(0, bytes.size() - 30);
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([&] { md::loadTriangleMesh(path); });
  std::remove(path.c_str());
  EXPECT_CONTAINS(msg, "cut_short.ply: cannot be read as PLY:");
  EXPECT_CONTAINS(msg, "Premature EOF");
}

TEST(LoadPly, IsNotAFibreFormat) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadPolylines(data("cube_ascii.ply")); });
  EXPECT_CONTAINS(msg, "PLY files hold triangles, not polylines");
}

// ----- polylines

TEST(LoadPolylines, AsciiVtkLines) { expectThreeFibres(md::loadPolylines(data("fibres_ascii.vtk"))); }

TEST(LoadPolylines, BinaryVtkLines) { expectThreeFibres(md::loadPolylines(data("fibres_binary.vtk"))); }

TEST(LoadPolylines, VtpLines) { expectThreeFibres(md::loadPolylines(data("fibres.vtp"))); }

TEST(LoadPolylines, ObjLineRecords) { expectThreeFibres(md::loadPolylines(data("fibres.obj"))); }

TEST(LoadPolylines, SurfaceFileHasNoLines) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadPolylines(data("cube_ascii.vtk")); });
  EXPECT_CONTAINS(msg, "cube_ascii.vtk: contains no lines");
}

TEST(LoadPolylines, StlIsRejected) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadPolylines(data("tetra_ascii.stl")); });
  EXPECT_CONTAINS(msg, "STL files hold triangles, not polylines");
}

TEST(LoadPolylines, ScaleConvertsMillimetresToMetres) {
  const auto fibres = md::loadPolylines(data("fibres.obj"), 0.001);
  ASSERT_EQ(fibres.size(), 3u);
  EXPECT_DOUBLE_EQ(md::polylineLength(fibres[1]), 0.006);
}

namespace {

// The three test fibres as ASCII legacy VTK with `coordinate` as the y of point 4 (line 10) and 'nan' as the z of
// point 6 (line 12), POINTS of type `type`.
std::string asciiFibresWith(const std::string& name, const std::string& coordinate, const std::string& type = "double") {
  const std::string path = tempPath(name);
  std::ofstream(path) << "# vtk DataFile Version 3.0\nthree fibres\nASCII\nDATASET POLYDATA\nPOINTS 8 " << type
                      << "\n0 0 0\n0 0 1\n0 0 2\n1 0 0\n1 " << coordinate << " 4\n1 3 5\n0 1 nan\n0 1 0.5\n"
                      << "LINES 3 11\n3 0 1 2\n3 3 4 5\n2 6 7\n";
  return path;
}

}  // namespace

// VTK's reader stops at such a token with "Possible mismatch of datasize with declaration"; the loader names the first.
TEST(LoadPolylines, NonFiniteCoordinateInAsciiVtkNamesFileLineAndPoint) {
  for (const std::string coordinate : {"nan", "inf", "-inf", "NaN", "Infinity", "1e999"}) {
    SCOPED_TRACE(coordinate);
    const std::string path = asciiFibresWith("non_finite.vtk", coordinate);
    const std::string msg = md::testing::errorMessageOf<md::LoadError>([&] { md::loadPolylines(path); });
    std::remove(path.c_str());
    EXPECT_CONTAINS(msg, "non_finite.vtk line 10: point 4 has a NaN or infinite coordinate: '" + coordinate + "'");
    EXPECT_EQ(msg.find("mismatch"), std::string::npos) << msg;
  }
}

TEST(LoadPolylines, CoordinateBeyondTheDeclaredFloatRangeInAsciiVtkNamesLineAndPoint) {
  const std::string path = asciiFibresWith("beyond_float.vtk", "1e39", "float");
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([&] { md::loadPolylines(path); });
  std::remove(path.c_str());
  EXPECT_CONTAINS(msg, "beyond_float.vtk line 10: point 4 has a coordinate beyond the range of float");
}

TEST(LoadPolylines, NanInBinaryVtkNamesFileAndPoint) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadPolylines(data("fibres_nan_binary.vtk")); });
  EXPECT_CONTAINS(msg, "fibres_nan_binary.vtk: point 4 has a NaN or infinite coordinate");
}

TEST(LoadPolylines, NanInBinaryVtpNamesFileAndPoint) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadPolylines(data("fibres_nan_binary.vtp")); });
  EXPECT_CONTAINS(msg, "fibres_nan_binary.vtp: point 4 has a NaN or infinite coordinate");
}

TEST(LoadPolylines, NanInObjNamesFileAndLine) {
  const std::string path = tempPath("non_finite.obj");
  std::ofstream(path) << "v 0 0 0\nv 0 0 1\nv 1 nan 0\nl 1 2 3\n";
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([&] { md::loadPolylines(path); });
  std::remove(path.c_str());
  EXPECT_CONTAINS(msg, "non_finite.obj line 3: vertex coordinate 'nan' is not finite");
}

TEST(SavePolylines, VtkRoundTripIsExact) {
  std::vector<md::Polyline> lines(2);
  lines[0] = md::Polyline::Random(3, 5);
  lines[1] = md::Polyline::Random(3, 2);
  const std::string path = tempPath("fibres.vtk");
  md::savePolylinesVtk(path, lines);
  const auto copy = md::loadPolylines(path);
  std::remove(path.c_str());
  ASSERT_EQ(copy.size(), 2u);
  EXPECT_EQ(copy[0], lines[0]);
  EXPECT_EQ(copy[1], lines[1]);
}

// ----- closed surfaces and general errors

TEST(LoadClosedSurface, AcceptsClosedCube) { expectUnitCube(md::loadClosedSurface(data("cube.obj"))); }

TEST(LoadClosedSurface, OpenBoxNamesFileAndBoundaryEdges) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadClosedSurface(data("open_box.obj")); });
  EXPECT_CONTAINS(msg, "open_box.obj");
  EXPECT_CONTAINS(msg, "4 boundary edges");
}

TEST(LoadClosedSurface, NonManifoldEdgeIsRejected) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadClosedSurface(data("nonmanifold.obj")); });
  EXPECT_CONTAINS(msg, "nonmanifold.obj");
  EXPECT_CONTAINS(msg, "1 non-manifold edge");
}

TEST(LoadClosedSurface, FlippedFaceIsRejected) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadClosedSurface(data("flipped.obj")); });
  EXPECT_CONTAINS(msg, "flipped.obj");
  EXPECT_CONTAINS(msg, "4 inconsistently oriented edges");
}

TEST(LoadErrors, MissingFileNamesPath) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("no_such_file.stl")); });
  EXPECT_CONTAINS(msg, "no_such_file.stl: file not found");
}

TEST(LoadErrors, UnknownExtensionListsSupportedFormats) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("cube.off")); });
  EXPECT_CONTAINS(msg, "cube.off: unknown file extension '.off'; supported: .stl, .vtk, .vtp, .obj, .ply");
}

// Every problem is in the LoadError; VTK's readers print nothing of their own.
TEST(LoadErrors, VtkReadersPrintNothing) {
  for (const char* name : {"bad_vertex.stl", "empty.stl", "bad_coordinates.vtk", "non_numeric.vtk", "wrong_count.vtk",
                           "truncated_binary.vtk", "bad_points.vtp", "cube_lz4.vtp", "unclosed.vtp", "cube.ply",
                           "fibres_nan_binary.vtk", "fibres_nan_binary.vtp"}) {
    ::testing::internal::CaptureStderr();
    ::testing::internal::CaptureStdout();
    EXPECT_THROW(md::loadTriangleMesh(data(name)), md::LoadError) << name;
    const std::string out = ::testing::internal::GetCapturedStdout();
    const std::string err = ::testing::internal::GetCapturedStderr();
    EXPECT_EQ(out + err, "") << name;
  }
}

TEST(LoadErrors, DirectoryIsNotAMesh) {
  const std::string path = tempPath("directory.obj");
  std::filesystem::create_directories(path);
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([&] { md::loadTriangleMesh(path); });
  std::filesystem::remove(path);
  EXPECT_CONTAINS(msg, "directory.obj: is a directory");
}

TEST(LoadErrors, ExtensionIsCaseInsensitive) {
  const std::string path = tempPath("CUBE.OBJ");
  std::filesystem::copy_file(data("cube.obj"), path, std::filesystem::copy_options::overwrite_existing);
  const md::TriangleMesh mesh = md::loadTriangleMesh(path);
  std::remove(path.c_str());
  expectUnitCube(mesh);
}

TEST(LoadErrors, NonPositiveScaleIsRejected) {
  const std::string msg = md::testing::errorMessageOf<md::LoadError>([] { md::loadTriangleMesh(data("cube.obj"), -0.001); });
  EXPECT_CONTAINS(msg, "scale_to_metres must be a positive finite number");
}

TEST(Scale, MillimetreCubeBecomesOneMillimetre) {
  const md::TriangleMesh mesh = md::loadTriangleMesh(data("cube.obj"), 0.001);
  EXPECT_NEAR(md::boundsOf(mesh.vertices).max.x(), 0.001, 1e-18);
  EXPECT_NEAR(md::enclosedVolume(mesh), 1e-9, 1e-21);
}

TEST(LoadPolylines, ASinglePointLineIsKeptForTheModelToSkipLikeAZeroLengthOne) {
  // One rule for degenerate fibres: the loader keeps them and the model skips them with a warning (it used to abort
  // loading for a single point while a zero-length fibre was skipped).
  const std::string path = (std::filesystem::temp_directory_path() / "md_single_point_line.vtk").string();
  std::ofstream(path) << "# vtk DataFile Version 3.0\nfibres\nASCII\nDATASET POLYDATA\nPOINTS 3 double\n"
                         "0 0 0\n0 0 1\n5 5 5\nLINES 2 5\n2 0 1\n1 2\n";
  const std::vector<md::Polyline> lines = md::loadPolylines(path);
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0].cols(), 2);
  EXPECT_EQ(lines[1].cols(), 1);
}
