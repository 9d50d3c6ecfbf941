// Specifications of incompressibility in the model: each muscle's skinned volume as a term of the frame energy that block
// descent and Newton-Krylov minimise (surfaces/skinned_volume.hpp, solvers/volume_term.hpp).
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/solvers/block_descent_solver.hpp"
#include "muscle_deformation/core/surfaces/skinned_volume.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <random>

using namespace muscle_deformation;

namespace {

constexpr double kLength = 0.1, kRadius = 0.015;

// A cylindrical muscle along z from 0 to kLength between two box bones, with straight fibres on a grid across it,
// origin on the bottom bone and insertion on the top one.
struct CylinderScene {
  std::vector<Bone> bones;
  std::vector<Muscle> muscles;
};

CylinderScene cylinderScene() {
  CylinderScene scene;
  scene.bones.push_back({0, "bottom", makeBoxMesh({-0.03, -0.03, -0.02}, {0.03, 0.03, -0.0005})});
  scene.bones.push_back({1, "top", makeBoxMesh({-0.03, -0.03, kLength + 0.0005}, {0.03, 0.03, kLength + 0.02})});
  Muscle muscle;
  muscle.name = "cylinder";
  muscle.surface = makeCylinderMesh({0, 0, 0}, {0, 0, kLength}, kRadius, 24, 20);
  muscle.origin_bone = "bottom";
  muscle.insertion_bone = "top";
  const int per_side = 6;
  for (int i = 0; i < per_side; ++i)
    for (int j = 0; j < per_side; ++j) {
      const double x = kRadius * 0.85 * (2.0 * (i + 0.5) / per_side - 1.0);
      const double y = kRadius * 0.85 * (2.0 * (j + 0.5) / per_side - 1.0);
      if (x * x + y * y > 0.85 * 0.85 * kRadius * kRadius) continue;
      Polyline fibre(3, 21);
      for (int k = 0; k <= 20; ++k) fibre.col(k) = Eigen::Vector3d(x, y, kLength * k / 20.0);
      muscle.fibres.push_back(fibre);
    }
  scene.muscles.push_back(muscle);
  return scene;
}

PipelineSettings cylinderSettings(double volume_stiffness, int threads = 1) {
  PipelineSettings settings;
  settings.simulation.solver_kind = SolverKind::block_descent;
  settings.simulation.collisions = false;
  settings.simulation.model.particles_per_fibre = 12;
  settings.simulation.model.tendons = false;
  settings.simulation.block_descent.volume_stiffness = volume_stiffness;
  settings.skin_surfaces = true;
  settings.measure_fidelity = false;
  settings.threads = threads;
  return settings;
}

// The top bone moved down the axis by `shortening` of the length.
BoneTransforms shortened(double shortening) {
  Eigen::Isometry3d top = Eigen::Isometry3d::Identity();
  top.translation() = Eigen::Vector3d(0, 0, -shortening * kLength);
  return {Eigen::Isometry3d::Identity(), top};
}

const FrameStopping kConverged = FrameStopping::of(StoppingSettings::atResidual(1e-6, 20000));
// The volume term's stiffness these tests run: a cylinder shortened 30 % keeps its volume within 2 % from about 30 up
// (measured 2026-11-26: 0.9925 of rest at 100). The node's default (config/muscle_deformation.yaml) is chosen on the
// bundled gait instead, where one sweep a frame must also follow the joints.
constexpr double kVolumeStiffness = 100;

double skinnedVolumeOf(const DeformationPipeline& pipeline) {
  const SkinnedVolume volume(*pipeline.skinning(), pipeline.system());
  std::vector<double> volumes;
  volume.volumes(pipeline.state().position, pipeline.boneTransforms(), volumes);
  return volumes[0] / volume.restVolumes()[0];
}

// Mean distance from the axis of the skin's vertices within 5 % of the length around the middle of the muscle.
double middleRadius(const DeformationPipeline& pipeline, double shortening) {
  Vertices skin;
  pipeline.skinning()->muscles()[0].update(pipeline.state().position, pipeline.boneTransforms(), skin);
  const double middle = 0.5 * (1.0 - shortening) * kLength;
  // About the centre of the same vertices: a muscle that is not attached may have slid sideways between the bones.
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  int count = 0;
  for (Eigen::Index v = 0; v < skin.cols(); ++v)
    if (std::abs(skin(2, v) - middle) <= 0.05 * kLength) {
      centre += skin.col(v).head<2>();
      ++count;
    }
  if (count == 0) return 0.0;
  centre /= count;
  double sum = 0;
  for (Eigen::Index v = 0; v < skin.cols(); ++v)
    if (std::abs(skin(2, v) - middle) <= 0.05 * kLength) sum += (skin.col(v).head<2>() - centre).norm();
  return sum / count;
}

}  // namespace

