// Specifications of tendons: a fibre end away from its bone hangs from the muscle's attachment site through its via
// points by a tendon much stiffer than the belly, so that the joint's motion reaches the belly.
#include "muscle_deformation/core/base/median.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/solvers/solve_control.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace muscle_deformation;

namespace {

constexpr double kBelly = 0.1, kTendon = 0.04, kRadius = 0.012;

// A cylindrical belly along z from 0 to kBelly on a bottom bone, its insertion site kTendon above its end on a top bone:
// the tendon was not segmented.
struct HangingScene {
  std::vector<Bone> bones;
  std::vector<Muscle> muscles;
};

HangingScene hangingMuscle(bool with_site = true) {
  HangingScene scene;
  scene.bones.push_back({0, "bottom", makeBoxMesh({-0.03, -0.03, -0.02}, {0.03, 0.03, -0.0005})});
  scene.bones.push_back({1, "top", makeBoxMesh({-0.03, -0.03, kBelly + kTendon}, {0.03, 0.03, kBelly + kTendon + 0.02})});
  Muscle muscle;
  muscle.name = "belly";
  muscle.surface = makeCylinderMesh({0, 0, 0}, {0, 0, kBelly}, kRadius, 24, 16);
  muscle.origin_bone = "bottom";
  muscle.insertion_bone = "top";
  for (int i = -2; i <= 2; ++i)
    for (int j = -2; j <= 2; ++j) {
      const double x = 0.004 * i, y = 0.004 * j;
      if (x * x + y * y > 0.85 * kRadius * 0.85 * kRadius) continue;
      Polyline fibre(3, 11);
      for (int k = 0; k <= 10; ++k) fibre.col(k) = Eigen::Vector3d(x, y, kBelly * k / 10.0);
      muscle.fibres.push_back(fibre);
    }
  if (with_site) muscle.insertion_path = {{"top", Eigen::Vector3d(0, 0, kBelly + kTendon)}};
  scene.muscles.push_back(muscle);
  return scene;
}

PipelineSettings settings(double tendon_ratio) {
  PipelineSettings s;
  s.simulation.solver_kind = SolverKind::block_descent;
  s.simulation.collisions = false;
  s.simulation.model.particles_per_fibre = 10;
  s.simulation.model.tendon_stiffness_ratio = tendon_ratio;
  s.skin_surfaces = false;
  s.measure_fidelity = false;
  s.threads = 1;
  return s;
}

double meanBellyLength(const DeformationPipeline& pipeline) {
  const std::vector<Eigen::Matrix3Xd> fibres = fibrePolylines(pipeline.system(), pipeline.state().position);
  double sum = 0;
  for (const Eigen::Matrix3Xd& fibre : fibres) sum += polylineLength(fibre);
  return sum / static_cast<double>(fibres.size());
}

// The top bone moved up so that the distance between the bones grows by `share`.
BoneTransforms apart(double share) {
  Eigen::Isometry3d top = Eigen::Isometry3d::Identity();
  top.translation().z() = share * (kBelly + kTendon);
  return {Eigen::Isometry3d::Identity(), top};
}

const FrameStopping kConverged = FrameStopping::of(StoppingSettings::atResidual(1e-7, 50000));

// The share by which the belly shortens, each pose solved to convergence, when the bones come 10 % closer.
double bellyShorteningWithBonesTenPercentCloser(const HangingScene& scene, const PipelineSettings& settings) {
  DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
  pipeline.solve(apart(0.0), StartMode::cold, kConverged, false, false);
  const double at_rest_pose = meanBellyLength(pipeline);
  pipeline.solve(apart(-0.10), StartMode::warm, kConverged, false, false);
  return 1.0 - meanBellyLength(pipeline) / at_rest_pose;
}

}  // namespace

TEST(Tendon, AFibreEndAwayFromItsBoneHangsFromTheInsertionSiteNotTheBonesNearestPoint) {
  const HangingScene scene = hangingMuscle();
  ModelBuildReport report;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, ModelSettings{}, &report);
  ASSERT_EQ(report.muscles.size(), 1u);
  EXPECT_EQ(report.muscles[0].tendons, report.muscles[0].fibres);
  EXPECT_EQ(report.muscles[0].tendons_to_sites, report.muscles[0].fibres);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (system.fibre_of[static_cast<std::size_t>(i)] == kTendonAnchor) {
      EXPECT_LT((system.rest_position.col(i) - Eigen::Vector3d(0, 0, kBelly + kTendon)).norm(), 1e-12);
    }
  }
}

