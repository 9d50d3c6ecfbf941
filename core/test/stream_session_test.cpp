// StreamSession: the stream protocol on a small synthetic thigh. A pose is solved cold first and warm after a smooth
// motion; a pose no bone moved in is skipped once the last frame converged and refines it while it has not; a jump
// after a hold, time going back and a failed solve restart the stream cold.
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <memory>
#include <vector>

using namespace muscle_deformation;

namespace {

constexpr double kFrameS = 1.0 / 60.0;

// Two muscles of 4 x 4 fibres, 8 particles a fibre, block descent with the node's tissue drag, no surfaces: a frame
// takes milliseconds.
PipelineSettings smallPipeline() {
  PipelineSettings settings;
  settings.simulation.model.particles_per_fibre = 8;
  settings.simulation.model.nearest_neighbours = 8;
  settings.simulation.model.tendons = false;  // the fixture's muscle ends are built to be fixed beside their bones
  settings.simulation.solver_kind = SolverKind::block_descent;
  settings.simulation.block_descent.tissue_relaxation_s = 0.0005;
  settings.skin_surfaces = false;
  settings.measure_fidelity = false;
  settings.threads = 1;
  return settings;
}

StreamSessionSettings streamStopping(const StoppingSettings& sweeps) {
  StreamSessionSettings settings;
  settings.stopping = FrameStopping::of(sweeps);
  return settings;
}

// Frames that converge: the force residual below 1e-3, at most 2000 sweeps.
StreamSessionSettings converging() { return streamStopping(StoppingSettings::atResidual(1e-3, 2000)); }

// Frames of one sweep each: unfinished, so a held pose is refined (one sweep per refinement) towards a residual below
// 1e-3 (14 refinements of the first frame, measured).
StreamSessionSettings oneSweep() {
  StoppingSettings sweeps = StoppingSettings::afterIterations(1);
  sweeps.residual_tolerance = 1e-3;
  return streamStopping(sweeps);
}

std::unique_ptr<StreamSession> sessionOf(const StreamSessionSettings& settings) {
  SyntheticScene scene = makeSyntheticThigh(2, 4);
  std::vector<MuscleDescription> descriptions = describedByName(scene.muscles);
  return std::make_unique<StreamSession>(std::move(descriptions), std::move(scene.muscles), std::move(scene.bones),
                                         smallPipeline(), settings);
}

BoneTransforms thighAt(const StreamSession& session, double hip_rad, double knee_rad) {
  return boneTransformsOf(session.bones(), syntheticThighPose(hip_rad, knee_rad));
}

const FrameWants kParticlesOnly{false, false};

}  // namespace

TEST(StreamSession, TheFirstPoseIsSolvedColdAndASmoothNextPoseWarm) {
  const auto session = sessionOf(converging());
  const StreamStep first = session->offer(10.0, thighAt(*session, 0.3, 0.2), kParticlesOnly);
  EXPECT_EQ(first.outcome, StreamOutcome::solved);
  EXPECT_TRUE(first.cold);
  EXPECT_FALSE(first.restarted) << "nothing was solved before";
  EXPECT_CONTAINS(first.reason, "first pose");
  ASSERT_NE(first.frame, nullptr);
  EXPECT_FALSE(first.frame->stats.warm_started);
  EXPECT_TRUE(first.frame->stats.solver.converged);
  EXPECT_EQ(first.stamp_s, 10.0);

  const StreamStep next = session->offer(10.0 + kFrameS, thighAt(*session, 0.31, 0.21), kParticlesOnly);
  EXPECT_EQ(next.outcome, StreamOutcome::solved);
  EXPECT_FALSE(next.cold) << next.reason;
  EXPECT_FALSE(next.restarted);
  ASSERT_NE(next.frame, nullptr);
  EXPECT_TRUE(next.frame->stats.warm_started);
  EXPECT_NEAR(next.elapsed_s, kFrameS, 1e-12);
  EXPECT_TRUE(next.frame->stats.solver.converged);

  const StreamCounters& counters = session->counters();
  EXPECT_EQ(counters.offered, 2u);
  EXPECT_EQ(counters.solved, 2u);
  EXPECT_EQ(counters.resets, 0u);
  EXPECT_EQ(counters.unchanged, 0u);
  EXPECT_EQ(counters.refined, 0u);
  EXPECT_EQ(counters.failed, 0u);
}

