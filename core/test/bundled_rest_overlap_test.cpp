// The bundled scene at rest lies outside its bones: no muscle surface vertex and no particle of the node's model is
// more than 1 mm inside a bone. Collision keeps a particle that starts inside a bone no deeper than it lay at rest, so
// an overlap in the data would stay in every frame; this keeps the data from regressing.
//
// Which particle is checked against which bone: a free particle against every bone; a fixed particle (an attachment,
// MassSpringSystem::is_fixed) against every bone but the one it is fixed to, since lying on or in that bone is what
// attaches it; a tendon's bone anchor (fibre_of == kTendonAnchor) is a point of the bone, not of the muscle, and is
// not checked.
#include "muscle_deformation/core/collision/bone_distance_field.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
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

  // skip_bone[i]: the bone index point i is not checked against (md::kNoBone: checked against every bone).
  static Deepest deepestInsideABone(const Eigen::Matrix3Xd& points, const std::vector<std::int32_t>& skip_bone = {}) {
    Deepest deepest;
    for (std::size_t b = 0; b < fields_->size(); ++b) {
      const md::BoneDistanceField::Probe probe = (*fields_)[b]->probe();
      for (Eigen::Index i = 0; i < points.cols(); ++i) {
        if (!skip_bone.empty() && skip_bone[static_cast<std::size_t>(i)] == static_cast<std::int32_t>(b)) continue;
        double distance = 0;
        Eigen::Vector3d gradient;
        if (!probe.closerThan(points.col(i), 0.0, distance, gradient)) continue;
        if (-distance > deepest.depth_m) deepest = {-distance, (*fields_)[b]->name()};
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

TEST_F(BundledRestOverlap, NoParticleOfTheNodesModelLiesMoreThanOneMillimetreInsideABoneItIsNotFixedTo) {
  md::ModelSettings settings;
  settings.particles_per_fibre = 20;  // the node's default (config/muscle_deformation.yaml)
  const md::MassSpringSystem system =
      md::buildMassSpringSystem(bundled_->scene.muscles, bundled_->scene.bones, settings);
  double worst = 0;
  ASSERT_EQ(fields_->size(), bundled_->scene.bones.size());
  for (std::size_t b = 0; b < bundled_->scene.bones.size(); ++b) ASSERT_EQ(bundled_->scene.bones[b].id, static_cast<int>(b));
  for (std::size_t m = 0; m < bundled_->scene.muscles.size(); ++m) {
    std::vector<Eigen::Index> own;
    std::vector<std::int32_t> fixed_to;
    for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
      const auto p = static_cast<std::size_t>(i);
      if (system.muscle_of[p] != static_cast<std::int32_t>(m) || system.fibre_of[p] == md::kTendonAnchor) continue;
      own.push_back(i);
      fixed_to.push_back(system.is_fixed[p] ? system.fixed_bone[p] : md::kNoBone);
    }
    Eigen::Matrix3Xd points(3, static_cast<Eigen::Index>(own.size()));
    for (std::size_t k = 0; k < own.size(); ++k) points.col(static_cast<Eigen::Index>(k)) = system.rest_position.col(own[k]);
    const Deepest deepest = deepestInsideABone(points, fixed_to);
    const Deepest any_bone = deepestInsideABone(points);  // attachments against their own bone too: printed only
    const std::string& name = bundled_->scene.muscles[m].name;
    std::printf("particles %-26s %4zu, deepest %.2f mm inside %s (any bone: %.2f mm)\n", name.c_str(), own.size(),
                deepest.depth_m * 1e3, deepest.bone.c_str(), any_bone.depth_m * 1e3);
    EXPECT_LE(deepest.depth_m, kAllowedDepthM) << name << " particle " << deepest.depth_m * 1e3 << " mm inside "
                                               << deepest.bone;
    worst = std::max(worst, deepest.depth_m);
  }
  std::printf("particles (%ld, %d per fibre, attachments not against their own bone): deepest %.2f mm inside a bone "
              "(allowed %.1f mm)\n",
              static_cast<long>(system.particleCount()), settings.particles_per_fibre, worst * 1e3,
              kAllowedDepthM * 1e3);
}