TEST(Tendon, AStraightMuscleBetweenTwoBonesThatMoveTenPercentApartStretchesItsBellyAtLeastNinePercent) {
  const HangingScene scene = hangingMuscle();
  const auto stretch = [&](double tendon_ratio) {
    DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, settings(tendon_ratio));
    pipeline.solve(apart(0.0), StartMode::cold, kConverged, false, false);
    const double rest = meanBellyLength(pipeline);
    pipeline.solve(apart(0.10), StartMode::warm, kConverged, false, false);
    return meanBellyLength(pipeline) / rest - 1.0;
  };
  const double soft = stretch(1.0), stiff = stretch(100.0);
  std::printf("bones 10 %% apart: belly stretched %.1f %% with the belly's material in the tendon, %.1f %% with a tendon "
              "100 x stiffer\n", 100 * soft, 100 * stiff);
  EXPECT_GE(stiff, 0.09);
  EXPECT_LT(soft, stiff) << "the soft tendon takes part of the stretch";
}

TEST(Tendon, ABellyUnderPassiveTensionShortensWithItsPathWhereOneAtItsRestLengthGoesSlack) {
  const HangingScene scene = hangingMuscle();
  const auto shortening = [&](double prestretch) {
    PipelineSettings s = settings(100.0);
    s.simulation.model.fibre_prestretch = prestretch;
    return bellyShorteningWithBonesTenPercentCloser(scene, s);
  };
  const double slack = shortening(0.0), tense = shortening(0.2);
  std::printf("bones 10 %% closer: belly shortened %.1f %% at its rest length, %.1f %% pre-stretched by 20 %%\n",
              100 * slack, 100 * tense);
  // The whole 14 cm path shortens by 14 mm; the stiff tendon passes it to the 10 cm belly when the belly is in tension.
  EXPECT_GE(tense, 0.09);
  EXPECT_LT(slack, 0.5 * tense);
}

TEST(Tendon, ABellySoftAcrossItsFibresShortensFurtherWithItsPathAtConstantVolume) {
  const HangingScene scene = hangingMuscle();
  const auto shortening = [&](double transverse_ratio) {
    PipelineSettings s = settings(100.0);
    s.simulation.model.fibre_prestretch = 0.2;
    s.simulation.model.transverse_stiffness_ratio = transverse_ratio;
    s.simulation.block_descent.volume_stiffness = 10.0;
    return bellyShorteningWithBonesTenPercentCloser(scene, s);
  };
  const double isotropic = shortening(1.0), transverse = shortening(0.05);
  std::printf("bones 10 %% closer, volume kept: belly shortened %.1f %% with isotropic springs, %.1f %% with springs "
              "across its fibres 1/20 as stiff\n", 100 * isotropic, 100 * transverse);
  // Shortening at constant volume thickens the belly, which its springs across the fibres resist.
  EXPECT_GT(transverse, isotropic + 0.01);
  EXPECT_GE(transverse, 0.09);
}

TEST(Tendon, SpringsAcrossTheFibresTakeTheTransverseShareOfTheStiffnessAndThoseAlongThemAllOfIt) {
  const HangingScene scene = hangingMuscle();
  ModelSettings s = settings(10.0).simulation.model;
  s.transverse_stiffness_ratio = 0.05;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, s);
  int along = 0, across = 0;
  for (std::size_t k = 0; k < system.springs.size(); ++k) {
    const std::int32_t a = system.springs.first[k], b = system.springs.second[k];
    if (system.fibre_of[static_cast<std::size_t>(a)] == kTendonAnchor || system.fibre_of[static_cast<std::size_t>(b)] == kTendonAnchor)
      continue;
    const auto spring = static_cast<Eigen::Index>(k);
    const Eigen::Vector3d d = system.rest_position.col(b) - system.rest_position.col(a);
    const double alignment = d.z() / d.norm();  // the fibres run along z
    const double expected = s.spring_material_n / system.springs.rest_length[spring] *
                            (alignment * alignment + 0.05 * (1 - alignment * alignment));
    EXPECT_NEAR(system.springs.stiffness[spring], expected, 1e-9 * expected) << "spring " << k;
    along += std::abs(alignment) > 0.999;
    across += std::abs(alignment) < 0.001;
  }
  EXPECT_GT(along, 0);
  EXPECT_GT(across, 0);
}