TEST(StreamSession, ALateFrameTakesNoCatchUpSweepsWhereAFrameOnTimeDoes) {
  // One sweep a frame (a zero budget) and up to 4 catch-up sweeps: small hip steps set the stream's typical residual, a
  // 0.25 rad step (15 rad/s, within the stream's speed limit: warm) then lies far above it.
  StoppingSettings sweeps = StoppingSettings::withinBudget(0.0, 30);
  sweeps.residual_tolerance = 1e-3;
  StreamSessionSettings settings = streamStopping(sweeps);
  settings.stopping.catch_up_sweeps = 4;
  settings.stopping.catch_up_residual_ratio = 3.0;
  settings.refine_unfinished_frames = false;
  const auto jumpFrame = [&](bool late) {
    const auto session = sessionOf(settings);
    double stamp = 10.0;
    session->offer(stamp, thighAt(*session, 0.3, 0.2), kParticlesOnly);
    for (int k = 1; k <= 10; ++k) session->offer(stamp += kFrameS, thighAt(*session, 0.3 + 0.002 * k, 0.2), kParticlesOnly);
    FrameWants wants = kParticlesOnly;
    wants.late = late;
    const StreamStep jump = session->offer(stamp += kFrameS, thighAt(*session, 0.57, 0.2), wants);
    EXPECT_EQ(jump.outcome, StreamOutcome::solved);
    EXPECT_FALSE(jump.cold) << jump.reason;
    return jump.frame->stats;
  };
  const FrameStats on_time = jumpFrame(false);
  const FrameStats late = jumpFrame(true);
  EXPECT_GT(on_time.catch_up_sweeps, 0);
  EXPECT_EQ(on_time.solver.iterations, 1 + on_time.catch_up_sweeps);
  EXPECT_EQ(late.catch_up_sweeps, 0);
  EXPECT_EQ(late.solver.iterations, 1);
}

TEST(StreamSession, AnUnchangedPoseIsNotSolvedWhenTheLastFrameConverged) {
  const auto session = sessionOf(converging());
  const BoneTransforms pose = thighAt(*session, 0.3, 0.2);
  const StreamStep solved = session->offer(0.0, pose, kParticlesOnly);
  ASSERT_EQ(solved.outcome, StreamOutcome::solved);
  ASSERT_TRUE(solved.frame->stats.solver.converged);
  const Eigen::Matrix3Xd answer = session->pipeline().state().position;
  EXPECT_FALSE(session->wantsRefinement());

  for (int frame = 1; frame <= 3; ++frame) {
    const StreamStep held = session->offer(frame * kFrameS, pose, kParticlesOnly);
    EXPECT_EQ(held.outcome, StreamOutcome::unchanged);
    EXPECT_EQ(held.frame, nullptr);
    EXPECT_CONTAINS(held.reason, "no bone moved");
  }
  EXPECT_EQ(session->pipeline().state().position, answer) << "nothing was solved";
  EXPECT_EQ(session->counters().unchanged, 3u);
  EXPECT_EQ(session->counters().refined, 0u);
  EXPECT_EQ(session->counters().solved, 1u);
  EXPECT_EQ(session->refine(kParticlesOnly).outcome, StreamOutcome::unchanged) << "nothing to refine";
}

