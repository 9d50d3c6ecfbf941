// The bundled scene at rest lies outside its bones: no muscle surface vertex and no particle of the node's model is
// more than 1 mm inside a bone. Collision keeps a particle that starts inside a bone no deeper than it lay at rest, so
// an overlap in the data would stay in every frame; this keeps the data from regressing.
#include "muscle_deformation/core/collision/bone_distance_field.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace md = muscle_deformation;

namespace {

constexpr double kAllowedDepthM = 0.001;

// The deepest point of a set inside any bone, read from the bones' distance fields (the fields the product's
// inside-bone metric and its collision use, 1 mm voxels), all at rest.
struct Deepest {
  double depth_m = 0;
  std::string bone = "-";
};

class BundledRestOverlap : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    bundled_ = std::make_unique<md::BundledScene>(md::loadBundledScene(MD_PACKAGE_DIR, {}));
    fields_ = std::make_unique<md::BoneFields>(md::buildBoneFields(bundled_->scene.bones, md::BoneFieldSettings{}));
  }
  static void TearDownTestSuite() {
    fields_.reset();
    bundled_.reset();
  }

  static Deepest deepestInsideABone(const Eigen::Matrix3Xd& points) {
    Deepest deepest;
    for (const auto& field : *fields_) {
      const md::BoneDistanceField::Probe probe = field->probe();
      for (Eigen::Index i = 0; i < points.cols(); ++i) {
        double distance = 0;
        Eigen::Vector3d gradient;
        if (!probe.closerThan(points.col(i), 0.0, distance, gradient)) continue;
        if (-distance > deepest.depth_m) deepest = {-distance, field->name()};
      }
    }
    return deepest;
  }

  static std::unique_ptr<md::BundledScene> bundled_;
  static std::unique_ptr<md::BoneFields> fields_;
};

std::unique_ptr<md::BundledScene> BundledRestOverlap::bundled_;
std::unique_ptr<md::BoneFields> BundledRestOverlap::fields_;

}  // namespace

TEST_F(BundledRestOverlap, NoMuscleSurfaceVertexLiesMoreThanOneMillimetreInsideABone) {
  ASSERT_EQ(bundled_->scene.muscles.size(), 26u);
  double worst = 0;
  for (const md::Muscle& muscle : bundled_->scene.muscles) {
    const Deepest deepest = deepestInsideABone(muscle.surface.vertices);
    std::printf("surface %-26s deepest %.2f mm inside %s\n", muscle.name.c_str(), deepest.depth_m * 1e3,
                deepest.bone.c_str());
    EXPECT_LE(deepest.depth_m, kAllowedDepthM) << muscle.name << " surface " << deepest.depth_m * 1e3 << " mm inside "
                                               << deepest.bone;
    worst = std::max(worst, deepest.depth_m);
  }
  std::printf("surface vertices: deepest %.2f mm inside a bone (allowed %.1f mm)\n", worst * 1e3,
              kAllowedDepthM * 1e3);
}

TEST_F(BundledRestOverlap, NoParticleOfTheNodesModelLiesMoreThanOneMillimetreInsideABone) {
  md::ModelSettings settings;
  settings.particles_per_fibre = 20;  // the node's default (config/muscle_deformation.yaml)
  const md::MassSpringSystem system =
      md::buildMassSpringSystem(bundled_->scene.muscles, bundled_->scene.bones, settings);
  double worst = 0;
  for (std::size_t m = 0; m < bundled_->scene.muscles.size(); ++m) {
    std::vector<Eigen::Index> own;
    for (Eigen::Index i = 0; i < system.particleCount(); ++i)
      if (system.muscle_of[static_cast<std::size_t>(i)] == static_cast<std::int32_t>(m)) own.push_back(i);
    Eigen::Matrix3Xd points(3, static_cast<Eigen::Index>(own.size()));
    for (std::size_t k = 0; k < own.size(); ++k) points.col(static_cast<Eigen::Index>(k)) = system.rest_position.col(own[k]);
    const Deepest deepest = deepestInsideABone(points);
    const std::string& name = bundled_->scene.muscles[m].name;
    std::printf("particles %-26s %4zu, deepest %.2f mm inside %s\n", name.c_str(), own.size(), deepest.depth_m * 1e3,
                deepest.bone.c_str());
    EXPECT_LE(deepest.depth_m, kAllowedDepthM) << name << " particle " << deepest.depth_m * 1e3 << " mm inside "
                                               << deepest.bone;
    worst = std::max(worst, deepest.depth_m);
  }
  std::printf("particles (%ld, %d per fibre): deepest %.2f mm inside a bone (allowed %.1f mm)\n",
              static_cast<long>(system.particleCount()), settings.particles_per_fibre, worst * 1e3,
              kAllowedDepthM * 1e3);
}
