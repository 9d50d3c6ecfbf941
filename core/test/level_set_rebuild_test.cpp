// The level-set rebuild: the surface of the volume some triangles enclose, for the defects a local repair cannot undo,
// with what it changed measured. And the fold detection that sends a closed surface crossing itself to it.
#include "muscle_deformation/core/base/inside_test.hpp"
#include "muscle_deformation/core/base/self_intersection.hpp"
#include "muscle_deformation/core/io/level_set_rebuild.hpp"
#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/io/surface_repair.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace md = muscle_deformation;

namespace {

std::string data(const std::string& name) { return std::string(MD_TEST_DATA_DIR) + "/" + name; }

int addVertex(md::TriangleMesh& mesh, const Eigen::Vector3d& position) {
  mesh.vertices.conservativeResize(Eigen::NoChange, mesh.vertexCount() + 1);
  mesh.vertices.col(mesh.vertexCount() - 1) = position;
  return static_cast<int>(mesh.vertexCount() - 1);
}

void addTriangle(md::TriangleMesh& mesh, int a, int b, int c) {
  mesh.triangles.conservativeResize(Eigen::NoChange, mesh.triangleCount() + 1);
  mesh.triangles.col(mesh.triangleCount() - 1) << a, b, c;
}

double meanEdge(const md::TriangleMesh& mesh) {
  double sum = 0;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    for (int k = 0; k < 3; ++k)
      sum += (mesh.vertices.col(mesh.triangles(k, t)) - mesh.vertices.col(mesh.triangles((k + 1) % 3, t))).norm();
  return sum / static_cast<double>(3 * mesh.triangleCount());
}

// A 30 mm icosphere (1,280 triangles) with a fin of three triangles hanging from one of its edges: one on the edge,
// the other two a strip beyond it. The local repair removes the triangles on the edge and fills the hole, but the
// strip is left joined at a vertex and "filled" into a flat double layer whose edges are shared by three triangles.
md::TriangleMesh sphereWithAStripFin() {
  md::TriangleMesh mesh = md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.03, 3);
  const int a = mesh.triangles(0, 1), b = mesh.triangles(1, 1);
  const Eigen::Vector3d middle = 0.5 * (mesh.vertices.col(a) + mesh.vertices.col(b));
  const int t1 = addVertex(mesh, 1.3 * middle), t2 = addVertex(mesh, 1.3 * Eigen::Vector3d(mesh.vertices.col(b))),
            t3 = addVertex(mesh, 1.5 * middle);
  addTriangle(mesh, a, b, t1);
  addTriangle(mesh, b, t2, t1);
  addTriangle(mesh, t1, t2, t3);
  return mesh;
}

// The same icosphere, closed and 2-manifold, with one vertex dragged two and a half edges sideways (and a fifth of
// one in): its fan of triangles folds over the ring around it and crosses it, as a smoothed segmentation can.
md::TriangleMesh sphereWithAFold() {
  md::TriangleMesh mesh = md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.03, 3);
  const Eigen::Vector3d v = mesh.vertices.col(0);
  const Eigen::Vector3d normal = v.normalized();
  const Eigen::Vector3d sideways = normal.cross(Eigen::Vector3d::UnitZ()).normalized();
  const double edge = meanEdge(mesh);
  mesh.vertices.col(0) = v + 2.5 * edge * sideways - 0.2 * edge * normal;
  return mesh;
}

}  // namespace

TEST(SelfIntersection, AClosedSphereDoesNotCrossItself) {
  const md::SelfIntersectionReport report = md::findSelfIntersections(md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.03, 3));
  EXPECT_FALSE(report.crosses());
  EXPECT_EQ(report.describe(), "");
}