TEST(Tendon, ATransverseStiffnessRatioOutsideZeroToOneIsRefused) {
  ModelSettings s;
  for (const double bad : {0.0, -0.1, 1.5, std::nan("")}) {
    s.transverse_stiffness_ratio = bad;
    EXPECT_NE(validate(s).find("transverse_stiffness_ratio"), std::string::npos) << bad;
  }
  s.transverse_stiffness_ratio = 0.05;
  EXPECT_TRUE(validate(s).empty());
}

TEST(Tendon, APreTensionedBellyInItsSegmentedShapeHasNoStrainThoughItsSpringsRestShorter) {
  const HangingScene scene = hangingMuscle();
  ModelSettings s = settings(10.0).simulation.model;
  s.fibre_prestretch = 0.2;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, s);
  const SpringMetrics at_rest = measureSprings(system.springs, system.rest_position);
  EXPECT_NEAR(at_rest.max_strain, 0.0, 1e-12);
  // The springs along the fibres rest a fifth shorter; stretched 10 % along the fibres, those show 10 % strain.
  ASSERT_EQ(system.springs.prestretch_factor.size(), static_cast<Eigen::Index>(system.springs.size()));
  EXPECT_NEAR(system.springs.prestretch_factor.minCoeff(), 0.8, 1e-9);
  Eigen::Matrix3Xd stretched = system.rest_position;
  stretched.row(2) *= 1.1;
  EXPECT_NEAR(measureSprings(system.springs, stretched).max_strain, 0.1, 1e-9);
}

TEST(Tendon, APrestretchOutsideZeroToAHalfIsRefused) {
  ModelSettings s;
  s.fibre_prestretch = 0.6;
  EXPECT_NE(validate(s).find("fibre_prestretch"), std::string::npos);
  s.fibre_prestretch = -0.1;
  EXPECT_NE(validate(s).find("fibre_prestretch"), std::string::npos);
  s.fibre_prestretch = 0.2;
  EXPECT_TRUE(validate(s).empty());
}

TEST(Tendon, ATendonOverAViaPointOnAnotherBoneFollowsThatBonesMotionWithItsWholeLength) {
  // The site on the bottom bone, reached over a via point on the top bone: moving the top bone along the via-site line
  // changes the fixed part of the path, and the tendon's spring takes up exactly that change.
  HangingScene scene = hangingMuscle(false);
  scene.muscles[0].insertion_path = {{"top", Eigen::Vector3d(0, 0, kBelly + kTendon)},
                                     {"bottom", Eigen::Vector3d(0.05, 0, kBelly + kTendon)}};
  MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, ModelSettings{});
  ASSERT_FALSE(system.tendon_paths.empty());
  const TendonPath& tendon = system.tendon_paths.front();
  const double rest = system.springs.rest_length[tendon.spring];
  EXPECT_NEAR(tendon.length_m - rest, 0.05, 1e-12) << "the whole length is the spring's plus the via-site segment";
  Eigen::Isometry3d top = Eigen::Isometry3d::Identity();
  top.translation().x() = 0.01;  // the via point moves 1 cm towards the site
  EXPECT_TRUE(updateTendonRestLengths(system, {Eigen::Isometry3d::Identity(), top}));
  EXPECT_NEAR(system.springs.rest_length[tendon.spring], rest + 0.01, 1e-12);
  EXPECT_FALSE(updateTendonRestLengths(system, {Eigen::Isometry3d::Identity(), top})) << "nothing changed";
}

TEST(Tendon, TheBundledScenesTendonPathsAreInTheSceneFrameOnTheirLinksBones) {
  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR, {"rectus_femoris"});
  ASSERT_EQ(bundled.scene.muscles.size(), 1u);
  const Muscle& rectus = bundled.scene.muscles[0];
  const MuscleDescription& description = bundled.scene.muscle_descriptions[0];
  ASSERT_EQ(rectus.insertion_path.size(), description.insertion_path.size());
  ASSERT_FALSE(rectus.insertion_path.empty());
  for (std::size_t k = 0; k < rectus.insertion_path.size(); ++k) {
    const SitePoint& written = description.insertion_path[k];
    EXPECT_EQ(rectus.insertion_path[k].bone, written.link);
    const Eigen::Vector3d expected = bundled.scene.rest_link_poses.at(written.link) * written.point;
    EXPECT_LT((rectus.insertion_path[k].point - expected).norm(), 1e-12);
  }
  EXPECT_EQ(rectus.insertion_path.front().bone, "patella_r");
  EXPECT_FALSE(description.reference_muscles.empty());
}

