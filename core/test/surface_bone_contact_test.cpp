// Specifications of the skin's contact with the bones: skinned surface vertices inside a bone are moved out to its
// surface, the others stay where they are.
#include "muscle_deformation/core/surfaces/surface_bone_contact.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

namespace md = muscle_deformation;

namespace {

// A ball of radius 25 mm as a bone (its mesh is inscribed in the sphere: 0.002 r at subdivision 4).
md::BoneFields ballBone(const Eigen::Vector3d& centre) {
  const md::TriangleMesh ball = md::makeSphereMesh(centre, 0.025, 4);
  return {std::make_shared<const md::BoneDistanceField>(ball, md::BoneFieldSettings{}, "ball")};
}

// Distance to the ball's mesh at `point`, through a fresh field (negative inside).
double distanceToBall(const md::BoneFields& bone, const Eigen::Vector3d& point) {
  return bone[0]->probe().distance(point);
}

}  // namespace

TEST(SurfaceBoneContact, VerticesInsideABoneEndJustOutsideItAndTheOthersStay) {
  const md::BoneFields bone = ballBone(Eigen::Vector3d::Zero());
  // A "surface" of vertices on a line through the ball: 9 mm and 3 mm deep (the skinning put the bundled surfaces up to
  // about 10 mm into bone), just inside its surface, and 5 mm and 40 mm outside.
  md::Vertices surface(3, 5);
  surface << 0.016, 0.022, 0.0249, 0.030, 0.065,  //
      0, 0, 0, 0, 0,                              //
      0, 0, 0, 0, 0;
  const md::Vertices before = surface;
  const md::SurfaceBoneContact contact({surface.cols()}, bone);
  std::vector<md::Vertices> surfaces = {surface};
  const std::vector<md::SurfaceBoneCorrection> corrections = contact.apply(surfaces, {});

  ASSERT_EQ(corrections.size(), 1u);
  EXPECT_EQ(corrections[0].vertices_moved, 3);
  EXPECT_NEAR(corrections[0].max_depth_before_m, 0.009, 2e-4);
  for (Eigen::Index v = 0; v < 3; ++v) {
    const double distance = distanceToBall(bone, surfaces[0].col(v));
    EXPECT_GT(distance, 0.0) << "vertex " << v << " still inside";
    EXPECT_LT(distance, 2 * md::SurfaceBoneContact::kClearanceM) << "vertex " << v << " pushed too far";
    // Out towards the nearest part of the bone's surface: within the clearance plus what a few degrees of error in the
    // interpolated gradient (the field follows the mesh's facets, between voxels) make of a 9 mm path, about 0.6 mm.
    EXPECT_LT((surfaces[0].col(v) - Eigen::Vector3d(0.025, 0, 0)).norm(), 1e-3) << "vertex " << v;
  }
  EXPECT_EQ(surfaces[0].col(3), before.col(3));
  EXPECT_EQ(surfaces[0].col(4), before.col(4));
}

TEST(SurfaceBoneContact, APosedBoneIsTakenWhereThePoseMovesItAndAFrameLaterItsLastReadsStillHold) {
  // The ball at rest around (1, 0, 0); the pose moves it to the origin and turns it, where the vertices are.
  const md::BoneFields bone = ballBone(Eigen::Vector3d(1, 0, 0));
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  pose.translation() = -(pose.linear() * Eigen::Vector3d(1, 0, 0));  // the ball's centre to the origin
  md::Vertices surface(3, 3);
  surface << 0.0, 0.010, 0.2,  //
      0.010, 0.0, 0.0,         //
      0.0, 0.0, 0.0;
  const md::SurfaceBoneContact contact({surface.cols()}, bone);
  std::vector<md::Vertices> surfaces = {surface};
  const Eigen::Isometry3d to_rest = pose.inverse();
  const std::vector<md::SurfaceBoneCorrection> first = contact.apply(surfaces, {pose});
  EXPECT_EQ(first[0].vertices_moved, 2);
  for (Eigen::Index v = 0; v < 2; ++v) EXPECT_GT(distanceToBall(bone, to_rest * surfaces[0].col(v)), 0.0);
  // The same surface again: nothing is inside any more, so nothing moves (the remembered reads may skip it).
  const md::Vertices settled = surfaces[0];
  const std::vector<md::SurfaceBoneCorrection> again = contact.apply(surfaces, {pose});
  EXPECT_EQ(again[0].vertices_moved, 0);
  EXPECT_EQ(surfaces[0], settled);
  // And with the bone back at rest, 1 m away, the surface is left alone.
  surfaces = {surface};
  EXPECT_EQ(contact.apply(surfaces, {Eigen::Isometry3d::Identity()})[0].vertices_moved, 0);
  EXPECT_EQ(surfaces[0], surface);
}

TEST(SurfaceBoneContact, RefusesSurfacesThatDoNotMatchItsMuscles) {
  const md::SurfaceBoneContact contact({4, 4}, ballBone(Eigen::Vector3d::Zero()));
  std::vector<md::Vertices> one(1, md::Vertices::Zero(3, 4));
  EXPECT_THROW(contact.apply(one, {}), std::invalid_argument);
}