TEST(VolumeTerm, TheSkinnedVolumesGradientIsItsFiniteDifference) {
  const CylinderScene scene = cylinderScene();
  DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, cylinderSettings(0));
  const SkinnedVolume volume(*pipeline.skinning(), pipeline.system());
  // A deformed state: the rest particles moved at random by up to 2 mm.
  std::mt19937 random(7);
  std::uniform_real_distribution<double> offset(-0.002, 0.002);
  Eigen::Matrix3Xd position = pipeline.system().rest_position;
  for (Eigen::Index i = 0; i < position.cols(); ++i) position.col(i) += Eigen::Vector3d(offset(random), offset(random), offset(random));
  std::vector<double> volumes;
  Eigen::Matrix3Xd gradients;
  volume.evaluate(position, {}, volumes, gradients);
  const double h = 1e-7;
  int checked = 0;
  for (Eigen::Index p = 0; p < position.cols(); p += 7) {
    if (gradients.col(p).norm() == 0) continue;
    for (int axis = 0; axis < 3; ++axis) {
      Eigen::Matrix3Xd plus = position, minus = position;
      plus(axis, p) += h;
      minus(axis, p) -= h;
      std::vector<double> up, down;
      volume.volumes(plus, {}, up);
      volume.volumes(minus, {}, down);
      EXPECT_NEAR(gradients(axis, p), (up[0] - down[0]) / (2 * h), 1e-6 * gradients.col(p).norm() + 1e-12)
          << "particle " << p << " axis " << axis;
    }
    ++checked;
  }
  EXPECT_GT(checked, 10);
  // Linear in one particle: a large move of one particle changes the volume by exactly g . d.
  const Eigen::Index p = 3;
  Eigen::Matrix3Xd moved = position;
  const Eigen::Vector3d d(0.003, -0.002, 0.004);
  moved.col(p) += d;
  std::vector<double> after;
  volume.volumes(moved, {}, after);
  EXPECT_NEAR(after[0] - volumes[0], gradients.col(p).dot(d), 1e-12 * std::abs(volumes[0]));
}

TEST(VolumeTerm, TheVolumesCurvatureAlongADirectionIsTheGradientsFiniteDifference) {
  const CylinderScene scene = cylinderScene();
  DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, cylinderSettings(0));
  const SkinnedVolume volume(*pipeline.skinning(), pipeline.system());
  std::mt19937 random(11);
  std::uniform_real_distribution<double> offset(-0.002, 0.002);
  Eigen::Matrix3Xd position = pipeline.system().rest_position, direction(3, position.cols());
  for (Eigen::Index i = 0; i < position.cols(); ++i) {
    position.col(i) += Eigen::Vector3d(offset(random), offset(random), offset(random));
    direction.col(i) = Eigen::Vector3d(offset(random), offset(random), offset(random)) / 0.002;
  }
  Eigen::Matrix3Xd curvature;
  volume.curvatureTimes(position, {}, direction, {1.0}, curvature);
  const double h = 1e-6;
  std::vector<double> unused;
  Eigen::Matrix3Xd up, down;
  volume.evaluate(position + h * direction, {}, unused, up);
  volume.evaluate(position - h * direction, {}, unused, down);
  const Eigen::Matrix3Xd difference = (up - down) / (2 * h);
  EXPECT_LT((curvature - difference).norm(), 1e-6 * difference.norm());
  EXPECT_GT(difference.norm(), 0.0);
}