TEST(Tendon, ASiteOnALinkWithoutABoneIsRefusedNamingTheMuscleAndTheLink) {
  const std::string package = MD_PACKAGE_DIR;
  SceneDescription description = loadSceneDescription(package + "/config/scenes/right_hip_thigh.yaml");
  for (MuscleDescription& m : description.muscles)
    if (m.name == "rectus_femoris") m.insertion_path.push_back({"knee_tx_r_link", Eigen::Vector3d::Zero()});
  const Skeleton skeleton = Skeleton::fromUrdfFile(package + "/urdf/right_hip_thigh.urdf");
  try {
    loadScene(description, skeleton, makeUriResolver({{"muscle_deformation", package}}, package), {"rectus_femoris"});
    FAIL() << "a site on a link without a bone was accepted";
  } catch (const SceneError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("rectus_femoris"), std::string::npos) << message;
    EXPECT_NE(message.find("knee_tx_r_link"), std::string::npos) << message;
  }
}

// The share by which a toned belly's rest length changes at `transforms`, as the mean over its fibres of the span's
// change over the belly's length, both from the model (the sampled fibres end a little inside the surface).
double tonedShare(const MassSpringSystem& system, const BoneTransforms& transforms) {
  double sum = 0;
  for (const FibreSpan& span : system.belly_tone.fibres) {
    const Eigen::Vector3d first = transforms[static_cast<std::size_t>(system.fixed_bone[static_cast<std::size_t>(span.first_anchor)])] *
                                  system.rest_position.col(span.first_anchor);
    const Eigen::Vector3d last = transforms[static_cast<std::size_t>(system.fixed_bone[static_cast<std::size_t>(span.last_anchor)])] *
                                 system.rest_position.col(span.last_anchor);
    sum += ((first - last).norm() - span.rest_span_m) / span.belly_length_m;
  }
  return sum / static_cast<double>(system.belly_tone.fibres.size());
}

TEST(Tendon, ATonedBellyTakesItsPathsWholeChangeWhereAPassiveOneSharesItWithAnElasticTendon) {
  // The tendon as soft as the belly's material (ratio 1), so that a passive belly leaves part of the path's change to
  // it. Bones 10 % closer shorten the 14 cm path by 14 mm; a belly with full tone (its rest length following the
  // span between its attachments) takes all of it: about 14 % of its 10 cm.
  const HangingScene scene = hangingMuscle();
  const auto shortening = [&](double tone) {
    PipelineSettings s = settings(1.0);
    s.simulation.model.fibre_prestretch = 0.2;
    s.simulation.model.fibre_tone = tone;
    return bellyShorteningWithBonesTenPercentCloser(scene, s);
  };
  ModelSettings model = settings(1.0).simulation.model;
  model.fibre_tone = 1.0;
  const double expected = -tonedShare(buildMassSpringSystem(scene.muscles, scene.bones, model), apart(-0.10));
  const double passive = shortening(0.0), toned = shortening(1.0);
  std::printf("bones 10 %% closer, tendon as soft as the belly: belly shortened %.1f %% passive, %.1f %% toned (its "
              "rest length %.1f %%)\n", 100 * passive, 100 * toned, 100 * expected);
  EXPECT_GT(expected, 0.14);  // the belly is a little shorter than 10 cm
  EXPECT_LT(expected, 0.16);
  EXPECT_NEAR(toned, expected, 0.005);
  EXPECT_LT(passive, toned - 0.02);
}

// The hanging muscle's model with the belly's full tone, 10 particles per fibre.
MassSpringSystem tonedHangingSystem() {
  const HangingScene scene = hangingMuscle();
  ModelSettings model;
  model.particles_per_fibre = 10;
  model.fibre_tone = 1.0;
  return buildMassSpringSystem(scene.muscles, scene.bones, model);
}

