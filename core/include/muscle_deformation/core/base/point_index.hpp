// Nearest-neighbour queries over a fixed set of 3-D points (nanoflann kd-tree).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

namespace muscle_deformation {

class PointIndex {
 public:
  // Keeps its own copy of the points, so the caller's matrix may change or go away.
  explicit PointIndex(const Eigen::Matrix3Xd& points);
  ~PointIndex();
  PointIndex(PointIndex&&) noexcept;
  PointIndex& operator=(PointIndex&&) noexcept;

  Eigen::Index size() const { return points_.cols(); }
  const Eigen::Matrix3Xd& points() const { return points_; }

  // Index of the closest point and the distance to it (metres). size() must be > 0.
  std::pair<std::int32_t, double> nearest(const Eigen::Vector3d& query) const;

  // Up to k closest points, nearest first: (index, distance).
  void nearest(const Eigen::Vector3d& query, int k, std::vector<std::pair<std::int32_t, double>>& out) const;

  // All points within `radius` metres (unsorted): (index, distance).
  void within(const Eigen::Vector3d& query, double radius, std::vector<std::pair<std::int32_t, double>>& out) const;

 private:
  struct Tree;
  Eigen::Matrix3Xd points_;
  std::unique_ptr<Tree> tree_;
};

// Distance queries to a triangle surface: exact point-to-surface distance through a kd-tree of triangle centroids.
class SurfaceDistance {
 public:
  SurfaceDistance(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles);

  // Exact distance to the surface if it is below `max_distance`, otherwise +infinity.
  double distanceWithin(const Eigen::Vector3d& query, double max_distance) const;

  // Exact distance to the surface (search widens until it is certain).
  double distance(const Eigen::Vector3d& query) const;

 private:
  double distanceToTriangle(const Eigen::Vector3d& query, std::int32_t triangle) const;
  // Smallest exact distance over the triangles that may lie within max_distance (+infinity when there are none).
  double nearestAmongCandidates(const Eigen::Vector3d& query, double max_distance) const;

  Eigen::Matrix3Xd vertices_;
  Eigen::Matrix3Xi triangles_;
  // The triangles in levels by size (centroid to farthest corner, each level up to twice the one before), each level
  // a kd-tree of centroids searched to its own largest extent: a decimated surface's large flat faces beside fine
  // detail no longer widen every query's search to their size, which made each query visit most of such a surface.
  struct Level {
    std::vector<std::int32_t> triangles;  // of each centroid in the index
    PointIndex centroids;
    double max_extent = 0;  // a triangle of the level lies within this radius of its centroid
  };
  std::vector<Level> levels_;
};

}  // namespace muscle_deformation