TEST(SelfIntersection, AVertexDraggedPastItsNeighboursFoldsTheSurfaceThroughItself) {
  const md::TriangleMesh folded = sphereWithAFold();
  ASSERT_TRUE(md::checkSurfaceTopology(folded).closedManifold());  // no edge count shows it
  const md::SelfIntersectionReport report = md::findSelfIntersections(folded);
  EXPECT_GT(report.crossing_pairs, 0);
  EXPECT_CONTAINS(report.describe(), "of triangles cross each other");
  EXPECT_LT((report.example - Eigen::Vector3d(folded.vertices.col(0))).norm(), 3 * meanEdge(folded));
}

// At a voxel of a twentieth of the radius the trilinear field of a convex shape lies above its distance, so the surface
// shrinks a little: measured 0.24 % of the volume as extracted, 0.41 % once decimated back to 1,280 triangles.
TEST(LevelSetRebuild, AClosedSphereComesBackWithinHalfAPercentOfItsVolumeAndATenthOfAVoxelOfItsSurface) {
  const md::TriangleMesh sphere = md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.03, 3);
  md::LevelSetRebuildReport report;
  const md::TriangleMesh rebuilt = md::rebuildFromLevelSet(sphere, sphere.triangleCount(), report);
  EXPECT_TRUE(md::checkSurfaceTopology(rebuilt).closedManifold());
  ASSERT_TRUE(report.volumeChange().has_value());
  EXPECT_LT(std::abs(*report.volumeChange()), 5e-3);
  EXPECT_LT(report.max_distance_to_input_m, 0.1 * report.voxel_m);
  EXPECT_NEAR(static_cast<double>(report.triangles), 1280.0, 128.0);
}

TEST(LevelSetRebuild, AMillimetreSizedPartInMetresComesBackLikeALargeOne) {
  // A 1 mm sphere 0.4 m from the origin (a small part of a scene in metres): voxels of a few micrometres, which OpenVDB
  // refuses as a transform's scale, and coordinates thousands of voxels from the origin.
  const md::TriangleMesh sphere = md::makeSphereMesh(Eigen::Vector3d(0.4, -0.2, 0.1), 0.001, 3);
  md::LevelSetRebuildReport report;
  const md::TriangleMesh rebuilt = md::rebuildFromLevelSet(sphere, sphere.triangleCount(), report);
  EXPECT_LT(report.voxel_m, 1e-4);
  EXPECT_TRUE(md::checkSurfaceTopology(rebuilt).closedManifold());
  ASSERT_TRUE(report.volumeChange().has_value());
  EXPECT_LT(std::abs(*report.volumeChange()), 1e-2);
  EXPECT_LE(report.max_distance_to_input_m, report.voxel_m);
}

TEST(LevelSetRebuild, TheVoxelIsHalfTheMedianEdgeUnlessTheShapeIsThinnerThanFortyOfThem) {
  const md::TriangleMesh sphere = md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.03, 3);
  EXPECT_NEAR(md::levelSetVoxelFor(sphere, 1280), 0.06 / 40, 1e-9);  // edges of about 4 mm: the 60 mm width decides
  const md::TriangleMesh fine = md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.03, 5);
  EXPECT_LT(md::levelSetVoxelFor(fine, 20480), 0.06 / 40);
  EXPECT_GT(md::levelSetVoxelFor(fine, 20480), 0.25 * meanEdge(fine));
}