TEST(StreamSession, AHeldPoseRefinesAnUnfinishedFrameUntilItConvergesAndThenIsSkipped) {
  const auto session = sessionOf(oneSweep());
  const BoneTransforms pose = thighAt(*session, 0.3, 0.2);
  const StreamStep solved = session->offer(0.0, pose, kParticlesOnly);
  ASSERT_EQ(solved.outcome, StreamOutcome::solved);
  ASSERT_EQ(solved.frame->stats.solver.iterations, 1);
  ASSERT_FALSE(solved.frame->stats.solver.converged) << "one sweep from the pre-transform must leave work to do";
  EXPECT_TRUE(session->wantsRefinement());

  int refinements = 0;
  double first_residual = solved.frame->stats.solver.residual, last_residual = first_residual;
  bool converged = false;
  const int kMaxHeldPoses = 2000;
  int held = 1;
  for (; held <= kMaxHeldPoses && !converged; ++held) {
    const StreamStep step = session->offer(held * kFrameS, pose, kParticlesOnly);
    ASSERT_EQ(step.outcome, StreamOutcome::refined) << "held pose " << held << ": " << step.reason;
    ASSERT_NE(step.frame, nullptr);
    EXPECT_EQ(step.frame->stats.solver.iterations, 1) << "a refinement stops as the frame's stopping says";
    EXPECT_EQ(step.stamp_s, 0.0) << "a refined frame is the pose it refines";
    last_residual = step.frame->stats.solver.residual;
    converged = step.frame->stats.solver.converged;
    EXPECT_EQ(converged, last_residual < session->settings().stopping.sweeps.residual_tolerance);
    ++refinements;
  }
  ASSERT_TRUE(converged) << "not converged after " << kMaxHeldPoses << " refinements: residual " << last_residual;
  EXPECT_GT(refinements, 1) << "the case exercises several refinements";
  EXPECT_LT(last_residual, first_residual);
  EXPECT_EQ(session->counters().refined, static_cast<std::uint32_t>(refinements));
  EXPECT_EQ(session->counters().solved, 1u);
  EXPECT_FALSE(session->wantsRefinement());

  // Converged: the next held pose is skipped, and so is an explicit refinement.
  const StreamStep after = session->offer(held * kFrameS, pose, kParticlesOnly);
  EXPECT_EQ(after.outcome, StreamOutcome::unchanged);
  EXPECT_EQ(after.frame, nullptr);
  EXPECT_EQ(session->refine(kParticlesOnly).outcome, StreamOutcome::unchanged);
  EXPECT_EQ(session->counters().refined, static_cast<std::uint32_t>(refinements));
  EXPECT_EQ(session->counters().unchanged, 1u);
  std::printf("%d one-sweep refinements from residual %.3g to %.3g\n", refinements, first_residual, last_residual);

  // A new pose is solved again, warm, and the refinement of its frame starts over.
  const StreamStep moved = session->offer((held + 1) * kFrameS, thighAt(*session, 0.31, 0.2), kParticlesOnly);
  EXPECT_EQ(moved.outcome, StreamOutcome::solved);
  EXPECT_FALSE(moved.cold) << moved.reason;
}

TEST(StreamSession, AFrameWhoseResidualStopsFallingIsLeftUnfinishedAndTheNextPoseRefinesAgain) {
  // A tolerance no frame can meet: the residual falls to round-off and then no further.
  StreamSessionSettings settings = oneSweep();
  settings.stopping.sweeps.residual_tolerance = 1e-300;
  const auto session = sessionOf(settings);
  const BoneTransforms pose = thighAt(*session, 0.3, 0.2);
  ASSERT_EQ(session->offer(0.0, pose, kParticlesOnly).outcome, StreamOutcome::solved);
  std::vector<double> residuals;
  int held = 1;
  for (; held <= 5000 && session->wantsRefinement(); ++held) {
    const StreamStep step = session->offer(held * kFrameS, pose, kParticlesOnly);
    ASSERT_EQ(step.outcome, StreamOutcome::refined) << "held pose " << held << ": " << step.reason;
    ASSERT_FALSE(step.frame->stats.solver.converged);
    residuals.push_back(step.frame->stats.solver.residual);
  }
  ASSERT_FALSE(session->wantsRefinement()) << "still refining after 5000 held poses: residual " << residuals.back();
  // None of the last ten refinements lowered the lowest residual before them by 1 %, and the residual had fallen a
  // long way before them.
  ASSERT_GE(residuals.size(), 11u);
  const std::size_t first_of_last_ten = residuals.size() - 10;
  const double lowest_before =
      *std::min_element(residuals.begin(), residuals.begin() + static_cast<std::ptrdiff_t>(first_of_last_ten));
  for (std::size_t k = first_of_last_ten; k < residuals.size(); ++k)
    EXPECT_GE(residuals[k], 0.99 * lowest_before) << "refinement " << k;
  EXPECT_LT(residuals.back(), 1e-6 * residuals.front());
  std::printf("refinement stopped after %zu refinements at residual %.3g (first %.3g)\n", residuals.size(),
              residuals.back(), residuals.front());
  // Held poses are now skipped; a new pose is solved and its frame refined again.
  EXPECT_EQ(session->offer(held * kFrameS, pose, kParticlesOnly).outcome, StreamOutcome::unchanged);
  EXPECT_EQ(session->offer((held + 1) * kFrameS, thighAt(*session, 0.31, 0.2), kParticlesOnly).outcome,
            StreamOutcome::solved);
  EXPECT_TRUE(session->wantsRefinement());
}

