// Building the mass-spring system from muscles and bones, and moving it with the bones.
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/base/point_index.hpp"
#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <set>
#include <string>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

using namespace muscle_deformation;

namespace {

// One spindle muscle between two plate-like bones: fibre starts touch the lower plate, ends the upper one.
struct SmallScene {
  std::vector<Muscle> muscles;
  std::vector<Bone> bones;
};

SmallScene spindleBetweenPlates() {
  SmallScene scene;
  scene.muscles.push_back(makeSpindleMuscle("spindle", {0, 0, 0}, {0, 0, 0.2}, 0.02, 1.0, 4, 30));
  scene.bones.push_back({0, "lower", makeBoxMesh({-0.05, -0.05, -0.03}, {0.05, 0.05, -0.001})});
  scene.bones.push_back({1, "upper", makeBoxMesh({-0.05, -0.05, 0.201}, {0.05, 0.05, 0.23})});
  return scene;
}

// The bone a particle is attached to: its own if fixed, else the bone of a tendon anchor a spring joins it to, else
// kNoBone.
int attachmentBoneOf(const MassSpringSystem& system, Eigen::Index particle) {
  if (system.is_fixed[static_cast<std::size_t>(particle)]) return system.fixed_bone[static_cast<std::size_t>(particle)];
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const std::int32_t a = system.springs.first[s], b = system.springs.second[s];
    const std::int32_t other = a == particle ? b : b == particle ? a : -1;
    if (other >= 0 && system.fibre_of[static_cast<std::size_t>(other)] == kTendonAnchor)
      return system.fixed_bone[static_cast<std::size_t>(other)];
  }
  return kNoBone;
}

ModelSettings smallSettings() {
  ModelSettings settings;
  settings.particles_per_fibre = 10;
  settings.nearest_neighbours = 8;
  return settings;
}

}  // namespace

TEST(ModelBuilder, BuildsParticlesForEveryFibre) {
  const SmallScene scene = spindleBetweenPlates();
  ModelBuildReport report;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings(), &report);
  ASSERT_EQ(report.muscles.size(), 1u);
  // 16 fibres of 10 particles, then one anchor per fibre end joined to its bone through a tendon.
  const int tendons = report.muscles[0].tendons;
  EXPECT_EQ(system.particleCount(), 16 * 10 + tendons);
  EXPECT_EQ(system.muscle_begin, (std::vector<std::int32_t>{0, 160 + tendons}));
  EXPECT_EQ(report.muscles[0].particles, 160 + tendons);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i)
    EXPECT_EQ(system.fibre_of[static_cast<std::size_t>(i)] == kTendonAnchor, i >= 160) << i;
  EXPECT_EQ(report.muscles[0].springs, static_cast<int>(system.springs.size()));
  EXPECT_GT(report.muscles[0].volume_m3, 0);
}

TEST(ModelBuilder, AMuscleSamplesItsFibresAtItsOwnResolution) {
  SmallScene scene = spindleBetweenPlates();
  scene.muscles.push_back(makeSpindleMuscle("second", {0.03, 0, 0}, {0.03, 0, 0.2}, 0.01, 1.0, 4, 30));
  scene.muscles[1].particles_per_fibre = 4;  // the first keeps the model's 10
  ModelSettings settings = smallSettings();
  settings.tendons = false;
  ModelBuildReport report;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings, &report);
  ASSERT_EQ(report.muscles.size(), 2u);
  EXPECT_EQ(report.muscles[0].particles, 16 * 10);
  EXPECT_EQ(report.muscles[1].particles, 16 * 4);
  // Each muscle's fibre ends are its own last samples: the second's sample 3 is fixed to the upper plate.
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    const int last = system.muscle_of[static_cast<std::size_t>(i)] == 0 ? 9 : 3;
    if (system.sample_of[i] == last) {
      EXPECT_TRUE(system.is_fixed[i]) << i;
      EXPECT_EQ(system.fixed_bone[i], 1) << i;
    } else if (system.sample_of[i] != 0) {
      EXPECT_FALSE(system.is_fixed[i]) << i;
    }
  }
}

TEST(ModelBuilder, RefusesAMuscleResolutionBelowTwoParticlesPerFibre) {
  SmallScene scene = spindleBetweenPlates();
  scene.muscles[0].particles_per_fibre = 1;
  try {
    buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
    FAIL() << "a muscle with one particle per fibre was accepted";
  } catch (const ModelError& error) {
    EXPECT_NE(std::string(error.what()).find("spindle"), std::string::npos) << error.what();
    EXPECT_NE(std::string(error.what()).find("particles_per_fibre 1"), std::string::npos) << error.what();
  }
}

