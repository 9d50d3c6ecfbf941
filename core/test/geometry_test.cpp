// Specifications of the basic mesh geometry: bounds, topology checks, volume, normals, closest points.
#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/base/point_index.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

namespace md = muscle_deformation;

namespace {

using muscle_deformation::testing::unitCube;

// UV sphere: poles plus (stacks - 1) rings of `slices` vertices, outward winding.
md::TriangleMesh uvSphere(double radius, int slices, int stacks) {
  md::TriangleMesh mesh;
  const int rings = stacks - 1;
  mesh.vertices.resize(3, 2 + rings * slices);
  mesh.vertices.col(0) = Eigen::Vector3d(0, 0, radius);
  for (int r = 0; r < rings; ++r) {
    const double theta = M_PI * (r + 1) / stacks;
    for (int s = 0; s < slices; ++s) {
      const double phi = 2.0 * M_PI * s / slices;
      mesh.vertices.col(1 + r * slices + s) =
          radius * Eigen::Vector3d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
    }
  }
  const int south = 1 + rings * slices;
  mesh.vertices.col(south) = Eigen::Vector3d(0, 0, -radius);
  std::vector<Eigen::Vector3i> tris;
  auto at = [&](int r, int s) { return 1 + r * slices + (s % slices); };
  for (int s = 0; s < slices; ++s) tris.emplace_back(0, at(0, s), at(0, s + 1));
  for (int r = 0; r + 1 < rings; ++r) {
    for (int s = 0; s < slices; ++s) {
      tris.emplace_back(at(r, s), at(r + 1, s), at(r + 1, s + 1));
      tris.emplace_back(at(r, s), at(r + 1, s + 1), at(r, s + 1));
    }
  }
  for (int s = 0; s < slices; ++s) tris.emplace_back(south, at(rings - 1, s + 1), at(rings - 1, s));
  mesh.triangles.resize(3, static_cast<Eigen::Index>(tris.size()));
  for (std::size_t i = 0; i < tris.size(); ++i) mesh.triangles.col(static_cast<Eigen::Index>(i)) = tris[i];
  return mesh;
}

// Drops the two triangles of the top face (z = 1).
md::TriangleMesh openBox() {
  md::TriangleMesh cube = unitCube();
  md::TriangleMesh box;
  box.vertices = cube.vertices;
  box.triangles.resize(3, 10);
  box.triangles << cube.triangles.leftCols(2), cube.triangles.rightCols(8);
  return box;
}

}  // namespace

TEST(Bounds, EmptyPointSetGivesEmptyBox) { EXPECT_TRUE(md::boundsOf(md::Vertices(3, 0)).empty()); }

TEST(Bounds, SpansAllPoints) {
  md::Vertices points(3, 3);
  points << -1, 2, 0,  //
      5, -3, 1,        //
      0, 0, 7;
  const md::AlignedBox box = md::boundsOf(points);
  EXPECT_FALSE(box.empty());
  EXPECT_EQ(box.min, Eigen::Vector3d(-1, -3, 0));
  EXPECT_EQ(box.max, Eigen::Vector3d(2, 5, 7));
}

TEST(Topology, UnitCubeIsClosedManifold) {
  const md::SurfaceTopologyReport report = md::checkSurfaceTopology(unitCube());
  EXPECT_TRUE(report.closedManifold()) << report.describe();
  EXPECT_EQ(report.unused_vertices, 0);
}

TEST(Topology, SphereIsClosedManifold) {
  EXPECT_TRUE(md::checkSurfaceTopology(uvSphere(1.0, 16, 8)).closedManifold());
}

TEST(Topology, OpenBoxReportsBoundaryEdges) {
  const md::SurfaceTopologyReport report = md::checkSurfaceTopology(openBox());
  EXPECT_FALSE(report.closedManifold());
  EXPECT_EQ(report.boundary_edges, 4);
  EXPECT_EQ(report.non_manifold_edges, 0);
  EXPECT_EQ(report.inconsistent_edges, 0);
}