TEST(StreamSession, RefinementIsOffWhenTheSettingsSaySo) {
  StreamSessionSettings settings = oneSweep();
  settings.refine_unfinished_frames = false;
  const auto session = sessionOf(settings);
  const BoneTransforms pose = thighAt(*session, 0.3, 0.2);
  ASSERT_FALSE(session->offer(0.0, pose, kParticlesOnly).frame->stats.solver.converged);
  EXPECT_FALSE(session->wantsRefinement());
  EXPECT_EQ(session->offer(kFrameS, pose, kParticlesOnly).outcome, StreamOutcome::unchanged);
  EXPECT_EQ(session->counters().refined, 0u);
}

TEST(StreamSession, AJumpAfterAHoldRestartsCold) {
  const auto session = sessionOf(converging());
  const BoneTransforms rest = thighAt(*session, 0.0, 0.0);
  ASSERT_EQ(session->offer(0.0, rest, kParticlesOnly).outcome, StreamOutcome::solved);
  // Held for half a second: every pose skipped as unchanged.
  for (int frame = 1; frame <= 30; ++frame)
    ASSERT_EQ(session->offer(frame * kFrameS, rest, kParticlesOnly).outcome, StreamOutcome::unchanged);
  // Then the hip turns 1.5 rad in one frame (90 rad/s): a jump, not a motion over the whole hold (2.9 rad/s).
  const StreamStep jump = session->offer(31 * kFrameS, thighAt(*session, 1.5, 0.0), kParticlesOnly);
  EXPECT_EQ(jump.outcome, StreamOutcome::solved);
  EXPECT_TRUE(jump.cold);
  EXPECT_TRUE(jump.restarted);
  EXPECT_CONTAINS(jump.reason, "faster than");
  ASSERT_NE(jump.frame, nullptr);
  EXPECT_FALSE(jump.frame->stats.warm_started);
  EXPECT_EQ(session->counters().resets, 1u);
  EXPECT_EQ(session->counters().solved, 2u);
  EXPECT_EQ(session->counters().unchanged, 30u);

  // The stream continues warm from the restarted frame.
  const StreamStep next = session->offer(32 * kFrameS, thighAt(*session, 1.51, 0.0), kParticlesOnly);
  EXPECT_EQ(next.outcome, StreamOutcome::solved);
  EXPECT_FALSE(next.cold) << next.reason;
  EXPECT_EQ(session->counters().resets, 1u);
}

TEST(StreamSession, TimeGoingBackRestartsCold) {
  const auto session = sessionOf(converging());
  ASSERT_EQ(session->offer(5.0, thighAt(*session, 0.3, 0.2), kParticlesOnly).outcome, StreamOutcome::solved);
  const StreamStep back = session->offer(1.0, thighAt(*session, 0.31, 0.2), kParticlesOnly);  // a looping bag
  EXPECT_EQ(back.outcome, StreamOutcome::solved);
  EXPECT_TRUE(back.cold);
  EXPECT_TRUE(back.restarted);
  EXPECT_CONTAINS(back.reason, "time went back");
  EXPECT_FALSE(back.frame->stats.warm_started);
  EXPECT_EQ(session->counters().resets, 1u);
}