TEST(VolumeTerm, BlockDescentsFrameForcesAndHessianIncludeTheVolumeTermAndMatchFiniteDifferences) {
  const CylinderScene scene = cylinderScene();
  DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, cylinderSettings(0));
  const MassSpringSystem& system = pipeline.system();
  const SkinnedVolume volume(*pipeline.skinning(), system);
  VolumeTerm term;
  term.rest_volume_m3 = volume.restVolumes();
  term.stiffness = {1e9};  // strong enough to dominate the springs where the volume is off by a few percent
  term.evaluate = [&](const Eigen::Matrix3Xd& x, std::vector<double>& v, Eigen::Matrix3Xd& g) {
    volume.evaluate(x, {}, v, g);
  };
  term.curvature_times = [&](const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& d, const std::vector<double>& w,
                             Eigen::Matrix3Xd& out) { volume.curvatureTimes(x, {}, d, w, out); };
  BlockDescentSolver solver(system, BlockDescentSettings{}, 1);
  solver.setVolumeTerm(term);
  // The muscle squeezed across its axis by 5 %: the volume term pushes outwards.
  ParticleState state = restState(system);
  state.position.row(0) *= 0.95;
  state.position.row(1) *= 0.95;
  for (Eigen::Index i = 0; i < state.position.cols(); ++i)
    if (system.is_fixed[static_cast<std::size_t>(i)]) state.position.col(i) = system.rest_position.col(i);
  solver.beginFrame(state);
  Eigen::Matrix3Xd force;
  std::vector<Eigen::Matrix3d> blocks;
  solver.frameForces(state.position, force, blocks);
  const double h = 1e-7;
  int checked = 0;
  for (const std::int32_t p : solver.freeParticles()) {
    if (p % 5 != 0) continue;
    for (int axis = 0; axis < 3; ++axis) {
      Eigen::Matrix3Xd plus = state.position, minus = state.position;
      plus(axis, p) += h;
      minus(axis, p) -= h;
      const double numeric = -(solver.frameEnergy(plus) - solver.frameEnergy(minus)) / (2 * h);
      EXPECT_NEAR(force(axis, p), numeric, 1e-5 * force.col(p).norm() + 1e-9) << "particle " << p;
    }
    ++checked;
  }
  EXPECT_GT(checked, 10);
  // Hessian along a direction of the free particles: the derivative of the forces. The springs' Hessian is projected
  // to be positive semi-definite where a spring is compressed (not the derivative there), so the volume term's own
  // share is compared: the same frame with and without it.
  BlockDescentSolver without(system, BlockDescentSettings{}, 1);
  without.beginFrame(state);
  std::mt19937 random(3);
  std::uniform_real_distribution<double> unit(-1, 1);
  Eigen::Matrix3Xd direction = Eigen::Matrix3Xd::Zero(3, state.position.cols());
  for (const std::int32_t p : solver.freeParticles()) direction.col(p) = Eigen::Vector3d(unit(random), unit(random), unit(random));
  const auto volumeShare = [&](const auto& evaluate) {
    Eigen::Matrix3Xd with_term, without_term;
    evaluate(solver, with_term);
    evaluate(without, without_term);
    return Eigen::Matrix3Xd(with_term - without_term);
  };
  const Eigen::Matrix3Xd product = volumeShare([&](BlockDescentSolver& s, Eigen::Matrix3Xd& out) {
    s.frameHessianTimes(state.position, direction, out);
  });
  const double step = 1e-8;
  const Eigen::Matrix3Xd numeric = volumeShare([&](BlockDescentSolver& s, Eigen::Matrix3Xd& out) {
    Eigen::Matrix3Xd up, down;
    std::vector<Eigen::Matrix3d> unused;
    s.frameForces(state.position + step * direction, up, unused);
    s.frameForces(state.position - step * direction, down, unused);
    out = -(up - down) / (2 * step);
  });
  double error = 0, size = 0;
  for (const std::int32_t p : solver.freeParticles()) {
    error += (product.col(p) - numeric.col(p)).squaredNorm();
    size += numeric.col(p).squaredNorm();
  }
  solver.endFrame();
  without.endFrame();
  EXPECT_GT(size, 0.0);
  EXPECT_LT(std::sqrt(error), 1e-5 * std::sqrt(size));
}

TEST(VolumeTerm, ACylinderShortenedByThirtyPercentKeepsItsVolumeAndThickensInItsMiddle) {
  const CylinderScene scene = cylinderScene();
  // Without the term, the particle model loses volume as it shortens.
  DeformationPipeline plain(describedByName(scene.muscles), scene.muscles, scene.bones, cylinderSettings(0));
  plain.solve(shortened(0.3), StartMode::cold, kConverged, false, false);
  const double plain_volume = skinnedVolumeOf(plain);
  DeformationPipeline kept(describedByName(scene.muscles), scene.muscles, scene.bones,
                           cylinderSettings(kVolumeStiffness));
  const FrameResult& frame = kept.solve(shortened(0.3), StartMode::cold, kConverged, false, false);
  const double kept_volume = skinnedVolumeOf(kept);
  const double plain_radius = middleRadius(plain, 0.3) / kRadius, kept_radius = middleRadius(kept, 0.3) / kRadius;
  const double uniform = 1.0 / std::sqrt(0.7);  // an incompressible cylinder shortened by 30 %, widening evenly
  std::printf("shortened 30 %%: volume %.4f of rest without the term, %.4f with it (residual %.2e, %d sweeps); middle "
              "radius %.4f of rest without, %.4f with (1/sqrt(0.7) = %.4f)\n",
              plain_volume, kept_volume, frame.stats.solver.residual, frame.stats.solver.iterations, plain_radius,
              kept_radius, uniform);
  EXPECT_LT(plain_volume, 0.8);
  EXPECT_NEAR(kept_volume, 1.0, 0.02);
  // Without the term the middle narrows; with it, it widens about as an incompressible cylinder does (the attached ends
  // cannot widen, the middle bows a little sideways as it shortens: 1.168 measured against 1.195).
  EXPECT_LT(plain_radius, 1.0);
  EXPECT_NEAR(kept_radius, uniform, 0.1 * uniform);
}

