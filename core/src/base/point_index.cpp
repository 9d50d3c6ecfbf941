#include "muscle_deformation/core/base/point_index.hpp"

#include "muscle_deformation/core/base/geometry.hpp"

#include <nanoflann.hpp>

#include <cmath>
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
Eigen::Matrix3Xd triangleCentroids(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles) {
  Eigen::Matrix3Xd centroids(3, triangles.cols());
  for (Eigen::Index t = 0; t < triangles.cols(); ++t)
    centroids.col(t) =
        (vertices.col(triangles(0, t)) + vertices.col(triangles(1, t)) + vertices.col(triangles(2, t))) / 3.0;
  return centroids;
}
}  // namespace

SurfaceDistance::SurfaceDistance(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles)
    : vertices_(vertices), triangles_(triangles), centroids_(triangleCentroids(vertices, triangles)) {
  for (Eigen::Index t = 0; t < triangles_.cols(); ++t)
    for (int corner = 0; corner < 3; ++corner)
      max_centroid_to_vertex_ = std::max(
          max_centroid_to_vertex_, (vertices_.col(triangles_(corner, t)) - centroids_.points().col(t)).norm());
}

double SurfaceDistance::distanceWithin(const Eigen::Vector3d& query, double max_distance) const {
  const double best = nearestAmongCandidates(query, max_distance);
  return best <= max_distance ? best : std::numeric_limits<double>::infinity();
}

double SurfaceDistance::nearestAmongCandidates(const Eigen::Vector3d& query, double max_distance) const {
  if (triangles_.cols() == 0) return std::numeric_limits<double>::infinity();
  // Any triangle with a point within max_distance has its centroid within max_distance + its own extent.
  std::vector<std::pair<std::int32_t, double>> candidates;
  centroids_.within(query, max_distance + max_centroid_to_vertex_, candidates);
  double best = std::numeric_limits<double>::infinity();
  for (const auto& candidate : candidates) {
    const int t = candidate.first;
    const Eigen::Vector3d closest = closestPointOnTriangle(query, vertices_.col(triangles_(0, t)),
                                                           vertices_.col(triangles_(1, t)),
                                                           vertices_.col(triangles_(2, t)));
    best = std::min(best, (closest - query).norm());
  }
  return best;
}

double SurfaceDistance::distance(const Eigen::Vector3d& query) const {
  if (triangles_.cols() == 0) return std::numeric_limits<double>::infinity();
  // The nearest centroid bounds the true distance from above, so the nearest triangle is among the candidates within
  // that bound. Not compared with the bound again: rounding can put the exact answer a hair above it.
  const double upper = centroids_.nearest(query).second;
  return nearestAmongCandidates(query, upper);
}

}  // namespace muscle_deformation