TEST(Tendon, TheTonesRestLengthsFollowTheSpanAlongTheFibresOnlyAndComeBackAtRest) {
  MassSpringSystem system = tonedHangingSystem();
  const BellyTone& tone = system.belly_tone;
  ASSERT_FALSE(tone.empty());
  for (const FibreSpan& span : tone.fibres) {
    ASSERT_GE(span.first_anchor, 0);
    // The fixed origin on the bottom bone to the site above the belly; the sampled fibre ends a little inside.
    EXPECT_NEAR(span.rest_span_m, kBelly + kTendon, 1e-3);
    EXPECT_GT(span.belly_length_m, 0.085);
    EXPECT_LE(span.belly_length_m, kBelly);
    EXPECT_EQ(system.fixed_bone[static_cast<std::size_t>(span.first_anchor)], 0);
    EXPECT_EQ(system.fixed_bone[static_cast<std::size_t>(span.last_anchor)], 1);
  }
  const Eigen::VectorXd untoned = system.springs.rest_length;
  EXPECT_FALSE(updateBellyTone(system, apart(0.0))) << "at rest the rest lengths are the model's";
  ASSERT_TRUE(updateBellyTone(system, apart(0.10)));
  const BoneTransforms moved = apart(0.10);
  const auto fibreFactor = [&](std::int32_t f) {
    const FibreSpan& span = tone.fibres[static_cast<std::size_t>(f)];
    const Eigen::Vector3d first = system.rest_position.col(span.first_anchor);
    const Eigen::Vector3d last = moved[1] * system.rest_position.col(span.last_anchor);
    return 1.0 + ((first - last).norm() - span.rest_span_m) / span.belly_length_m;
  };
  int along = 0, across = 0;
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const auto e = static_cast<Eigen::Index>(s);
    if (tone.first_fibre[s] < 0) {
      EXPECT_EQ(system.springs.rest_length[e], untoned[e]) << "a tendon keeps its own rest length";
      continue;
    }
    const Eigen::Vector3d d = system.rest_position.col(system.springs.second[s]) -
                              system.rest_position.col(system.springs.first[s]);
    const double cosine = std::abs(d.normalized().z());
    const double factor = 0.5 * (fibreFactor(tone.first_fibre[s]) + fibreFactor(tone.second_fibre[s]));
    if (cosine > 1 - 1e-9) {
      EXPECT_GT(factor, 1.13);  // 14 mm more span on a belly of about 10 cm
      EXPECT_NEAR(system.springs.rest_length[e], untoned[e] * factor, 1e-12);
      ++along;
    } else if (cosine < 1e-9) {
      EXPECT_NEAR(system.springs.rest_length[e], untoned[e], 1e-12);
      ++across;
    }
  }
  EXPECT_GT(along, 0);
  EXPECT_GT(across, 0);
  ASSERT_TRUE(updateBellyTone(system, apart(0.0)));
  EXPECT_LT((system.springs.rest_length - untoned).cwiseAbs().maxCoeff(), 1e-15);
}

