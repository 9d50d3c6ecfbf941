// The once-only notice that one sweep does not fit between two poses.
#include "muscle_deformation/core/pipeline/sweep_budget_check.hpp"

#include <gtest/gtest.h>

using namespace muscle_deformation;

namespace {
// A frame whose whole solve took solve_ms, of which the solver's sweeps solver_ms.
FrameStats frameOf(double solve_ms, double solver_ms, int sweeps) {
  FrameStats stats;
  stats.solve_ms = solve_ms;
  stats.solver.total_ms = solver_ms;
  stats.solver.iterations = sweeps;
  return stats;
}
}  // namespace

TEST(SweepBudgetCheck, ASlowMachineIsToldOnceWithTheMeasuredSweepAndThePosePeriod) {
  SweepBudgetCheck check(1000.0 / 60);  // 16.7 ms between poses
  EXPECT_EQ(check.add(frameOf(410, 400, 10), false), "");  // a cold start's ten sweeps do not count
  // Two sweeps of 20 ms in a 44 ms frame: 24 ms with one.
  for (int k = 1; k < SweepBudgetCheck::kFramesJudged; ++k) EXPECT_EQ(check.add(frameOf(44, 40, 2), true), "");
  EXPECT_FALSE(check.judged());
  const std::string notice = check.add(frameOf(26, 22, 1), true);
  EXPECT_TRUE(check.judged());
  EXPECT_DOUBLE_EQ(check.medianSweepMilliseconds(), 24.0);
  EXPECT_NE(notice.find("a frame's solve with one sweep takes 24.0 ms"), std::string::npos) << notice;
  EXPECT_NE(notice.find("16.7 ms between poses"), std::string::npos) << notice;
  EXPECT_NE(notice.find("particles_per_fibre"), std::string::npos) << notice;
  EXPECT_EQ(check.add(frameOf(44, 40, 1), true), "");  // once
}

TEST(SweepBudgetCheck, AMachineThatFitsASweepHearsNothingAndNoRateMeansNoJudgement) {
  SweepBudgetCheck fits(1000.0 / 60);
  for (int k = 0; k < 2 * SweepBudgetCheck::kFramesJudged; ++k) EXPECT_EQ(fits.add(frameOf(14, 12, 1), true), "");
  EXPECT_TRUE(fits.judged());
  SweepBudgetCheck no_rate(0);
  for (int k = 0; k < 2 * SweepBudgetCheck::kFramesJudged; ++k) EXPECT_EQ(no_rate.add(frameOf(55, 50, 1), true), "");
  EXPECT_FALSE(no_rate.judged());
}

TEST(SweepBudgetCheck, AModelAutoResolutionChoseIsNotOfferedItAgain) {
  SweepBudgetCheck check(1000.0 / 60, /*resolution_fitted=*/true);
  std::string notice;
  for (int k = 0; k < SweepBudgetCheck::kFramesJudged; ++k) notice = check.add(frameOf(33, 30, 1), true);
  EXPECT_NE(notice.find("one sweep takes 33.0 ms"), std::string::npos) << notice;
  EXPECT_NE(notice.find("auto_resolution chose this model already"), std::string::npos) << notice;
  EXPECT_EQ(notice.find("particles_per_fibre 10"), std::string::npos) << notice;
  SweepBudgetCheck unfitted(1000.0 / 60);
  for (int k = 0; k < SweepBudgetCheck::kFramesJudged; ++k) notice = unfitted.add(frameOf(33, 30, 1), true);
  EXPECT_NE(notice.find("auto_resolution: true"), std::string::npos) << notice;
}