TEST(ModelBuilder, FibreEndsAreFixedToTheNearestBone) {
  const SmallScene scene = spindleBetweenPlates();
  ModelSettings settings = smallSettings();
  settings.tendons = false;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (system.sample_of[i] == 0) {
      EXPECT_TRUE(system.is_fixed[i]);
      EXPECT_EQ(system.fixed_bone[i], 0);
    } else if (system.sample_of[i] == 9) {
      EXPECT_TRUE(system.is_fixed[i]);
      EXPECT_EQ(system.fixed_bone[i], 1);
    }
  }
}

TEST(ModelBuilder, AFibreEndAwayFromItsBoneHangsFromItThroughATendon) {
  const SmallScene scene = spindleBetweenPlates();
  ModelSettings settings = smallSettings();
  ModelBuildReport report;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings, &report);
  ASSERT_EQ(report.muscles.size(), 1u);
  // The last particle of a fibre lies up to one sampling interval (2.2 cm here) short of the fibre's end, the first
  // at it: 1 mm from the lower plate. Ends within attachment_distance_m are fixed in place, the others hang from
  // their plate through a tendon.
  int tendons = 0, fixed_in_place = 0;
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    const int sample = system.sample_of[i];
    if (system.fibre_of[i] == kTendonAnchor || (sample != 0 && sample != 9)) continue;
    const int expected_bone = sample == 0 ? 0 : 1;
    const SurfaceDistance plate(scene.bones[expected_bone].surface.vertices, scene.bones[expected_bone].surface.triangles);
    const double distance = plate.distance(system.rest_position.col(i));
    if (distance <= settings.attachment_distance_m) {
      EXPECT_TRUE(system.is_fixed[i]) << i;
      EXPECT_EQ(system.fixed_bone[i], expected_bone) << i;
      ++fixed_in_place;
      continue;
    }
    EXPECT_FALSE(system.is_fixed[i]) << i;
    int anchors = 0;
    for (std::size_t s = 0; s < system.springs.size(); ++s) {
      const std::int32_t a = system.springs.first[s], b = system.springs.second[s];
      const std::int32_t anchor = a == i ? b : b == i ? a : -1;
      if (anchor < 0 || system.fibre_of[static_cast<std::size_t>(anchor)] != kTendonAnchor) continue;
      ++anchors;
      EXPECT_TRUE(system.is_fixed[static_cast<std::size_t>(anchor)]);
      EXPECT_EQ(system.fixed_bone[static_cast<std::size_t>(anchor)], expected_bone);
      EXPECT_EQ(system.muscle_of[static_cast<std::size_t>(anchor)], 0);
      // The anchor is a vertex of the plate, and the tendon's rest length is what separates them at rest.
      EXPECT_LT(plate.distance(system.rest_position.col(anchor)), 1e-12);
      const double length = (system.rest_position.col(anchor) - system.rest_position.col(i)).norm();
      EXPECT_DOUBLE_EQ(system.springs.rest_length[static_cast<Eigen::Index>(s)], length);
      EXPECT_GE(length, distance);
      EXPECT_DOUBLE_EQ(system.springs.stiffness[static_cast<Eigen::Index>(s)], settings.spring_material_n / length);
    }
    EXPECT_EQ(anchors, 1) << "fibre end " << i;
    ++tendons;
  }
  EXPECT_GT(fixed_in_place, 0);
  EXPECT_GT(tendons, 0);
  EXPECT_EQ(report.muscles[0].tendons, tendons);
  EXPECT_GT(report.muscles[0].longest_tendon_m, settings.attachment_distance_m);
  // No fibre runs through the anchors.
  std::size_t fibre_particles = 0;
  for (const Eigen::Matrix3Xd& fibre : fibrePolylines(system, system.rest_position)) {
    EXPECT_EQ(fibre.cols(), 10);
    fibre_particles += static_cast<std::size_t>(fibre.cols());
  }
  EXPECT_EQ(fibre_particles, 160u);
}

TEST(ModelBuilder, ParticlesCloseToABoneAreFixedToIt) {
  SmallScene scene = spindleBetweenPlates();
  // A thin rod along the muscle axis passing through it: every particle within 2 mm of it must be attached.
  scene.bones.push_back({2, "rod", makeCylinderMesh({0.0, 0.0, 0.05}, {0.0, 0.0, 0.15}, 0.001, 12, 4)});
  ModelSettings settings = smallSettings();
  settings.attachment_distance_m = 0.004;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings);
  int attached_to_rod = 0;
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    const Eigen::Vector3d p = system.rest_position.col(i);
    const double radial = std::hypot(p.x(), p.y());
    // The 12-sided rod's faces are cos(15 deg) of its radius from the axis.
    const bool near_rod = p.z() > 0.05 && p.z() < 0.15 && radial < 0.001 * std::cos(M_PI / 12) + 0.004 - 1e-9;
    if (near_rod) {
      EXPECT_TRUE(system.is_fixed[i]) << i;
      ++attached_to_rod;
    }
    if (system.fixed_bone[i] == 2) {
      EXPECT_LE(radial - 0.001, 0.004 + 1e-9);
    }
  }
  EXPECT_GT(attached_to_rod, 0);
}

