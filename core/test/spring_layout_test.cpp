// Spring layouts on small grids: expected counts, no duplicates, no self springs.
#include "muscle_deformation/core/model/spring_layout.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <random>
#include <set>

using namespace muscle_deformation;

namespace {

// rows x columns fibres, `samples` particles each, on an exact lattice with spacing 1 cm (fibres along z).
struct Grid {
  Eigen::Matrix3Xd points;
  std::vector<std::int32_t> fibre_of, sample_of;
  int rows, columns, samples;
  int index(int r, int c, int s) const { return (r * columns + c) * samples + s; }
};

Grid makeGrid(int rows, int columns, int samples) {
  Grid grid{Eigen::Matrix3Xd(3, rows * columns * samples), {}, {}, rows, columns, samples};
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < columns; ++c)
      for (int s = 0; s < samples; ++s) {
        grid.points.col(grid.index(r, c, s)) = Eigen::Vector3d(r, c, s) * 0.01;
        grid.fibre_of.push_back(r * columns + c);
        grid.sample_of.push_back(s);
      }
  return grid;
}

std::vector<int> springsPerParticle(const ParticlePairs& pairs, Eigen::Index count) {
  std::vector<int> degree(count, 0);
  for (const auto& [a, b] : pairs) {
    ++degree[a];
    ++degree[b];
  }
  return degree;
}

void expectNoDuplicateOrSelfSprings(const ParticlePairs& pairs) {
  std::set<std::pair<std::int32_t, std::int32_t>> seen;
  for (const auto& [a, b] : pairs) {
    EXPECT_NE(a, b);
    EXPECT_LT(a, b);
    EXPECT_TRUE(seen.insert({std::min(a, b), std::max(a, b)}).second) << a << "-" << b;
  }
}

}  // namespace

TEST(CubicLattice, SixNeighboursGiveSixSpringsOnInteriorParticles) {
  const Grid grid = makeGrid(4, 4, 5);
  const ParticlePairs pairs = cubicLatticePairs(grid.points, grid.fibre_of, grid.sample_of, false);
  const auto degree = springsPerParticle(pairs, grid.points.cols());
  for (int r = 1; r < 3; ++r)
    for (int c = 1; c < 3; ++c)
      for (int s = 1; s < 4; ++s) EXPECT_EQ(degree[grid.index(r, c, s)], 6);
  EXPECT_EQ(degree[grid.index(0, 0, 0)], 3);  // a corner
  // Edges of a 4 x 4 x 5 lattice: 3*4*5 + 4*3*5 + 4*4*4.
  EXPECT_EQ(pairs.size(), 3u * 4 * 5 + 4u * 3 * 5 + 4u * 4 * 4);
  expectNoDuplicateOrSelfSprings(pairs);
}

TEST(CubicLattice, TwentySixNeighboursGiveTwentySixSpringsOnInteriorParticles) {
  const Grid grid = makeGrid(4, 4, 5);
  const ParticlePairs pairs = cubicLatticePairs(grid.points, grid.fibre_of, grid.sample_of, true);
  const auto degree = springsPerParticle(pairs, grid.points.cols());
  for (int r = 1; r < 3; ++r)
    for (int c = 1; c < 3; ++c)
      for (int s = 1; s < 4; ++s) EXPECT_EQ(degree[grid.index(r, c, s)], 26);
  EXPECT_EQ(degree[grid.index(0, 0, 0)], 7);
  expectNoDuplicateOrSelfSprings(pairs);
}

TEST(CubicLattice, SpringsOnlyJoinGridNeighbours) {
  const Grid grid = makeGrid(3, 3, 4);
  for (const bool diagonals : {false, true})
    for (const auto& [a, b] : cubicLatticePairs(grid.points, grid.fibre_of, grid.sample_of, diagonals)) {
      const double length = (grid.points.col(a) - grid.points.col(b)).norm();
      EXPECT_LE(length, (diagonals ? std::sqrt(3.0) : 1.0) * 0.01 + 1e-12);
    }
}