TEST(LevelSetRebuild, AThinPlateTurnedInItsBoxGetsAFifthOfItsMeanThicknessAsItsVoxel) {
  // 100 x 100 x 4 mm turned 45 degrees about a diagonal: its box is wide on every side, its volume over its area is
  // 1.85 mm (half its thickness, less its rim).
  md::TriangleMesh plate = md::makeBoxMesh(Eigen::Vector3d::Zero(), Eigen::Vector3d(0.1, 0.1, 0.004), 0.004);
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(M_PI / 4, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
  plate.vertices = turn * plate.vertices;
  const double area = 2 * (0.1 * 0.1 + 2 * 0.1 * 0.004);
  EXPECT_NEAR(md::levelSetVoxelFor(plate, 100000), 0.1 * 0.1 * 0.004 / area / 5, 1e-9);
}

TEST(LevelSetRebuild, AFlatSheetEnclosesNoVolumeAndIsRefusedSayingSo) {
  md::TriangleMesh sheet = md::loadTriangleMesh(data("nonmanifold.obj"));  // three triangles on one edge, flat
  md::LevelSetRebuildReport report;
  const std::string message =
      md::testing::errorMessageOf<md::NoEnclosedVolumeError>([&] { md::rebuildFromLevelSet(sheet, 0, report); });
  EXPECT_CONTAINS(message, "enclose no volume");
}

TEST(SurfaceRepair, AStripFinTheLocalRepairCannotUndoIsRebuiltClosedWithinOnePercentAndOneVoxel) {
  const md::TriangleMesh sphere = md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.03, 3);
  const md::TriangleMesh spoilt = sphereWithAStripFin();
  md::SurfaceRepairReport local;
  ASSERT_FALSE(md::checkSurfaceTopology(md::repairSurface(spoilt, local)).closedManifold());  // the local repair alone

  md::SurfaceRepairReport report;
  std::string defects;
  const md::TriangleMesh repaired = md::closedOrRepaired(spoilt, "fin.obj", report, &defects);
  EXPECT_CONTAINS(defects, "non-manifold edge");
  EXPECT_TRUE(md::checkSurfaceTopology(repaired).closedManifold()) << md::checkSurfaceTopology(repaired).describe();
  EXPECT_FALSE(md::findSelfIntersections(repaired).crosses());
  ASSERT_TRUE(report.level_set.has_value());
  EXPECT_CONTAINS(report.left_by_local_repair, "non-manifold edge");
  const double volume = md::enclosedVolume(sphere);
  EXPECT_NEAR(md::enclosedVolume(repaired), volume, 0.01 * volume);
  EXPECT_LE(report.level_set->max_distance_to_input_m, report.level_set->voxel_m);
  EXPECT_NEAR(static_cast<double>(repaired.triangleCount()), static_cast<double>(spoilt.triangleCount()),
              0.1 * static_cast<double>(spoilt.triangleCount()));
  EXPECT_CONTAINS(report.describe(), "rebuilt from a level set");
}

TEST(SurfaceRepair, ASelfIntersectingFoldIsRebuiltClosedWithinOnePercentAndOneVoxel) {
  const md::TriangleMesh sphere = md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.03, 3);
  md::SurfaceRepairReport report;
  std::string defects;
  const md::TriangleMesh repaired = md::closedOrRepaired(sphereWithAFold(), "fold.stl", report, &defects);
  EXPECT_CONTAINS(defects, "cross each other");
  EXPECT_TRUE(md::checkSurfaceTopology(repaired).closedManifold());
  EXPECT_FALSE(md::findSelfIntersections(repaired).crosses());
  ASSERT_TRUE(report.level_set.has_value());
  EXPECT_CONTAINS(report.left_by_local_repair, "cross each other");
  const double volume = md::enclosedVolume(sphere);
  EXPECT_NEAR(md::enclosedVolume(repaired), volume, 0.01 * volume);
  EXPECT_LE(report.level_set->max_distance_to_input_m, report.level_set->voxel_m);
}

TEST(SurfaceRepair, TheReportSaysHowMuchTheRebuildChangedTheVolumeAndHowFarItMovedTheSurface) {
  md::SurfaceRepairReport report;
  md::closedOrRepaired(sphereWithAStripFin(), "fin.obj", report);
  ASSERT_TRUE(report.level_set.has_value());
  const std::string text = report.describe();
  EXPECT_CONTAINS(text, "left 1 non-manifold edge");
  EXPECT_CONTAINS(text, " ml against ");
  EXPECT_CONTAINS(text, " %)");
  EXPECT_CONTAINS(text, "every vertex within ");
  // The strip's tip lay 15 mm out: the rebuild left it out, and says how far.
  EXPECT_GT(report.level_set->max_input_distance_m, 0.01);
}