// A belly that bends round a bone (the iliacus over the pelvic brim) follows the line through the point it bends at,
// not the straight line between its attachments: its span runs from the first anchor through the muscle's belly path
// (points carried by their bones) to the last anchor. Here the path point sits on the bottom bone beside the belly's
// middle, and the top bone moves sideways: the span changes as the segment from that point to the top anchor does.
TEST(Tendon, TheTonesSpanRunsThroughTheBellyPathPointsEachCarriedByItsBone) {
  HangingScene scene = hangingMuscle();
  const Eigen::Vector3d bend(0.02, 0.0, 0.05);
  scene.muscles[0].belly_path = {{"bottom", bend}};
  ModelSettings model;
  model.particles_per_fibre = 10;
  model.fibre_tone = 1.0;
  MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, model);
  const BellyTone& tone = system.belly_tone;
  ASSERT_EQ(tone.belly_paths.size(), 1u);
  ASSERT_EQ(tone.belly_paths[0].bones, std::vector<std::int32_t>{0});
  Eigen::Isometry3d sideways = Eigen::Isometry3d::Identity();
  sideways.translation() = Eigen::Vector3d(0.03, 0, 0);
  const BoneTransforms moved = {Eigen::Isometry3d::Identity(), sideways};
  const Eigen::Vector3d site(0, 0, kBelly + kTendon);
  int spans = 0;
  for (const FibreSpan& span : tone.fibres) {
    ASSERT_GE(span.first_anchor, 0);
    EXPECT_EQ(span.muscle, 0);
    const Eigen::Vector3d first = system.rest_position.col(span.first_anchor);
    const Eigen::Vector3d last = system.rest_position.col(span.last_anchor);
    const double beyond = (site - last).norm();  // the insertion tendon's path past its anchor, rigid with the top bone
    EXPECT_NEAR(span.rest_span_m, (bend - first).norm() + (last - bend).norm() + beyond, 1e-12);
    EXPECT_NEAR(fibreSpanLength(system, tone, span, moved),
                (bend - first).norm() + (sideways * last - bend).norm() + beyond, 1e-12);
    // The straight line would not see the bend: the two spans differ by more than a millimetre here.
    EXPECT_GT(std::abs(fibreSpanLength(system, tone, span, moved) - span.rest_span_m -
                       ((sideways * last - first).norm() - (last - first).norm())),
              1e-3);
    ++spans;
  }
  EXPECT_GT(spans, 0);
  // A belly path naming a bone the model lacks is refused by name.
  scene.muscles[0].belly_path = {{"nowhere", bend}};
  EXPECT_CONTAINS(muscle_deformation::testing::errorMessageOf<ModelError>(
                      [&] { buildMassSpringSystem(scene.muscles, scene.bones, model); }),
                  "belly path names bone 'nowhere'");
}

// On real anatomy: the bundled iliacus bends over the pelvic brim (its belly path: gait2392's via points the belly
// covers, two on the pelvis, one on the femur). Hip flexion shortens its path, as in gait2392 (-41 mm/rad at rest); the
// straight line from its fossa anchors to the lesser trochanter passes behind the brim and lengthens instead.
TEST(Tendon, TheBundledIliacusSpanShortensInHipFlexionAlongItsBellyPath) {
  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR, {"iliacus"});
  ASSERT_EQ(bundled.scene.muscles.size(), 1u);
  ASSERT_EQ(bundled.scene.muscles[0].belly_path.size(), 3u);
  ModelSettings model;
  model.fibre_tone = 1.0;
  const MassSpringSystem system = buildMassSpringSystem(bundled.scene.muscles, bundled.scene.bones, model);
  const BellyTone& tone = system.belly_tone;
  const BoneTransforms flexed = boneTransformsOf(bundled.scene.bones, poseFor(bundled, {{"hip_flexion_r", 0.5}}));
  BellyTone straight = tone;
  straight.belly_paths.clear();
  double along_path = 0, straight_line = 0;
  int spans = 0;
  for (const FibreSpan& span : tone.fibres) {
    if (span.first_anchor < 0) continue;
    along_path += fibreSpanLength(system, tone, span, flexed) - span.rest_span_m;
    straight_line += fibreSpanLength(system, straight, span, flexed) - fibreSpanLength(system, straight, span, {});
    ++spans;
  }
  ASSERT_GT(spans, 0);
  along_path /= spans;
  straight_line /= spans;
  std::printf("iliacus, hip flexion 0.5 rad: mean span change %.1f mm along its belly path, %+.1f mm straight\n",
              1e3 * along_path, 1e3 * straight_line);
  EXPECT_LT(along_path, -0.010);  // gait2392: about -20 mm over 0.5 rad
  EXPECT_GT(straight_line, along_path + 0.010);
}

TEST(Tendon, AToneOutsideZeroToTwoIsRefused) {
  ModelSettings s;
  for (const double tone : {-0.1, 2.5, std::nan("")}) {
    s.fibre_tone = tone;
    EXPECT_NE(validate(s).find("fibre_tone"), std::string::npos) << tone;
  }
  s.fibre_tone = 1.0;
  EXPECT_TRUE(validate(s).empty());
}