TEST(VolumeTerm, OneAndTwoThreadsGiveTheSameFrames) {
  const CylinderScene scene = cylinderScene();
  DeformationPipeline one(describedByName(scene.muscles), scene.muscles, scene.bones, cylinderSettings(kVolumeStiffness, 1));
  DeformationPipeline two(describedByName(scene.muscles), scene.muscles, scene.bones, cylinderSettings(kVolumeStiffness, 2));
  const FrameStopping sweeps = FrameStopping::of(StoppingSettings::afterIterations(5));
  for (const double shortening : {0.1, 0.2, 0.3}) {
    one.solve(shortened(shortening), StartMode::warm, sweeps, false, false);
    two.solve(shortened(shortening), StartMode::warm, sweeps, false, false);
    ASSERT_EQ(one.state().position, two.state().position) << "shortening " << shortening;
  }
}

// The cylinder shortened 30 % beside a third bone that reaches 4 mm into its side: the volume term thickens the belly
// against that bone, and the contacts hold it out. Block descent must still settle: a particle in contact takes the
// volume term into its own step (where its halving sees the contact). When the colour's joint volume step moved it
// without looking at the contacts, it was pushed into the bone and back every sweep, and the residual stayed near 2
// (thigh13 at the node's defaults: 2.4 after 400 sweeps, against 0.016 without the term).
TEST(VolumeTerm, BlockDescentSettlesAMuscleThatThickensAgainstABone) {
  CylinderScene scene = cylinderScene();
  scene.bones.push_back({2, "side", makeBoxMesh({kRadius - 0.004, -0.03, 0.02}, {kRadius + 0.03, 0.03, 0.06}, 0.003)});
  for (const double stiffness : {0.0, kVolumeStiffness}) {
    PipelineSettings settings = cylinderSettings(stiffness);
    settings.simulation.collisions = true;
    settings.simulation.collision.bone_proxy = BoneProxyKind::distance_field;
    DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
    const FrameResult& frame = pipeline.solve(
        {Eigen::Isometry3d::Identity(), shortened(0.3)[1], Eigen::Isometry3d::Identity()}, StartMode::cold,
        FrameStopping::of(StoppingSettings::atResidual(0.05, 400)), true, false);
    EXPECT_LT(frame.stats.solver.residual, 0.05) << "volume stiffness " << stiffness << ", "
                                                  << frame.stats.solver.iterations << " sweeps";
    // Nothing of the muscle inside the side bone beyond its collision radius.
    EXPECT_LT(frame.stats.collision.max_penetration_muscle_bone_m, 0.001) << "volume stiffness " << stiffness;
    if (stiffness > 0) EXPECT_NEAR(skinnedVolumeOf(pipeline), 1.0, 0.03);
  }
}

// The muscles' pressures (volume_pressure_gain): after each frame a muscle's pressure takes on its remaining volume
// error, so a held shortening settles at its rest volume over the frames at a stiffness whose penalty alone leaves an
// error of several percent; a cold start forgets the pressure built before it.
TEST(VolumeTerm, PressureBringsAHeldShorteningToItsRestVolumeWhereThePenaltyAloneStopsShort) {
  const CylinderScene scene = cylinderScene();
  constexpr double kSoftStiffness = 3;  // measured 2026-11-27: the penalty alone then loses 12.4 % of the volume
  double error_after[2] = {0, 0};
  for (const double gain : {0.0, 1.0}) {
    PipelineSettings settings = cylinderSettings(kSoftStiffness);
    settings.simulation.block_descent.volume_pressure_gain = gain;
    DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
    pipeline.solve(shortened(0.3), StartMode::cold, kConverged, false, false);
    for (int frame = 0; frame < 12; ++frame) pipeline.solve(shortened(0.3), StartMode::warm, kConverged, false, false);
    error_after[gain > 0] = std::abs(skinnedVolumeOf(pipeline) - 1.0);
    std::printf("gain %.0f: volume error %.4f %% after 13 converged frames of the same pose\n", gain,
                100 * error_after[gain > 0]);
  }
  EXPECT_GT(error_after[0], 0.02);
  EXPECT_LT(error_after[1], 0.001);
}