TEST(StreamSession, RestartMakesTheNextPoseCold) {
  const auto session = sessionOf(converging());
  ASSERT_EQ(session->offer(0.0, thighAt(*session, 0.3, 0.2), kParticlesOnly).outcome, StreamOutcome::solved);
  session->restart();
  const StreamStep next = session->offer(kFrameS, thighAt(*session, 0.31, 0.2), kParticlesOnly);
  EXPECT_EQ(next.outcome, StreamOutcome::solved);
  EXPECT_TRUE(next.cold);
  EXPECT_FALSE(next.frame->stats.warm_started);
}

TEST(StreamSession, TransformsThatDoNotFitTheBonesAreRefusedByOfferItself) {
  const auto session = sessionOf(converging());
  const BoneTransforms too_few(1, Eigen::Isometry3d::Identity());
  const std::string message = muscle_deformation::testing::errorMessageOf<std::invalid_argument>(
      [&] { session->offer(0.0, too_few, kParticlesOnly); });
  EXPECT_CONTAINS(message, "1 bone transforms for 3 bones");
  EXPECT_EQ(session->counters().offered, 0u);
  EXPECT_EQ(session->counters().failed, 0u);
}

TEST(StreamSession, ASolveThatThrowsIsAFailedStepAndTheNextPoseStartsCold) {
  const auto session = sessionOf(converging());
  // A non-finite bone transform of the right size passes offer's own check; the simulation refuses it inside the solve.
  BoneTransforms broken = thighAt(*session, 0.3, 0.2);
  broken[1].translation().x() = std::numeric_limits<double>::quiet_NaN();
  const StreamStep failed = session->offer(0.0, broken, kParticlesOnly);
  EXPECT_EQ(failed.outcome, StreamOutcome::failed);
  EXPECT_EQ(failed.frame, nullptr);
  EXPECT_CONTAINS(failed.reason, "non-finite");
  EXPECT_EQ(session->counters().failed, 1u);
  EXPECT_EQ(session->counters().solved, 0u);

  const StreamStep next = session->offer(kFrameS, thighAt(*session, 0.3, 0.2), kParticlesOnly);
  EXPECT_EQ(next.outcome, StreamOutcome::solved);
  EXPECT_TRUE(next.cold);
  ASSERT_NE(next.frame, nullptr);
  EXPECT_TRUE(next.frame->stats.finite);
}

TEST(StreamSession, ASolveThatThrowsAfterSolvedFramesIsAFailedStepAndTheStreamRecoversCold) {
  const auto session = sessionOf(converging());
  ASSERT_EQ(session->offer(0.0, thighAt(*session, 0.3, 0.2), kParticlesOnly).outcome, StreamOutcome::solved);
  // The same kind of non-finite transform after a solved frame: it is not taken for an unchanged pose but solved, and
  // the simulation refuses it inside the solve.
  BoneTransforms broken = thighAt(*session, 0.31, 0.2);
  broken[1].translation().x() = std::numeric_limits<double>::quiet_NaN();
  const StreamStep failed = session->offer(kFrameS, broken, kParticlesOnly);
  EXPECT_EQ(failed.outcome, StreamOutcome::failed);
  EXPECT_EQ(failed.frame, nullptr);
  EXPECT_CONTAINS(failed.reason, "non-finite");
  EXPECT_EQ(session->counters().failed, 1u);

  const StreamStep next = session->offer(2 * kFrameS, thighAt(*session, 0.32, 0.2), kParticlesOnly);
  EXPECT_EQ(next.outcome, StreamOutcome::solved);
  EXPECT_TRUE(next.cold) << "never warm from before a failed frame";
  EXPECT_TRUE(next.restarted) << "the recovery's cold start is a restart of the running stream";
  EXPECT_EQ(session->counters().resets, 1u);
  ASSERT_NE(next.frame, nullptr);
  EXPECT_FALSE(next.frame->stats.warm_started);
}