TEST(ModelBuilder, NoParticleIsFixedToABoneThatIsNeitherTheMusclesOriginNorInsertion) {
  SmallScene scene = spindleBetweenPlates();
  // The same rod through the muscle as above, but the muscle is attached to the plates only: near the rod its
  // particles stay free.
  scene.bones.push_back({2, "rod", makeCylinderMesh({0.0, 0.0, 0.05}, {0.0, 0.0, 0.15}, 0.001, 12, 4)});
  scene.muscles[0].origin_bone = "lower";
  scene.muscles[0].insertion_bone = "upper";
  ModelSettings settings = smallSettings();
  settings.attachment_distance_m = 0.004;
  ModelBuildReport report;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings, &report);
  int near_rod = 0;
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (system.is_fixed[i]) EXPECT_NE(system.fixed_bone[i], 2) << "particle " << i << " fixed to the rod";
    const Eigen::Vector3d p = system.rest_position.col(i);
    if (p.z() > 0.05 && p.z() < 0.15 && std::hypot(p.x(), p.y()) < 0.001 * std::cos(M_PI / 12) + 0.004) {
      EXPECT_FALSE(system.is_fixed[i]) << i;
      ++near_rod;
    }
  }
  EXPECT_GT(near_rod, 0);
  ASSERT_EQ(report.muscles.size(), 1u);
  EXPECT_EQ(report.muscles[0].fixed_by_bone.count("rod"), 0u);
  EXPECT_EQ(report.muscles[0].fixed_by_bone.at("lower") + report.muscles[0].fixed_by_bone.at("upper"),
            report.muscles[0].fixed_particles);
}

TEST(ModelBuilder, FibreStartsAreFixedToTheOriginAndEndsToTheInsertionAndAReversedMuscleIsWarnedAbout) {
  SmallScene scene = spindleBetweenPlates();
  ModelSettings settings = smallSettings();
  settings.attachment_distance_m = 0;  // only the fibre ends are fixed
  scene.muscles[0].origin_bone = "upper";  // the fibres start at the lower plate: named the wrong way round
  scene.muscles[0].insertion_bone = "lower";
  ModelBuildReport report;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings, &report);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (system.fibre_of[i] == kTendonAnchor) continue;
    if (system.sample_of[i] == 0) EXPECT_EQ(attachmentBoneOf(system, i), 1) << i;
    if (system.sample_of[i] == 9) EXPECT_EQ(attachmentBoneOf(system, i), 0) << i;
  }
  ASSERT_EQ(report.warnings.size(), 1u);
  EXPECT_CONTAINS(report.warnings[0], "muscle 'spindle': 16 of 16 fibres start nearer its insertion bone 'lower'");
  EXPECT_CONTAINS(report.warnings[0], "swapped");

  std::swap(scene.muscles[0].origin_bone, scene.muscles[0].insertion_bone);
  buildMassSpringSystem(scene.muscles, scene.bones, settings, &report);
  EXPECT_TRUE(report.warnings.empty()) << report.warnings[0];
}

TEST(ModelBuilder, AnAttachmentBoneThatIsNotABoneIsAnErrorNamingMuscleAndBone) {
  SmallScene scene = spindleBetweenPlates();
  scene.muscles[0].origin_bone = "lower";
  scene.muscles[0].insertion_bone = "kneecap";
  const std::string message =
      muscle_deformation::testing::errorMessageOf<ModelError>([&] { buildMassSpringSystem(scene.muscles, scene.bones, smallSettings()); });
  EXPECT_CONTAINS(message, "muscle 'spindle'");
  EXPECT_CONTAINS(message, "insertion bone 'kneecap'");
  EXPECT_CONTAINS(message, "'lower', 'upper'");
}

TEST(ModelBuilder, AMuscleFixedToTwoBonesAFewMillimetresApartIsWarnedAboutNamingMuscleAndBones) {
  // A muscle across a joint: its fibres start on two bones side by side, 2 mm apart (a hip joint's pelvis and femur).
  SmallScene scene;
  scene.muscles.push_back(makeSpindleMuscle("iliacus", {0, 0, 0}, {0, 0, 0.2}, 0.02, 1.0, 4, 30));
  scene.bones.push_back({0, "pelvis", makeBoxMesh({-0.05, -0.05, -0.03}, {-0.001, 0.05, -0.001})});
  scene.bones.push_back({1, "femur", makeBoxMesh({0.001, -0.05, -0.03}, {0.05, 0.05, -0.001})});
  scene.bones.push_back({2, "tibia", makeBoxMesh({-0.05, -0.05, 0.201}, {0.05, 0.05, 0.23})});
  scene.muscles[0].origin_bone = "pelvis";
  scene.muscles[0].insertion_bone = "femur";
  ModelBuildReport report;
  buildMassSpringSystem(scene.muscles, scene.bones, smallSettings(), &report);
  ASSERT_EQ(report.muscles.size(), 1u);
  EXPECT_LT(report.muscles[0].closest_attachments_m, kCloseAttachmentsWarningM);
  std::string warnings;
  for (const std::string& warning : report.warnings) warnings += warning + "\n";
  EXPECT_CONTAINS(warnings, "muscle 'iliacus': particles fixed to 'pelvis' and to 'femur' are ");
  EXPECT_CONTAINS(warnings, "mm apart at rest");

  // Attached at both ends of the muscle instead, 20 cm apart: nothing to say.
  scene.muscles[0].insertion_bone = "tibia";
  buildMassSpringSystem(scene.muscles, scene.bones, smallSettings(), &report);
  EXPECT_GT(report.muscles[0].closest_attachments_m, 0.15);
  EXPECT_TRUE(report.warnings.empty()) << report.warnings[0];
}