// A cold start's pressure holds the volume against the tissue drag's pull towards the rigid pre-transform (which
// squeezes a shortened cylinder along its axis); the warm frame after it pulls towards the cold answer instead. The
// pressure carried on is the answer's own (the drag's share taken out), so a pose held across that frame keeps its
// volume instead of inflating by the share the drag no longer takes.
TEST(VolumeTerm, TheFirstWarmFrameAfterAColdStartKeepsItsVolume) {
  const CylinderScene scene = cylinderScene();
  PipelineSettings settings = cylinderSettings(kVolumeStiffness);
  settings.simulation.block_descent.volume_pressure_gain = 1.0;
  settings.simulation.block_descent.tissue_relaxation_s = 0.001;
  const FrameStopping sweeps = FrameStopping::of(StoppingSettings::afterIterations(400));
  // The same pose held: a cold frame, then a warm one. `carried_on` continues the cold answer as a stream would
  // continue any frame (continueFrom: the pressure as it stands, drag's share and all), which is what every warm frame
  // after a cold start did before the share was taken out.
  double cold = 0, warm = 0, carried_on = 0;
  {
    DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
    pipeline.solve(shortened(0.15), StartMode::cold, sweeps, false, false);
    cold = skinnedVolumeOf(pipeline);
    pipeline.solve(shortened(0.15), StartMode::warm, sweeps, false, false);
    warm = skinnedVolumeOf(pipeline);
  }
  {
    DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
    pipeline.solve(shortened(0.15), StartMode::cold, sweeps, false, false);
    pipeline.continueFrom(pipeline.boneTransforms(), Eigen::Matrix3Xd(pipeline.state().position));
    pipeline.solve(shortened(0.15), StartMode::warm, sweeps, false, false);
    carried_on = skinnedVolumeOf(pipeline);
  }
  std::printf("volume / rest: cold frame %.5f; the warm frame after it %.5f, with the drag's share kept %.5f\n", cold,
              warm, carried_on);
  // Measured 2026-11-28: 1.00000; 1.00018 against 1.00243.
  EXPECT_NEAR(cold, 1.0, 0.001);
  EXPECT_NEAR(warm, 1.0, 0.0005);
  EXPECT_GT(std::abs(carried_on - 1.0), 5 * std::abs(warm - 1.0));
}

TEST(VolumeTerm, AColdStartForgetsThePressureBuiltBeforeIt) {
  const CylinderScene scene = cylinderScene();
  PipelineSettings settings = cylinderSettings(3);
  settings.simulation.block_descent.volume_pressure_gain = 1.0;
  DeformationPipeline streamed(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
  DeformationPipeline fresh(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
  const FrameStopping sweeps = FrameStopping::of(StoppingSettings::afterIterations(30));
  for (int frame = 0; frame < 6; ++frame) streamed.solve(shortened(0.3), StartMode::warm, sweeps, false, false);
  streamed.solve(shortened(0.2), StartMode::cold, sweeps, false, false);
  fresh.solve(shortened(0.2), StartMode::cold, sweeps, false, false);
  EXPECT_EQ(streamed.state().position, fresh.state().position);
}

// A single pose may ask for unlimited sweeps within a wall-time limit. A cold start that builds the pressures in parts
// must share that limit among its parts (each part a solve of its own would start the clock again and never stop).
TEST(VolumeTerm, AColdStartBuildingPressureInPartsKeepsTheSolvesTimeLimit) {
  const CylinderScene scene = cylinderScene();
  PipelineSettings settings = cylinderSettings(kVolumeStiffness);
  settings.simulation.block_descent.volume_pressure_gain = 1.0;
  DeformationPipeline pipeline(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
  StoppingSettings unlimited = StoppingSettings::afterIterations(100000000);
  unlimited.limits.wall_time_limit_ms = 300;
  const auto start = std::chrono::steady_clock::now();
  const FrameResult& frame = pipeline.solve(shortened(0.3), StartMode::cold, FrameStopping::of(unlimited), false, false);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_TRUE(frame.stats.solver.time_limit_reached);
  EXPECT_FALSE(frame.stats.solver.stopping_rule_met);
  EXPECT_GT(frame.stats.solver.iterations, 5);  // more than one part ran
  EXPECT_LT(seconds, 3.0);
}