namespace {

// The small thigh at 40 particles per fibre, its first muscle with 20 of its own, streamed within `budget_ms`.
std::unique_ptr<StreamSession> autoResolutionSession(double budget_ms) {
  SyntheticScene scene = makeSyntheticThigh(2, 4);
  scene.muscles.front().particles_per_fibre = 20;
  std::vector<MuscleDescription> descriptions = describedByName(scene.muscles);
  PipelineSettings pipeline = smallPipeline();
  pipeline.simulation.model.particles_per_fibre = 40;
  StreamSessionSettings settings = streamStopping(StoppingSettings::withinBudget(budget_ms, 30));
  settings.auto_resolution = true;
  return std::make_unique<StreamSession>(std::move(descriptions), std::move(scene.muscles), std::move(scene.bones),
                                         pipeline, settings);
}

}  // namespace

TEST(StreamSession, AutoResolutionKeepsTheConfiguredModelWhenItsOneSweepSolveFitsTheBudget) {
  const auto session = autoResolutionSession(1e6);
  ASSERT_TRUE(session->resolutionFit().has_value());
  const ResolutionFit& fit = *session->resolutionFit();
  ASSERT_EQ(fit.models.size(), 1u);
  EXPECT_TRUE(fit.fits());
  EXPECT_FALSE(fit.changed());
  EXPECT_EQ(fit.models.front().particles_per_fibre, 40);
  EXPECT_GT(fit.models.front().solve_ms, 0.0);
  EXPECT_EQ(fit.models.front().particles, session->pipeline().system().particleCount());
  EXPECT_EQ(session->pipeline().muscles().front().particles_per_fibre, 20) << "a muscle's own resolution stays";
  EXPECT_CONTAINS(fit.describe(), "within the 1000000.0 ms budget: the stream keeps it");
  // The timing solves leave nothing behind: the first pose is the stream's first, solved cold.
  const StreamStep first = session->offer(10.0, thighAt(*session, 0.3, 0.2), kParticlesOnly);
  EXPECT_EQ(first.outcome, StreamOutcome::solved);
  EXPECT_TRUE(first.cold);
  EXPECT_CONTAINS(first.reason, "first pose");
}

TEST(StreamSession, AutoResolutionBuildsCoarserModelsDownToTheCoarsestWhenNoneFits) {
  // A zero budget: no solve fits, so the fit goes straight to the coarsest model and says the budget is still missed.
  const auto session = autoResolutionSession(0.0);
  ASSERT_TRUE(session->resolutionFit().has_value());
  const ResolutionFit& fit = *session->resolutionFit();
  ASSERT_EQ(fit.models.size(), 2u);
  EXPECT_FALSE(fit.fits());
  EXPECT_TRUE(fit.changed());
  EXPECT_EQ(fit.models[0].particles_per_fibre, 40);
  EXPECT_EQ(fit.models[1].particles_per_fibre, ResolutionFit::kCoarsestParticlesPerFibre);
  EXPECT_LT(fit.models[1].particles, fit.models[0].particles / 2) << "a quarter of the particles per fibre";
  EXPECT_EQ(fit.models[1].particles, session->pipeline().system().particleCount());
  EXPECT_EQ(session->pipeline().muscles().front().particles_per_fibre, 5) << "20 scaled as 40 -> 10";
  const std::string said = fit.describe();
  EXPECT_CONTAINS(said, "at 40 particles per fibre (" + std::to_string(fit.models[0].particles) + " particles) ");
  EXPECT_CONTAINS(said, "over the 0.0 ms budget; at 10 particles per fibre (");
  EXPECT_CONTAINS(said, "The stream uses 10 particles per fibre, still over the budget");
  EXPECT_CONTAINS(said, "single poses (~deform_pose) keep 40");
  const StreamStep first = session->offer(10.0, thighAt(*session, 0.3, 0.2), kParticlesOnly);
  EXPECT_EQ(first.outcome, StreamOutcome::solved);
  EXPECT_TRUE(first.cold);
  EXPECT_TRUE(first.frame->stats.finite);
}

TEST(StreamSession, AutoResolutionWithoutATimeBudgetIsRefusedNamingWhy) {
  StreamSessionSettings settings = oneSweep();
  settings.auto_resolution = true;
  EXPECT_CONTAINS(validate(settings), "auto_resolution");
  EXPECT_CONTAINS(validate(settings), "time_budget");
  EXPECT_THROW(sessionOf(settings), std::invalid_argument);
}