// A tendon's anchor sits at the first point of the muscle's tendon path beyond the belly, which may be a via point on
// a bone the muscle crosses (tensor fasciae latae's iliotibial band runs down the femur to the tibia): a bone of the
// muscle's own paths, never a bone it merely lies against.
TEST(ModelBuilder, NoParticleOfTheBundledSceneIsFixedToABoneOtherThanItsMusclesAttachmentsOrTendonPaths) {
  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR, {});
  ASSERT_EQ(bundled.scene.muscles.size(), 26u);
  ModelBuildReport report;
  const MassSpringSystem system =
      buildMassSpringSystem(bundled.scene.muscles, bundled.scene.bones, ModelSettings{}, &report);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (!system.is_fixed[i]) continue;
    const Muscle& muscle = bundled.scene.muscles[static_cast<std::size_t>(system.muscle_of[i])];
    const std::string& bone = bundled.scene.bones[static_cast<std::size_t>(system.fixed_bone[i])].name;
    const auto on_path = [&](const std::vector<AttachmentSite>& path) {
      return std::any_of(path.begin(), path.end(), [&](const AttachmentSite& site) { return site.bone == bone; });
    };
    EXPECT_TRUE(bone == muscle.origin_bone || bone == muscle.insertion_bone || on_path(muscle.origin_path) ||
                on_path(muscle.insertion_path))
        << "particle " << i << " of " << muscle.name << " fixed to " << bone;
  }
  // Every muscle holds on to both of its bones, and none is fixed by the fibres' direction the wrong way round.
  for (const MuscleBuildSummary& summary : report.muscles) {
    const Muscle& muscle = *std::find_if(bundled.scene.muscles.begin(), bundled.scene.muscles.end(),
                                         [&](const Muscle& m) { return m.name == summary.name; });
    // Directly, or through tendons whose path ends at the attachment site on that bone (a path whose first point lies
    // on a bone the muscle crosses: tensor fasciae latae down the femur to the tibia).
    const auto holds = [&](const std::string& bone, const AttachmentSite* site) {
      return summary.fixed_by_bone.count(bone) > 0 || (summary.tendons_to_sites > 0 && site && site->bone == bone);
    };
    const AttachmentSite* origin_site = muscle.origin_path.empty() ? nullptr : &muscle.origin_path.front();
    const AttachmentSite* insertion_site = muscle.insertion_path.empty() ? nullptr : &muscle.insertion_path.back();
    EXPECT_TRUE(holds(muscle.origin_bone, origin_site)) << summary.name << " does not hold its origin bone";
    EXPECT_TRUE(holds(muscle.insertion_bone, insertion_site)) << summary.name << " does not hold its insertion bone";
  }
  for (const std::string& warning : report.warnings) {
    EXPECT_EQ(warning.find("fibres start nearer"), std::string::npos) << warning;
    EXPECT_EQ(warning.find("start inside bone"), std::string::npos) << warning;
    std::printf("bundled scene: %s\n", warning.c_str());
  }
}

// The margin of the bone size rule on real anatomy: every bundled bone beside the median muscle of the whole scene,
// and beside each muscle alone (a scene that selects only the smallest or only the largest muscle).
TEST(ModelBuilder, EveryBundledBoneIsFarFromTheImplausibleSizeRatioWhateverTheMuscleSelection) {
  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR, {});
  const BoneScale scale = measureBoneScale(bundled.scene.muscles, bundled.scene.bones);
  std::printf("median muscle of the bundled scene: %.3f m across\n", scale.median_muscle_diagonal_m);
  for (const BoneSize& bone : scale.bones)
    std::printf("  bone %-10s %.3f m across, %.2f times the median muscle\n", bone.bone.c_str(), bone.diagonal_m,
                bone.ratio);
  double smallest = std::numeric_limits<double>::infinity(), largest = 0;
  for (const Muscle& muscle : bundled.scene.muscles) {
    for (const BoneSize& bone : measureBoneScale({muscle}, bundled.scene.bones).bones) {
      smallest = std::min(smallest, bone.ratio);
      largest = std::max(largest, bone.ratio);
    }
  }
  std::printf("beside any one muscle alone: %.3f to %.1f times\n", smallest, largest);
  // Ten times inside the refusal on either side, however the muscles are selected.
  EXPECT_GT(smallest, 10.0 / kImplausibleBoneSizeRatio);
  EXPECT_LT(largest, kImplausibleBoneSizeRatio / 10.0);
}