// The tissue carries a belly along its fibres as its tone changes (SimulationSettings::drag_follows_tone): each fibre of
// the carried shape stretches along itself about its fixed particles by the tone's change, by no more, and by at most
// kMaxToneStretchPerFrame a frame.
TEST(Tendon, TheCarriedBellyStretchesAlongItsFibresAboutTheirFixedEndsByTheTonesChangeAndNoFurther) {
  MassSpringSystem system = tonedHangingSystem();
  const Eigen::VectorXd stiffness = springStiffnessSums(system);
  const std::vector<double> rest_arcs = fibreArcLengths(system, system.rest_position);
  ASSERT_EQ(rest_arcs.size(), system.belly_tone.fibres.size());

  // The shape stretched from rest to the tone at `bones` (the bottom bone does not move, so the rest shape is where the
  // bones carry it), and each free particle's expected move along z: f - 1 (held to the frame's limit) times its height
  // above its fibre's last fixed particle, less by the ratio of its stiffness over the fibre's median where above it.
  const auto check = [&](const BoneTransforms& bones, double expected_ratio_limit) {
    updateBellyTone(system, bones);
    const std::vector<double> factor = system.belly_tone.factor;
    Eigen::Matrix3Xd carried = system.rest_position;
    stretchWithTone(system, stiffness, {}, rest_arcs, carried);
    std::size_t fibre = 0;
    int moved_fully = 0, free_particles = 0;
    forEachFibre(system, [&](Eigen::Index begin, Eigen::Index count) {
      const double f = std::min(factor[fibre++], 1.0 + expected_ratio_limit);
      ASSERT_GT(f, 1.0);
      ASSERT_TRUE(system.is_fixed[static_cast<std::size_t>(begin)]) << "the fibre starts on the bottom bone";
      double z0 = system.rest_position(2, begin);  // its last fixed particle (within the attachment distance)
      std::vector<double> free_stiffness;
      for (Eigen::Index i = begin; i < begin + count; ++i) {
        if (system.is_fixed[static_cast<std::size_t>(i)])
          z0 = system.rest_position(2, i);
        else
          free_stiffness.push_back(stiffness[i]);
      }
      const double median = upperMedian(free_stiffness);
      for (Eigen::Index i = begin; i < begin + count; ++i) {
        const Eigen::Vector3d change = carried.col(i) - system.rest_position.col(i);
        if (system.is_fixed[static_cast<std::size_t>(i)]) {
          EXPECT_EQ(change.norm(), 0.0);
          continue;
        }
        ++free_particles;
        EXPECT_LT(change.head<2>().norm(), 1e-15) << "along the fibre only";
        EXPECT_GT(change.z(), 0.0);
        EXPECT_NEAR(change.z(), (f - 1.0) * (system.rest_position(2, i) - z0) * std::min(1.0, median / stiffness[i]),
                    1e-15);
        if (stiffness[i] <= median) ++moved_fully;
      }
    });
    EXPECT_GT(2 * moved_fully, free_particles);
    return carried;
  };
  // 0.5 % apart: the tone's change (about 0.7 %) is within a frame's limit; 10 % apart (about 14 %): held to it.
  ASSERT_LT(kMaxToneStretchPerFrame, 0.14);
  const Eigen::Matrix3Xd carried = check(apart(0.005), 1.0);
  check(apart(0.10), kMaxToneStretchPerFrame);

  // The tone unchanged since the frame before: nothing moves.
  updateBellyTone(system, apart(0.005));
  const std::vector<double> factor = system.belly_tone.factor;
  Eigen::Matrix3Xd again = carried;
  stretchWithTone(system, stiffness, factor, fibreArcLengths(system, carried), again);
  EXPECT_EQ((again - carried).cwiseAbs().maxCoeff(), 0.0);

  // What the carrying already stretched is not added again: a shape the bones carried to the toned length stays.
  Eigen::Matrix3Xd stretched = system.rest_position;
  std::size_t fibre = 0;
  forEachFibre(system, [&](Eigen::Index begin, Eigen::Index count) {
    const double f = factor[fibre++];
    for (Eigen::Index i = begin + 1; i < begin + count; ++i)
      stretched(2, i) = system.rest_position(2, begin) + f * (system.rest_position(2, i) - system.rest_position(2, begin));
  });
  Eigen::Matrix3Xd kept = stretched;
  stretchWithTone(system, stiffness, {}, rest_arcs, kept);
  EXPECT_LT((kept - stretched).cwiseAbs().maxCoeff(), 1e-15);

  // Nor against the tone: carried past the toned length, the fibre is left to its springs.
  Eigen::Matrix3Xd beyond = system.rest_position;
  beyond.row(2) *= 1.3;
  Eigen::Matrix3Xd left = beyond;
  stretchWithTone(system, stiffness, {}, rest_arcs, left);
  EXPECT_EQ((left - beyond).cwiseAbs().maxCoeff(), 0.0);
}

