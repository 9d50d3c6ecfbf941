// The bundled scene at rest lies outside its bones: no muscle surface vertex and no particle of the node's model is
// more than 1 mm inside a bone. Collision keeps a particle that starts inside a bone no deeper than it lay at rest, so
// an overlap in the data would stay in every frame; this keeps the data from regressing.
//
// Measured by the product's own fidelity metrics (DeformationMetrics, the figures ~stats reports), at rest: a free
// particle counts in every bone, a fixed particle (an attachment) in every bone but the one it is fixed to, since
// lying on or in that bone is what attaches it, and a tendon's bone anchor (a point of the bone) not at all.
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <memory>
#include <vector>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace md = muscle_deformation;

namespace {

constexpr double kAllowedDepthM = 0.001;

class BundledRestOverlap : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const md::BundledScene bundled = md::loadBundledScene(MD_PACKAGE_DIR, {});
    md::ModelSettings settings;
    settings.particles_per_fibre = 20;  // the node's default (config/muscle_deformation.yaml)
    const md::MassSpringSystem system =
        md::buildMassSpringSystem(bundled.scene.muscles, bundled.scene.bones, settings);
    const md::DeformationMetrics metrics(bundled.scene.bones, bundled.scene.muscles, system);
    std::vector<md::Vertices> surfaces;
    for (const md::Muscle& muscle : bundled.scene.muscles) surfaces.push_back(muscle.surface.vertices);
    at_rest_ = std::make_unique<md::SceneMetrics>(metrics.measure(surfaces, system.rest_position, {}));
  }
  static void TearDownTestSuite() { at_rest_.reset(); }

  static std::unique_ptr<md::SceneMetrics> at_rest_;
};

std::unique_ptr<md::SceneMetrics> BundledRestOverlap::at_rest_;

}  // namespace

TEST_F(BundledRestOverlap, NoMuscleSurfaceVertexLiesMoreThanOneMillimetreInsideABone) {
  ASSERT_EQ(at_rest_->muscles.size(), 26u);
  for (const md::MuscleMetrics& muscle : at_rest_->muscles) {
    std::printf("surface   %-26s deepest %.2f mm inside %s\n", muscle.name.c_str(),
                muscle.max_inside_bone_depth_m * 1e3, muscle.deepest_bone.empty() ? "-" : muscle.deepest_bone.c_str());
    EXPECT_LE(muscle.max_inside_bone_depth_m, kAllowedDepthM)
        << muscle.name << " surface " << muscle.max_inside_bone_depth_m * 1e3 << " mm inside " << muscle.deepest_bone;
  }
  std::printf("surface vertices: deepest %.2f mm inside a bone (allowed %.1f mm)\n",
              at_rest_->max_inside_bone_depth_m * 1e3, kAllowedDepthM * 1e3);
}

TEST_F(BundledRestOverlap, NoParticleOfTheNodesModelLiesMoreThanOneMillimetreInsideABoneItIsNotFixedTo) {
  ASSERT_EQ(at_rest_->muscles.size(), 26u);
  for (const md::MuscleMetrics& muscle : at_rest_->muscles) {
    std::printf("particles %-26s deepest %.2f mm inside %s\n", muscle.name.c_str(),
                muscle.max_particle_inside_bone_depth_m * 1e3,
                muscle.deepest_particle_bone.empty() ? "-" : muscle.deepest_particle_bone.c_str());
    EXPECT_LE(muscle.max_particle_inside_bone_depth_m, kAllowedDepthM)
        << muscle.name << " particle " << muscle.max_particle_inside_bone_depth_m * 1e3 << " mm inside "
        << muscle.deepest_particle_bone;
  }
  std::printf("particles (20 per fibre, attachments not against their own bone): deepest %.2f mm inside a bone "
              "(allowed %.1f mm)\n",
              at_rest_->max_particle_inside_bone_depth_m * 1e3, kAllowedDepthM * 1e3);
}