TEST(Topology, ThreeTrianglesOnOneEdgeAreNonManifold) {
  md::TriangleMesh fin;
  fin.vertices.resize(3, 5);
  fin.vertices << 0, 1, 0.5, 0.5, 0.5,  //
      0, 0, 1, -1, 0,                   //
      0, 0, 0, 0, 1;
  fin.triangles.resize(3, 3);
  fin.triangles << 0, 1, 0,  //
      1, 0, 1,               //
      2, 3, 4;
  const md::SurfaceTopologyReport report = md::checkSurfaceTopology(fin);
  EXPECT_EQ(report.non_manifold_edges, 1);
  EXPECT_FALSE(report.closedManifold());
}

TEST(Topology, FlippedFaceReportsInconsistentEdges) {
  md::TriangleMesh cube = unitCube();
  // Reverse both triangles of the top face: its four outer edges now run the same way as their neighbours'.
  for (int t : {2, 3}) std::swap(cube.triangles(1, t), cube.triangles(2, t));
  const md::SurfaceTopologyReport report = md::checkSurfaceTopology(cube);
  EXPECT_EQ(report.inconsistent_edges, 4);
  EXPECT_EQ(report.boundary_edges, 0);
  EXPECT_FALSE(report.closedManifold());
}

TEST(Topology, RepeatedOrOutOfRangeIndexIsDegenerate) {
  md::TriangleMesh cube = unitCube();
  cube.triangles.conservativeResize(3, 14);
  cube.triangles.col(12) << 0, 0, 1;
  cube.triangles.col(13) << 0, 1, 8;
  EXPECT_EQ(md::checkSurfaceTopology(cube).degenerate_triangles, 2);
  EXPECT_FALSE(md::checkSurfaceTopology(cube).closedManifold());
}

TEST(Topology, UnusedVerticesAreReportedButDoNotOpenTheSurface) {
  md::TriangleMesh cube = unitCube();
  cube.vertices.conservativeResize(3, 9);
  cube.vertices.col(8) = Eigen::Vector3d(5, 5, 5);
  const md::SurfaceTopologyReport report = md::checkSurfaceTopology(cube);
  EXPECT_EQ(report.unused_vertices, 1);
  EXPECT_TRUE(report.closedManifold());
}

TEST(Describe, ClosedSurfaceSaysSo) {
  EXPECT_EQ(md::SurfaceTopologyReport().describe(), "closed, consistently oriented 2-manifold");
}

TEST(Describe, NamesEveryProblemWithItsCount) {
  md::SurfaceTopologyReport report;
  report.boundary_edges = 12;
  report.non_manifold_edges = 2;
  report.inconsistent_edges = 1;
  report.degenerate_triangles = 3;
  const std::string text = report.describe();
  EXPECT_NE(text.find("12 boundary edges"), std::string::npos) << text;
  EXPECT_NE(text.find("2 non-manifold edges"), std::string::npos) << text;
  EXPECT_NE(text.find("1 inconsistently oriented edge "), std::string::npos) << text;
  EXPECT_NE(text.find("3 degenerate triangles"), std::string::npos) << text;
}

TEST(Volume, UnitCubeIsOne) { EXPECT_NEAR(md::enclosedVolume(unitCube()), 1.0, 1e-12); }

TEST(Volume, InwardWindingIsNegative) {
  md::TriangleMesh cube = unitCube();
  cube.triangles.row(1).swap(cube.triangles.row(2));
  EXPECT_NEAR(md::enclosedVolume(cube), -1.0, 1e-12);
}

TEST(Volume, FarFromOriginIsStillExact) {
  md::TriangleMesh cube = unitCube();
  cube.vertices.colwise() += Eigen::Vector3d(1e6, -2e6, 3e6);
  EXPECT_NEAR(md::enclosedVolume(cube), 1.0, 1e-9);
}

TEST(Volume, SphereMeshApproachesFourThirdsPiRCubed) {
  const double r = 0.03;
  const double exact = 4.0 / 3.0 * M_PI * r * r * r;
  const double coarse = std::abs(md::enclosedVolume(uvSphere(r, 16, 8)) - exact);
  const double fine = std::abs(md::enclosedVolume(uvSphere(r, 128, 64)) - exact);
  EXPECT_LT(fine, coarse);
  EXPECT_LT(fine / exact, 2e-3);
}