// At one sweep a frame the tissue drag holds a belly near the previous frame's length carried rigidly; carried along
// its fibres with its tone, the belly takes the tone's length within the frames the bones take to move. (In this short
// straight belly the carrying, a blend of the two bones, already stretches it most of the way; on the bundled gait the
// drag carrying rigidly left the biceps femoris short head a third of gait2392's excursion, docs/lengths.md.)
TEST(Tendon, AStreamedBellyTakesItsTonesLengthWhenTheDragFollowsTheTone) {
  const HangingScene scene = hangingMuscle();
  const auto stretch = [&](bool drag_follows_tone) {
    PipelineSettings s = settings(10.0);
    s.simulation.model.fibre_prestretch = 0.2;
    s.simulation.model.fibre_tone = 1.0;
    s.simulation.block_descent.tissue_relaxation_s = 0.001;
    s.simulation.drag_follows_tone = drag_follows_tone;
    DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, s);
    pipeline.solve(apart(0.0), StartMode::cold, kConverged, false, false);
    const double rest = meanBellyLength(pipeline);
    const FrameStopping one_sweep = FrameStopping::of(StoppingSettings::afterIterations(1));
    for (int frame = 1; frame <= 20; ++frame)  // 0.7 % of the tone a frame, within a frame's limit
      pipeline.solve(apart(0.005 * frame), StartMode::warm, one_sweep, false, false);
    return meanBellyLength(pipeline) / rest - 1.0;
  };
  ModelSettings model = settings(10.0).simulation.model;
  model.fibre_tone = 1.0;
  const double toned = tonedShare(buildMassSpringSystem(scene.muscles, scene.bones, model), apart(0.10));
  const double rigid = stretch(false), following = stretch(true);
  std::printf("bones 10 %% apart over 20 frames of one sweep: the tone asks %.1f %%, the belly stretched %.1f %% with the "
              "drag carrying it rigidly, %.1f %% with the drag following the tone\n", 100 * toned, 100 * rigid,
              100 * following);
  EXPECT_GT(following, 0.95 * toned);
  EXPECT_LT(following, 1.05 * toned);
  EXPECT_LT(rigid, following);
}

// A frame continued from another stream's answer (DeformationPipeline::continueFrom: the service's warm start, the
// benches' references) is the frame that stream solves: the tissue's stretch starts from the tone at the pose continued,
// not at the pose the pipeline solved last.
TEST(Tendon, AFrameContinuedFromAnotherStreamStretchesFromTheToneAtThePoseContinued) {
  const HangingScene scene = hangingMuscle();
  PipelineSettings s = settings(10.0);
  s.simulation.model.fibre_prestretch = 0.2;
  s.simulation.model.fibre_tone = 1.0;
  s.simulation.block_descent.tissue_relaxation_s = 0.001;
  s.simulation.drag_follows_tone = true;
  s.simulation.prediction.predict_start = false;  // both frames start where the tissue carries the particles
  const FrameStopping one_sweep = FrameStopping::of(StoppingSettings::afterIterations(1));
  const FrameStopping five_sweeps = FrameStopping::of(StoppingSettings::afterIterations(5));
  DeformationPipeline stream(describedByName(scene.muscles), scene.muscles, scene.bones, s);
  stream.solve(apart(0.0), StartMode::cold, kConverged, false, false);
  stream.solve(apart(0.005), StartMode::warm, one_sweep, false, false);
  const Eigen::Matrix3Xd continued = stream.state().position;
  stream.solve(apart(0.01), StartMode::warm, five_sweeps, false, false);

  DeformationPipeline other(describedByName(scene.muscles), scene.muscles, scene.bones, s);
  other.solve(apart(0.0), StartMode::cold, kConverged, false, false);
  other.solve(apart(-0.05), StartMode::warm, one_sweep, false, false);  // a tone far from the one continued
  other.continueFrom(apart(0.005), continued);
  other.solve(apart(0.01), StartMode::warm, five_sweeps, false, false);
  EXPECT_LT((other.state().position - stream.state().position).cwiseAbs().maxCoeff(), 1e-12);
}