TEST(ModelBuilder, OuterFibresAreBoundaryAndCentralFibresAreNot) {
  SmallScene scene;
  scene.muscles.push_back(makeSpindleMuscle("spindle", {0, 0, 0}, {0, 0, 0.2}, 0.02, 1.0, 6, 30, 48, 60));
  ModelSettings settings = smallSettings();
  settings.particles_per_fibre = 20;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, {}, settings);
  // Fibre f sits at grid (f / 6, f % 6): rows/columns 0 and 5 are the outer ring, 2..3 the centre.
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    const int row = system.fibre_of[i] / 6, column = system.fibre_of[i] % 6;
    const bool outer = row == 0 || row == 5 || column == 0 || column == 5;
    const bool centre = row >= 2 && row <= 3 && column >= 2 && column <= 3;
    if (outer) {
      EXPECT_TRUE(system.is_boundary[i]) << "fibre " << system.fibre_of[i];
    }
    if (centre) {
      EXPECT_FALSE(system.is_boundary[i]) << "fibre " << system.fibre_of[i];
    }
  }
}

TEST(ModelBuilder, BoundaryFibresDoNotDependOnParticlesPerFibre) {
  SmallScene scene;
  scene.muscles.push_back(makeSpindleMuscle("spindle", {0, 0, 0}, {0, 0, 0.2}, 0.02, 1.0, 6, 30, 48, 60));
  std::set<std::int32_t> reference;
  for (int per_fibre : {10, 20, 40, 80}) {
    ModelSettings settings = smallSettings();
    settings.particles_per_fibre = per_fibre;
    const MassSpringSystem system = buildMassSpringSystem(scene.muscles, {}, settings);
    std::set<std::int32_t> boundary_fibres;
    for (Eigen::Index i = 0; i < system.particleCount(); ++i)
      if (system.is_boundary[i]) boundary_fibres.insert(system.fibre_of[i]);
    if (reference.empty()) reference = boundary_fibres;
    EXPECT_EQ(boundary_fibres, reference) << per_fibre << " particles per fibre";
  }
  EXPECT_EQ(reference.size(), 20u);  // the outer ring of the 6 x 6 grid
}

TEST(ModelBuilder, BoundaryFractionZeroMakesEveryParticleCollide) {
  SmallScene scene;
  scene.muscles.push_back(makeSpindleMuscle("spindle", {0, 0, 0}, {0, 0, 0.2}, 0.02, 1.0, 6, 30, 48, 60));
  ModelSettings settings = smallSettings();
  settings.boundary_fibre_fraction = 0;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, {}, settings);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    EXPECT_TRUE(system.is_boundary[i]) << "particle " << i;
    EXPECT_GT(system.radius[i], 0.0) << "particle " << i;
  }
}

TEST(BoneMotion, LargestTravelOfACentroidAndLargestTurn) {
  const std::vector<Eigen::Vector3d> centroids = {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 0, 0)};
  const BoneTransforms rest(2, Eigen::Isometry3d::Identity());
  BoneTransforms moved = rest;
  moved[0] = Eigen::Translation3d(0, 0.003, 0) * Eigen::Isometry3d::Identity();
  // Bone 1 turns 0.2 rad about its own centroid: it turns but its centroid stays.
  moved[1] = Eigen::Translation3d(1, 0, 0) * Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitZ()) *
             Eigen::Translation3d(-1, 0, 0);
  const BoneMotion motion = largestBoneMotion(rest, moved, centroids);
  EXPECT_NEAR(motion.translation_m, 0.003, 1e-12);
  EXPECT_NEAR(motion.rotation_rad, 0.2, 1e-12);
  const BoneMotion none = largestBoneMotion(moved, moved, centroids);
  EXPECT_EQ(none.translation_m, 0.0);
  EXPECT_NEAR(none.rotation_rad, 0.0, 1e-12);
}

TEST(SyntheticScene, SubdividedBoxIsClosedWithShortEdges) {
  const TriangleMesh box = makeBoxMesh({0, 0, 0}, {0.1, 0.2, 0.05}, 0.01);
  EXPECT_TRUE(checkSurfaceTopology(box).closedManifold()) << checkSurfaceTopology(box).describe();
  EXPECT_NEAR(enclosedVolume(box), 0.1 * 0.2 * 0.05, 1e-15);
  for (Eigen::Index t = 0; t < box.triangleCount(); ++t)
    for (int c = 0; c < 3; ++c)
      EXPECT_LE((box.vertices.col(box.triangles(c, t)) - box.vertices.col(box.triangles((c + 1) % 3, t))).norm(),
                0.01 * std::sqrt(2.0) + 1e-12);
}