TEST(Volume, OtherVertexPositionsUseTheSameConnectivity) {
  const md::TriangleMesh cube = unitCube();
  const md::Vertices doubled = 2.0 * cube.vertices;
  EXPECT_NEAR(md::enclosedVolume(doubled, cube.triangles), 8.0, 1e-12);
}

TEST(Volume, MismatchedVertexCountThrows) {
  const md::TriangleMesh cube = unitCube();
  EXPECT_THROW(md::enclosedVolume(cube.vertices.leftCols(4), cube.triangles), std::out_of_range);
}

TEST(Normals, SphereNormalsPointRadiallyOutward) {
  const md::TriangleMesh sphere = uvSphere(2.0, 32, 16);
  const md::Vertices normals = md::vertexNormals(sphere);
  for (Eigen::Index i = 0; i < sphere.vertexCount(); ++i) {
    EXPECT_NEAR(normals.col(i).norm(), 1.0, 1e-12);
    EXPECT_GT(normals.col(i).dot(sphere.vertices.col(i).normalized()), 0.99) << "vertex " << i;
  }
}

TEST(Normals, FlatSheetNormalsAreThePlaneNormal) {
  md::TriangleMesh sheet;
  sheet.vertices.resize(3, 4);
  sheet.vertices << 0, 1, 1, 0,  //
      0, 0, 1, 1,                //
      0, 0, 0, 0;
  sheet.triangles.resize(3, 2);
  sheet.triangles << 0, 0,  //
      1, 2,                 //
      2, 3;
  const md::Vertices normals = md::vertexNormals(sheet);
  for (Eigen::Index i = 0; i < 4; ++i) EXPECT_TRUE(normals.col(i).isApprox(Eigen::Vector3d::UnitZ()));
}

TEST(Normals, UnusedVertexGetsZeroNotNaN) {
  md::TriangleMesh cube = unitCube();
  cube.vertices.conservativeResize(3, 9);
  cube.vertices.col(8).setConstant(3.0);
  EXPECT_EQ(md::vertexNormals(cube).col(8), Eigen::Vector3d::Zero());
}

TEST(ClosestPoint, AboveTheInteriorProjectsOntoThePlane) {
  const Eigen::Vector3d a(0, 0, 0), b(1, 0, 0), c(0, 1, 0);
  EXPECT_TRUE(md::closestPointOnTriangle({0.2, 0.3, 5.0}, a, b, c).isApprox(Eigen::Vector3d(0.2, 0.3, 0)));
}

TEST(ClosestPoint, BeyondACornerGivesTheCorner) {
  const Eigen::Vector3d a(0, 0, 0), b(1, 0, 0), c(0, 1, 0);
  EXPECT_TRUE(md::closestPointOnTriangle({2, -1, 1}, a, b, c).isApprox(b));
  EXPECT_LT((md::closestPointOnTriangle({-1, -1, -1}, a, b, c) - a).norm(), 1e-15);
}

TEST(ClosestPoint, BesideAnEdgeGivesThePointOnTheEdge) {
  const Eigen::Vector3d a(0, 0, 0), b(1, 0, 0), c(0, 1, 0);
  EXPECT_TRUE(md::closestPointOnTriangle({1, 1, 0}, a, b, c).isApprox(Eigen::Vector3d(0.5, 0.5, 0)));
  EXPECT_TRUE(md::closestPointOnTriangle({0.5, -2, 3}, a, b, c).isApprox(Eigen::Vector3d(0.5, 0, 0)));
}

TEST(ClosestPoint, CollinearTriangleBehavesAsASegment) {
  const Eigen::Vector3d a(0, 0, 0), b(1, 0, 0), c(2, 0, 0);
  const Eigen::Vector3d q = md::closestPointOnTriangle({1.5, 1, 0}, a, b, c);
  EXPECT_TRUE(q.allFinite());
  EXPECT_TRUE(q.isApprox(Eigen::Vector3d(1.5, 0, 0)));
}