// A 40 mm box with a 10 mm ball sunk half into its top face, and a second ball 4 mm into its side: the box carved by
// both, grown by a 1.5 mm clearance at a 1 mm voxel, lets no vertex of either ball inside it (the clearance is
// larger than the voxel, the iso-surface's and the decimation's error), loses the two grown caps' volume within 2 %,
// and stays where no ball is.
TEST(LevelSetCarve, ABoxCarvedByTwoBallsLetsNeitherInsideAndLosesOnlyTheirGrownCaps) {
  const md::TriangleMesh box = md::makeBoxMesh(Eigen::Vector3d(-0.02, -0.02, -0.04), Eigen::Vector3d(0.02, 0.02, 0.0),
                                               0.004);
  const md::TriangleMesh top_ball = md::makeSphereMesh(Eigen::Vector3d(0, 0, 0), 0.01, 4);
  const md::TriangleMesh side_ball = md::makeSphereMesh(Eigen::Vector3d(0.026, 0, -0.02), 0.01, 4);
  const double clearance = 0.0015, voxel = 0.001;
  md::LevelSetRebuildReport report;
  const md::TriangleMesh carved =
      md::carvedFromLevelSet(box, {top_ball, side_ball}, clearance, voxel, 4000, report);
  EXPECT_TRUE(md::checkSurfaceTopology(carved).closedManifold());
  EXPECT_FALSE(md::findSelfIntersections(carved).crosses());
  EXPECT_LE(carved.triangleCount(), 4400);

  const md::ClosedSurfaceInsideTest inside(carved, "carved box");
  for (const md::TriangleMesh* ball : {&top_ball, &side_ball})
    for (Eigen::Index v = 0; v < ball->vertexCount(); ++v)
      EXPECT_FALSE(inside.contains(ball->vertices.col(v))) << "ball vertex " << v;

  // Caps of the balls grown by the clearance: a half ball, and a cap of height 4 mm + clearance.
  const double r = 0.01 + clearance;
  const double half_ball = 2.0 / 3.0 * M_PI * r * r * r;
  const double h = 0.004 + clearance;
  const double cap = M_PI * h * h * (3 * r - h) / 3.0;
  const double box_volume = 0.04 * 0.04 * 0.04;
  EXPECT_NEAR(report.volume_m3, box_volume - half_ball - cap, 0.02 * (half_ball + cap));
  EXPECT_NEAR(report.max_distance_to_input_m, r, voxel);  // the deepest carve: the half ball's grown radius

  // The bottom corners, far from both balls, are where they were (within a voxel).
  const md::SurfaceDistance to_carved(carved.vertices, carved.triangles);
  EXPECT_LT(to_carved.distance(Eigen::Vector3d(-0.02, -0.02, -0.04)), voxel);
  EXPECT_LT(to_carved.distance(Eigen::Vector3d(0.02, 0.02, -0.04)), voxel);
}

TEST(LevelSetCarve, RefusesSurfacesThatAreNotClosedAndAVoxelThatIsNotPositive) {
  using md::testing::errorMessageOf;
  const md::TriangleMesh box = md::makeBoxMesh(Eigen::Vector3d(-0.02, -0.02, -0.04), Eigen::Vector3d(0.02, 0.02, 0.0));
  md::TriangleMesh open = box;
  open.triangles.conservativeResize(Eigen::NoChange, open.triangleCount() - 1);
  md::LevelSetRebuildReport report;
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([&] { md::carvedFromLevelSet(open, {box}, 0.001, 0.0005, 0, report); }),
                  "not a closed");
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([&] { md::carvedFromLevelSet(box, {open}, 0.001, 0.0005, 0, report); }),
                  "not a closed");
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([&] { md::carvedFromLevelSet(box, {box}, 0.001, 0.0, 0, report); }),
                  "voxel");
}