TEST(ModelBuilder, StiffnessIsMaterialConstantOverRestLength) {
  const SmallScene scene = spindleBetweenPlates();
  ModelSettings settings = smallSettings();
  settings.spring_material_n = 3.0;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings);
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const auto e = static_cast<Eigen::Index>(s);
    const double rest = (system.rest_position.col(system.springs.first[s]) - system.rest_position.col(system.springs.second[s])).norm();
    EXPECT_DOUBLE_EQ(system.springs.rest_length[e], rest);
    EXPECT_DOUBLE_EQ(system.springs.stiffness[e], 3.0 / rest);
  }
}

TEST(ModelBuilder, SpringsNeverJoinTwoMuscles) {
  SmallScene scene = spindleBetweenPlates();
  scene.muscles.push_back(makeSpindleMuscle("neighbour", {0.045, 0, 0}, {0.045, 0, 0.2}, 0.02, 1.0, 4, 30));
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
  for (std::size_t s = 0; s < system.springs.size(); ++s)
    EXPECT_EQ(system.muscle_of[system.springs.first[s]], system.muscle_of[system.springs.second[s]]);
}

TEST(ModelBuilder, EveryLayoutBuildsOnTheSpindle) {
  const SmallScene scene = spindleBetweenPlates();
  for (SpringLayout layout : {SpringLayout::nearest_neighbours, SpringLayout::cubic6, SpringLayout::cubic26,
                              SpringLayout::delaunay}) {
    ModelSettings settings = smallSettings();
    settings.spring_layout = layout;
    const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings);
    EXPECT_GT(system.springs.size(), 0u) << toString(layout);
  }
}

TEST(ModelBuilder, InvalidSettingsAreRejectedWithAMessage) {
  const SmallScene scene = spindleBetweenPlates();
  ModelSettings settings = smallSettings();
  settings.particles_per_fibre = 1;
  try {
    buildMassSpringSystem(scene.muscles, scene.bones, settings);
    FAIL() << "expected ModelError";
  } catch (const ModelError& error) {
    EXPECT_NE(std::string(error.what()).find("particles_per_fibre"), std::string::npos);
  }
  settings = smallSettings();
  settings.spring_material_n = -1;
  EXPECT_THROW(buildMassSpringSystem(scene.muscles, scene.bones, settings), ModelError);
}

TEST(ModelBuilder, AMuscleWithoutUsableFibresIsNamedInTheError) {
  SmallScene scene = spindleBetweenPlates();
  scene.muscles[0].fibres = {Polyline::Zero(3, 3)};
  try {
    buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
    FAIL() << "expected ModelError";
  } catch (const ModelError& error) {
    EXPECT_NE(std::string(error.what()).find("spindle"), std::string::npos);
  }
}

TEST(ModelBuilder, DegenerateFibresAreSkippedWithAWarning) {
  SmallScene scene = spindleBetweenPlates();
  scene.muscles[0].fibres.push_back(Polyline::Zero(3, 1));
  ModelBuildReport report;
  buildMassSpringSystem(scene.muscles, scene.bones, smallSettings(), &report);
  EXPECT_EQ(report.muscles[0].skipped_fibres, 1);
  EXPECT_FALSE(report.warnings.empty());
}

// A URDF mesh in millimetres without scale="0.001 0.001 0.001" makes a bone 1000 times too large: most particles
// start inside it, and the model used to build with nothing but a count of them.
TEST(ModelBuilder, ABoneInMillimetresIsRefusedNamingItsSizeBesideTheMusclesAndTheUrdfScale) {
  SyntheticScene scene = makeSyntheticThigh(3, 4);
  ASSERT_EQ(scene.bones[1].name, "femur");
  scene.bones[1].surface.vertices *= 1000.0;
  const std::string message = muscle_deformation::testing::errorMessageOf<ModelError>(
      [&] { buildMassSpringSystem(scene.muscles, scene.bones, smallSettings()); });
  EXPECT_CONTAINS(message, "bone 'femur' is 422 m across");  // 0.42 m long, 28 mm wide: its diagonal in mm
  EXPECT_CONTAINS(message, "times the median muscle (0.");
  EXPECT_CONTAINS(message, "<mesh filename=\"...\" scale=\"0.001 0.001 0.001\"/>");
  EXPECT_EQ(message.find("'pelvis'"), std::string::npos) << message;
  EXPECT_EQ(message.find("'tibia'"), std::string::npos) << message;
}

