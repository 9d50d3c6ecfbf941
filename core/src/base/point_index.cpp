#include "muscle_deformation/core/base/point_index.hpp"

#include "muscle_deformation/core/base/geometry.hpp"

#include <nanoflann.hpp>

#include <cmath>
#include <map>
#include <limits>
#include <stdexcept>

namespace muscle_deformation {

namespace {
// nanoflann reads points through this adaptor; the matrix is column-major 3 x N.
struct ColumnPoints {
  const Eigen::Matrix3Xd* points;
  std::size_t kdtree_get_point_count() const { return static_cast<std::size_t>(points->cols()); }
  double kdtree_get_pt(std::size_t index, std::size_t dim) const { return (*points)(dim, index); }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};
using KdTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, ColumnPoints>, ColumnPoints,
                                                   3, std::uint32_t>;
}  // namespace

struct PointIndex::Tree {
  ColumnPoints adaptor;
  KdTree tree;
  explicit Tree(const Eigen::Matrix3Xd* points)
      : adaptor{points}, tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(16)) {
    tree.buildIndex();
  }
};

PointIndex::PointIndex(const Eigen::Matrix3Xd& points) : points_(points) {
  tree_ = std::make_unique<Tree>(&points_);
}
PointIndex::~PointIndex() = default;
PointIndex::PointIndex(PointIndex&& other) noexcept : points_(std::move(other.points_)) {
  // The tree holds a pointer to the matrix it indexes: rebuild against our own copy.
  tree_ = std::make_unique<Tree>(&points_);
  other.tree_.reset();
}
PointIndex& PointIndex::operator=(PointIndex&& other) noexcept {
  points_ = std::move(other.points_);
  tree_ = std::make_unique<Tree>(&points_);
  other.tree_.reset();
  return *this;
}

std::pair<std::int32_t, double> PointIndex::nearest(const Eigen::Vector3d& query) const {
  if (points_.cols() == 0) throw std::logic_error("PointIndex::nearest on an empty point set");
  std::uint32_t index = 0;
  double squared = 0;
  tree_->tree.knnSearch(query.data(), 1, &index, &squared);
  return {static_cast<std::int32_t>(index), std::sqrt(squared)};
}

void PointIndex::nearest(const Eigen::Vector3d& query, int k,
                         std::vector<std::pair<std::int32_t, double>>& out) const {
  out.clear();
  if (k <= 0 || points_.cols() == 0) return;
  const auto count = static_cast<std::size_t>(std::min<Eigen::Index>(k, points_.cols()));
  std::vector<std::uint32_t> indices(count);
  std::vector<double> squared(count);
  const std::size_t found = tree_->tree.knnSearch(query.data(), count, indices.data(), squared.data());
  out.reserve(found);
  for (std::size_t i = 0; i < found; ++i) out.emplace_back(static_cast<std::int32_t>(indices[i]), std::sqrt(squared[i]));
}

void PointIndex::within(const Eigen::Vector3d& query, double radius,
                        std::vector<std::pair<std::int32_t, double>>& out) const {
  out.clear();
  if (points_.cols() == 0 || !(radius >= 0)) return;
  std::vector<std::pair<std::uint32_t, double>> hits;
  nanoflann::SearchParams params;
  params.sorted = false;
  tree_->tree.radiusSearch(query.data(), radius * radius, hits, params);
  out.reserve(hits.size());
  for (const auto& [index, squared] : hits) out.emplace_back(static_cast<std::int32_t>(index), std::sqrt(squared));
}

namespace {

Eigen::Vector3d centroidOf(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles, Eigen::Index t) {
  return (vertices.col(triangles(0, t)) + vertices.col(triangles(1, t)) + vertices.col(triangles(2, t))) / 3.0;
}

double extentOf(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles, Eigen::Index t) {
  const Eigen::Vector3d centroid = centroidOf(vertices, triangles, t);
  double extent = 0;
  for (int corner = 0; corner < 3; ++corner)
    extent = std::max(extent, (vertices.col(triangles(corner, t)) - centroid).norm());
  return extent;
}

}  // namespace

SurfaceDistance::SurfaceDistance(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles)
    : vertices_(vertices), triangles_(triangles) {
  const Eigen::Index count = triangles_.cols();
  std::vector<double> extents(static_cast<std::size_t>(count));
  double smallest = std::numeric_limits<double>::infinity();
  for (Eigen::Index t = 0; t < count; ++t) {
    extents[static_cast<std::size_t>(t)] = extentOf(vertices_, triangles_, t);
    if (extents[static_cast<std::size_t>(t)] > 0) smallest = std::min(smallest, extents[static_cast<std::size_t>(t)]);
  }
  // Level k holds the extents up to smallest x 2^k (degenerate triangles in the first).
  std::map<int, std::vector<std::int32_t>> by_level;
  for (Eigen::Index t = 0; t < count; ++t) {
    const double extent = extents[static_cast<std::size_t>(t)];
    const int level = extent > smallest ? static_cast<int>(std::ceil(std::log2(extent / smallest))) : 0;
    by_level[level].push_back(static_cast<std::int32_t>(t));
  }
  for (auto& [level, members] : by_level) {
    Eigen::Matrix3Xd centroids(3, static_cast<Eigen::Index>(members.size()));
    double max_extent = 0;
    for (std::size_t k = 0; k < members.size(); ++k) {
      centroids.col(static_cast<Eigen::Index>(k)) = centroidOf(vertices_, triangles_, members[k]);
      max_extent = std::max(max_extent, extents[static_cast<std::size_t>(members[k])]);
    }
    levels_.push_back(Level{std::move(members), PointIndex(centroids), max_extent});
  }
}

double SurfaceDistance::distanceWithin(const Eigen::Vector3d& query, double max_distance) const {
  const double best = nearestAmongCandidates(query, max_distance);
  return best <= max_distance ? best : std::numeric_limits<double>::infinity();
}

double SurfaceDistance::distanceToTriangle(const Eigen::Vector3d& query, std::int32_t t) const {
  return (closestPointOnTriangle(query, vertices_.col(triangles_(0, t)), vertices_.col(triangles_(1, t)),
                                 vertices_.col(triangles_(2, t))) -
          query)
      .norm();
}

double SurfaceDistance::nearestAmongCandidates(const Eigen::Vector3d& query, double max_distance) const {
  double best = std::numeric_limits<double>::infinity();
  std::vector<std::pair<std::int32_t, double>> candidates;
  for (const Level& level : levels_) {
    // Any triangle of the level with a point within the bound has its centroid within the bound + the level's extent.
    level.centroids.within(query, std::min(max_distance, best) + level.max_extent, candidates);
    for (const auto& candidate : candidates)
      best = std::min(best, distanceToTriangle(query, level.triangles[static_cast<std::size_t>(candidate.first)]));
  }
  return best;
}

double SurfaceDistance::distance(const Eigen::Vector3d& query) const {
  if (triangles_.cols() == 0) return std::numeric_limits<double>::infinity();
  // The nearest centroid of any level bounds the true distance from above (its triangle reaches at least that close),
  // so the nearest triangle is among the candidates within that bound. Not compared with the bound again: rounding can
  // put the exact answer a hair above it.
  double upper = std::numeric_limits<double>::infinity();
  for (const Level& level : levels_) upper = std::min(upper, level.centroids.nearest(query).second);
  return nearestAmongCandidates(query, upper);
}

}  // namespace muscle_deformation