TEST(ClosestPoint, TriangleCollapsedToAPointGivesThatPoint) {
  const Eigen::Vector3d a(1, 2, 3);
  const Eigen::Vector3d q = md::closestPointOnTriangle({4, 5, 6}, a, a, a);
  EXPECT_EQ(q, a);
}

TEST(ClosestPoint, IsNeverFartherThanAnyPointOfTheTriangle) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    const Eigen::Vector3d a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng)), c(u(rng), u(rng), u(rng));
    const Eigen::Vector3d p = 2.0 * Eigen::Vector3d(u(rng), u(rng), u(rng));
    const Eigen::Vector3d q = md::closestPointOnTriangle(p, a, b, c);
    const double d = (p - q).norm();
    for (int i = 0; i <= 20; ++i) {
      for (int j = 0; i + j <= 20; ++j) {
        const Eigen::Vector3d s = a + (b - a) * (i / 20.0) + (c - a) * (j / 20.0);
        ASSERT_LE(d, (p - s).norm() + 1e-12) << "trial " << trial;
      }
    }
  }
}

TEST(PolylineLength, SumsSegmentLengths) {
  md::Polyline line(3, 3);
  line << 0, 0, 3,  //
      0, 0, 4,      //
      0, 2, 2;
  EXPECT_DOUBLE_EQ(md::polylineLength(line), 2.0 + 5.0);
}

TEST(PolylineLength, SinglePointOrEmptyIsZero) {
  EXPECT_EQ(md::polylineLength(md::Polyline(3, 0)), 0.0);
  EXPECT_EQ(md::polylineLength(md::Polyline::Ones(3, 1)), 0.0);
}

// A fine sphere beside a few triangles a hundred times larger (a decimated flat face): the large ones are checked on
// every query instead of widening every search to their size, and every distance is still the exact one.
TEST(SurfaceDistance, MixedTriangleSizesGiveTheExactDistanceEverywhere) {
  md::TriangleMesh mesh = md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.01, 3);
  const Eigen::Index first = mesh.vertexCount();
  mesh.vertices.conservativeResize(Eigen::NoChange, first + 6);
  mesh.vertices.col(first) << -1.0, -1.0, 0.05;
  mesh.vertices.col(first + 1) << 1.0, -1.0, 0.05;
  mesh.vertices.col(first + 2) << 0.0, 1.0, 0.05;
  mesh.vertices.col(first + 3) << -1.0, -1.0, -0.3;
  mesh.vertices.col(first + 4) << 1.0, 1.0, -0.3;
  mesh.vertices.col(first + 5) << -1.0, 1.0, -0.2;
  const Eigen::Index triangles = mesh.triangleCount();
  mesh.triangles.conservativeResize(Eigen::NoChange, triangles + 2);
  mesh.triangles.col(triangles) << static_cast<int>(first), static_cast<int>(first + 1), static_cast<int>(first + 2);
  mesh.triangles.col(triangles + 1) << static_cast<int>(first + 3), static_cast<int>(first + 4),
      static_cast<int>(first + 5);
  const md::SurfaceDistance surface(mesh.vertices, mesh.triangles);
  std::srand(7);
  for (int q = 0; q < 500; ++q) {
    const Eigen::Vector3d query = 0.08 * Eigen::Vector3d::Random();
    double brute = std::numeric_limits<double>::infinity();
    for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
      brute = std::min(brute, (md::closestPointOnTriangle(query, mesh.vertices.col(mesh.triangles(0, t)),
                                                          mesh.vertices.col(mesh.triangles(1, t)),
                                                          mesh.vertices.col(mesh.triangles(2, t))) -
                               query)
                                  .norm());
    EXPECT_NEAR(surface.distance(query), brute, 1e-12) << "query " << q;
    const double within = surface.distanceWithin(query, 0.02);
    if (brute <= 0.02)
      EXPECT_NEAR(within, brute, 1e-12) << "query " << q;
    else
      EXPECT_TRUE(std::isinf(within)) << "query " << q;
  }
}