TEST(ModelBuilder, ABoneAThousandTimesTooSmallIsRefusedNamingItsSizeBesideTheMuscles) {
  SyntheticScene scene = makeSyntheticThigh(3, 4);
  scene.bones[1].surface.vertices *= 0.001;
  const std::string message = muscle_deformation::testing::errorMessageOf<ModelError>(
      [&] { buildMassSpringSystem(scene.muscles, scene.bones, smallSettings()); });
  EXPECT_CONTAINS(message, "bone 'femur' is 0.000422 m across, 1/");
  EXPECT_CONTAINS(message, "of the median muscle (0.");
  EXPECT_CONTAINS(message, "scaled twice");
}

// What the node gets from a URDF whose collision mesh is in millimetres and has no scale: loadScene takes the mesh as
// metres, and the model build refuses the bone, naming its link.
TEST(ModelBuilder, AUrdfMeshInMillimetresWithoutScaleIsRefusedNamingTheLink) {
  const std::string package = MD_PACKAGE_DIR;
  const std::string node_data = package + "/test/data/node";
  TriangleMesh femur = loadTriangleMesh(node_data + "/meshes/femur.stl");
  femur.vertices *= 1000.0;
  const std::string femur_mm = (std::filesystem::temp_directory_path() / "md_model_builder_test_femur_mm.stl").string();
  saveTriangleMeshStl(femur_mm, femur);
  std::ifstream file(node_data + "/thigh.urdf");
  std::string urdf((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  const std::string femur_uri = "package://muscle_deformation/test/data/node/meshes/femur.stl";
  ASSERT_NE(urdf.find(femur_uri), std::string::npos);
  urdf.replace(urdf.find(femur_uri), femur_uri.size(), "file://" + femur_mm);

  const SceneDescription description = loadSceneDescription(node_data + "/thigh.yaml");
  const Scene scene = loadScene(description, Skeleton::fromUrdfString(urdf, "robot_description"),
                                makeUriResolver({{"muscle_deformation", package}}, package));
  std::remove(femur_mm.c_str());
  const std::string message = muscle_deformation::testing::errorMessageOf<ModelError>(
      [&] { buildMassSpringSystem(scene.muscles, scene.bones, ModelSettings{}); });
  EXPECT_CONTAINS(message, "bone 'femur_r' is ");
  EXPECT_CONTAINS(message, "times the median muscle");
  EXPECT_CONTAINS(message, "in the <collision> of link 'femur_r' in the URDF: <mesh filename=\"...\" scale=\"0.001 0.001 0.001\"/>");
}

TEST(ModelBuilder, AMuscleMostlyInsideABoneIsWarnedAboutNamingMuscleBoneAndFraction) {
  SmallScene scene = spindleBetweenPlates();
  // A bone around the middle 80 % of the muscle, as a bone mesh in the wrong place would be.
  const Eigen::Vector3d low(-0.05, -0.05, 0.02), high(0.05, 0.05, 0.18);
  scene.bones.push_back({2, "sleeve", makeBoxMesh(low, high)});
  ModelBuildReport report;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings(), &report);
  int inside = 0;
  for (Eigen::Index i = 0; i < 160; ++i) {
    const Eigen::Vector3d p = system.rest_position.col(i);
    inside += (p.array() > low.array()).all() && (p.array() < high.array()).all() ? 1 : 0;
  }
  ASSERT_GT(inside, 80);
  const std::string expected = "muscle 'spindle': " + std::to_string(inside) + " of 160 particles (" +
                               std::to_string(std::lround(100.0 * inside / 160)) + " %) start inside bone 'sleeve'";
  const auto warning = std::find_if(report.warnings.begin(), report.warnings.end(),
                                    [&](const std::string& w) { return w.find("start inside") != std::string::npos; });
  ASSERT_NE(warning, report.warnings.end()) << "no warning about particles inside a bone";
  EXPECT_CONTAINS(*warning, expected);
  EXPECT_EQ(std::count_if(report.warnings.begin(), report.warnings.end(),
                          [](const std::string& w) { return w.find("start inside") != std::string::npos; }),
            1);
}

TEST(RigidPretransform, SameTransformForEveryBoneMovesEveryParticleRigidly) {
  const SmallScene scene = spindleBetweenPlates();
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
  const Eigen::Isometry3d motion = Eigen::Translation3d(0.1, -0.2, 0.05) *
                                   Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized());
  ParticleState state;
  rigidPretransform(system, {motion, motion}, state);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i)
    EXPECT_LT((state.position.col(i) - motion * system.rest_position.col(i)).norm(), 1e-12);
  EXPECT_EQ(state.previous_position, state.position);
}

TEST(RigidPretransform, FixedParticlesMoveExactlyWithTheirBone) {
  const SmallScene scene = spindleBetweenPlates();
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
  const Eigen::Isometry3d lower(Eigen::Translation3d(0, 0, -0.01));
  const Eigen::Isometry3d upper(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX()));
  ParticleState state;
  rigidPretransform(system, {lower, upper}, state);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (!system.is_fixed[i]) continue;
    const Eigen::Isometry3d& bone = system.fixed_bone[i] == 0 ? lower : upper;
    EXPECT_LT((state.position.col(i) - bone * system.rest_position.col(i)).norm(), 1e-15);
  }
}