TEST(CubicLattice, FibresOffTheGridAreAssignedToTheNearestGridCells) {
  // Rotate and jitter the fibre grid: the rank-based assignment must still recover a 6-neighbour lattice.
  Grid grid = makeGrid(4, 4, 3);
  const Eigen::Matrix3d rotation = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  std::mt19937 random(3);
  std::uniform_real_distribution<double> jitter(-0.001, 0.001);
  for (int f = 0; f < 16; ++f) {
    const Eigen::Vector3d shift(jitter(random), jitter(random), 0);
    for (int s = 0; s < 3; ++s) grid.points.col(f * 3 + s) += shift;
  }
  grid.points = rotation * grid.points;
  const ParticlePairs pairs = cubicLatticePairs(grid.points, grid.fibre_of, grid.sample_of, false);
  EXPECT_EQ(pairs.size(), 3u * 4 * 3 + 4u * 3 * 3 + 4u * 4 * 2);
  for (const auto& [a, b] : pairs) EXPECT_LT((grid.points.col(a) - grid.points.col(b)).norm(), 0.0125);
}

TEST(NearestNeighbours, EveryParticleHasAtLeastNSpringsAndNoDuplicates) {
  const Grid grid = makeGrid(4, 4, 6);
  const ParticlePairs pairs = nearestNeighbourPairs(grid.points, 18);
  const auto degree = springsPerParticle(pairs, grid.points.cols());
  for (int d : degree) EXPECT_GE(d, 18);
  expectNoDuplicateOrSelfSprings(pairs);
}

TEST(NearestNeighbours, OneNeighbourJoinsEachParticleToItsClosest) {
  Eigen::Matrix3Xd points(3, 4);
  points << 0, 0.1, 1.0, 1.05,  //
      0, 0, 0, 0,               //
      0, 0, 0, 0;
  const ParticlePairs pairs = nearestNeighbourPairs(points, 1);
  EXPECT_EQ(pairs, (ParticlePairs{{0, 1}, {2, 3}}));
}

TEST(Delaunay, EdgesAreUniqueAndConnectEveryParticle) {
  Grid grid = makeGrid(3, 3, 4);
  std::mt19937 random(1);
  std::uniform_real_distribution<double> jitter(-0.001, 0.001);
  for (Eigen::Index i = 0; i < grid.points.cols(); ++i)
    grid.points.col(i) += Eigen::Vector3d(jitter(random), jitter(random), jitter(random));
  const ParticlePairs pairs = delaunayPairs(grid.points);
  const auto degree = springsPerParticle(pairs, grid.points.cols());
  for (int d : degree) EXPECT_GE(d, 3);  // every vertex of a tetrahedralisation has at least 3 edges
  expectNoDuplicateOrSelfSprings(pairs);
}

TEST(Delaunay, ATetrahedronGivesItsSixEdges) {
  Eigen::Matrix3Xd points(3, 5);
  points << 0, 1, 0, 0, 0.2,  //
      0, 0, 1, 0, 0.2,        //
      0, 0, 0, 1, 0.2;        // the fifth point inside: 4 tetrahedra, 4 + 6 = 10 edges
  EXPECT_EQ(delaunayPairs(points).size(), 10u);
}

TEST(Delaunay, TooFewOrCoplanarParticlesAreRejectedWithAMessage) {
  EXPECT_THROW(delaunayPairs(Eigen::Matrix3Xd::Random(3, 3)), std::runtime_error);
  Eigen::Matrix3Xd flat = Eigen::Matrix3Xd::Random(3, 20);
  flat.row(2).setZero();
  EXPECT_THROW(delaunayPairs(flat), std::runtime_error);
}

TEST(SpringLayoutNames, RoundTripAndRejectUnknown) {
  for (SpringLayout layout : {SpringLayout::nearest_neighbours, SpringLayout::cubic6, SpringLayout::cubic26,
                              SpringLayout::delaunay})
    EXPECT_EQ(springLayoutFromString(toString(layout)), layout);
  EXPECT_THROW(springLayoutFromString("hexagonal"), std::invalid_argument);
}
