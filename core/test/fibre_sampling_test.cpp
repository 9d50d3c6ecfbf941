// Sampling particles along fibres (GRAPP 2014 section 3.1).
#include "muscle_deformation/core/model/fibre_sampling.hpp"

#include <gtest/gtest.h>

using namespace muscle_deformation;

namespace {
Polyline straightFibre(double length, int points) {
  Polyline fibre = Polyline::Zero(3, points);
  for (int i = 0; i < points; ++i) fibre(2, i) = length * i / (points - 1);
  return fibre;
}
}  // namespace

TEST(FibreSampling, SameSeedGivesTheSameParticles) {
  const std::vector<Polyline> fibres = {straightFibre(0.2, 7), straightFibre(0.3, 3)};
  const FibreSamples a = sampleFibres(fibres, 10, 42);
  const FibreSamples b = sampleFibres(fibres, 10, 42);
  EXPECT_EQ(a.position, b.position);
}

TEST(FibreSampling, DifferentSeedsGiveDifferentParticles) {
  const std::vector<Polyline> fibres = {straightFibre(0.2, 7)};
  EXPECT_NE(sampleFibres(fibres, 10, 1).position, sampleFibres(fibres, 10, 2).position);
}

TEST(FibreSampling, FirstParticleSitsOnTheFibreStart) {
  Polyline fibre(3, 3);
  fibre << 0.1, 0.2, 0.4,  //
      -0.3, -0.1, 0.0,     //
      0.5, 0.5, 0.7;
  const FibreSamples samples = sampleFibres({fibre}, 8, 7);
  EXPECT_EQ(Eigen::Vector3d(samples.position.col(0)), Eigen::Vector3d(fibre.col(0)));
  EXPECT_EQ(samples.sample_of[0], 0);
}

TEST(FibreSampling, EachParticleLiesInsideItsOwnSamplingInterval) {
  const double length = 0.24;
  const int particles = 9;
  const FibreSamples samples = sampleFibres({straightFibre(length, 5)}, particles, 3);
  const double interval = length / (particles - 1);
  ASSERT_EQ(samples.position.cols(), particles);
  for (int i = 1; i < particles; ++i) {
    EXPECT_GE(samples.position(2, i), (i - 1) * interval - 1e-12) << i;
    EXPECT_LE(samples.position(2, i), i * interval + 1e-12) << i;
  }
}

TEST(FibreSampling, PositionsAreRandomisedWithinIntervalsNotEquallySpaced) {
  const FibreSamples samples = sampleFibres({straightFibre(1.0, 2)}, 11, 5);
  int off_grid = 0;
  for (int i = 1; i < 11; ++i) off_grid += std::abs(samples.position(2, i) - i * 0.1) > 1e-9;
  EXPECT_GT(off_grid, 5);
}

TEST(FibreSampling, ParticlesFollowTheFibreThroughRepeatedPoints) {
  Polyline fibre(3, 5);
  fibre << 0, 0, 0.1, 0.1, 0.1,  //
      0, 0, 0, 0, 0.1,           //
      0, 0, 0, 0, 0;             // a repeated point and a zero-length segment
  const FibreSamples samples = sampleFibres({fibre}, 6, 11);
  for (int i = 0; i < 6; ++i) {
    const Eigen::Vector3d p = samples.position.col(i);
    const bool on_first_leg = std::abs(p.y()) < 1e-12 && p.x() >= -1e-12 && p.x() <= 0.1 + 1e-12;
    const bool on_second_leg = std::abs(p.x() - 0.1) < 1e-12 && p.y() >= -1e-12 && p.y() <= 0.1 + 1e-12;
    EXPECT_TRUE(on_first_leg || on_second_leg) << p.transpose();
  }
}

TEST(FibreSampling, ZeroLengthAndSinglePointFibresAreSkippedAndReported) {
  const Polyline point = Polyline::Zero(3, 1);
  const Polyline collapsed = Polyline::Zero(3, 4);
  const FibreSamples samples = sampleFibres({point, straightFibre(0.1, 2), collapsed}, 5, 1);
  EXPECT_EQ(samples.position.cols(), 5);
  EXPECT_EQ(samples.skipped_fibres, (std::vector<int>{0, 2}));
  for (int f : samples.fibre_of) EXPECT_EQ(f, 1);
}

TEST(FibreSampling, TwoPointFibresAreSampledLikeAnyOther) {
  const FibreSamples samples = sampleFibres({straightFibre(0.05, 2)}, 4, 9);
  EXPECT_EQ(samples.position.cols(), 4);
}

TEST(FibreSampling, FewerThanTwoParticlesPerFibreIsRejected) {
  EXPECT_THROW(sampleFibres({straightFibre(0.1, 2)}, 1, 1), std::invalid_argument);
}