TEST(RigidPretransform, RigidMotionOfTheWholeSceneLeavesTheSpringsAtRest) {
  const SmallScene scene = spindleBetweenPlates();
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
  const Eigen::Isometry3d motion = Eigen::Translation3d(0.3, 0, 0) * Eigen::AngleAxisd(1.0, Eigen::Vector3d::UnitY());
  ParticleState state;
  rigidPretransform(system, {motion, motion}, state);
  VerletSolver solver(system, VerletSettings{});
  const SolveStats stats = solver.solve(state, StoppingSettings::atDisplacement(1e-12, 100));
  EXPECT_LT(stats.spring_deviation_ratio, 1e-12);
  EXPECT_LE(stats.iterations, 2);
}

TEST(WarmStart, MovesOnlyTheAttachmentsAndKeepsTheFreeParticles) {
  const SmallScene scene = spindleBetweenPlates();
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
  ParticleState state = restState(system);
  const Eigen::Isometry3d lift(Eigen::Translation3d(0, 0, 0.01));
  moveAttachments(system, {Eigen::Isometry3d::Identity(), lift}, state);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    const Eigen::Vector3d expected =
        system.is_fixed[i] && system.fixed_bone[i] == 1 ? Eigen::Vector3d(lift * system.rest_position.col(i))
                                                          : Eigen::Vector3d(system.rest_position.col(i));
    EXPECT_LT((state.position.col(i) - expected).norm(), 1e-15);
  }
}

TEST(RigidPretransform, RestVectorsTurnWithTheBlendOfTheirBonesRotations) {
  const SmallScene scene = spindleBetweenPlates();
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
  const Eigen::Index n = system.particleCount();
  const Eigen::Matrix3Xd vectors = Eigen::Matrix3Xd::Random(3, n);
  // One motion for both bones: every vector turns with its rotation, and the translation does not move it.
  const Eigen::Isometry3d motion = Eigen::Translation3d(0.1, -0.2, 0.05) *
                                   Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized());
  const Eigen::Matrix3Xd turned = carryRestVectors(system, {motion, motion}, vectors);
  EXPECT_LT((turned - motion.linear() * vectors).cwiseAbs().maxCoeff(), 1e-12);
  // Two bones turned differently: each particle's vector takes the weighted sum of the rotations, as positions blend.
  const Eigen::Isometry3d lower(Eigen::AngleAxisd(-0.4, Eigen::Vector3d::UnitX()));
  const Eigen::Isometry3d upper(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitX()));
  const Eigen::Matrix3Xd blended = carryRestVectors(system, {lower, upper}, vectors);
  for (Eigen::Index i = 0; i < n; ++i) {
    Eigen::Matrix3d expected = Eigen::Matrix3d::Zero();
    double weights = 0;
    for (int k = 0; k < MassSpringSystem::kBlendBones; ++k) {
      const int bone = system.blend_bone(k, i);
      if (bone == kNoBone) continue;
      expected += system.blend_weight(k, i) * (bone == 0 ? lower : upper).linear();
      weights += system.blend_weight(k, i);
    }
    EXPECT_LT((blended.col(i) - expected * vectors.col(i) / weights).norm(), 1e-12) << "particle " << i;
  }
  EXPECT_THROW(carryRestVectors(system, {motion, motion}, Eigen::Matrix3Xd::Zero(3, n - 1)), std::invalid_argument);
}

TEST(RigidPretransform, TooFewBoneTransformsIsAnError) {
  const SmallScene scene = spindleBetweenPlates();
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, smallSettings());
  ParticleState state;
  EXPECT_THROW(rigidPretransform(system, {Eigen::Isometry3d::Identity()}, state), std::invalid_argument);
}

TEST(SurfaceDistance, IsFiniteWhenTheClosestPointIsATriangleCentroid) {
  // The query sits straight above a centroid: the exact distance equals the centroid bound up to rounding.
  const TriangleMesh box = makeBoxMesh({0, 0, 0}, {0.3, 0.3, 0.3}, 0.1);
  const SurfaceDistance surface(box.vertices, box.triangles);
  for (Eigen::Index t = 0; t < box.triangleCount(); ++t) {
    const Eigen::Vector3d a = box.vertices.col(box.triangles(0, t)), b = box.vertices.col(box.triangles(1, t)),
                          c = box.vertices.col(box.triangles(2, t));
    const Eigen::Vector3d normal = (b - a).cross(c - a).normalized();
    const Eigen::Vector3d query = (a + b + c) / 3.0 + 0.0137 * normal;
    EXPECT_NEAR(surface.distance(query), 0.0137, 1e-12) << "triangle " << t;
  }
}
