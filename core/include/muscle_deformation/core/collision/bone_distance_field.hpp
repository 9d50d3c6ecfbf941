// A bone as its signed distance field: the collision proxy that is the bone itself (rather than spheres standing in for
// it), and the inside-bone test of the surface metrics.
//
// Built once per bone at load time from its closed rest surface, in the bone's rest frame, on a sparse voxel grid
// (OpenVDB's mesh-to-level-set conversion): exact distances in a narrow band outside the surface and everywhere inside.
// A lookup interpolates the eight voxels around a point trilinearly (value and gradient of that interpolant), so it
// costs a few tens of nanoseconds through a Probe, which caches the grid path between nearby queries.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

class BoneFieldError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct BoneFieldSettings {
  double voxel_m = 0.001;          // grid spacing: the field is exact at voxel centres, interpolated between
  double exterior_band_m = 0.015;  // distances are known this far outside the surface; beyond, a point is "far"
};

std::string validate(const BoneFieldSettings& settings);

class BoneDistanceField {
 public:
  // `surface` must be closed (its inside is undefined otherwise); throws BoneFieldError naming `name` and the problem.
  BoneDistanceField(const TriangleMesh& surface, const BoneFieldSettings& settings = {}, const std::string& name = "bone");
  ~BoneDistanceField();
  BoneDistanceField(const BoneDistanceField&) = delete;
  BoneDistanceField& operator=(const BoneDistanceField&) = delete;

  // Reads the field; not shared between threads (each keeps its own cache), cheap to make.
  class Probe {
   public:
    explicit Probe(const BoneDistanceField& field);
    ~Probe();
    Probe(Probe&&) noexcept;
    // Signed distance (metres, negative inside) at a point of the bone's rest frame. Beyond the exterior band the
    // result is the band width: the point is at least that far, and the gradient there is zero.
    double distance(const Eigen::Vector3d& point) const;
    // The same with the gradient of the interpolated field (unit length up to interpolation, zero beyond the band).
    double distance(const Eigen::Vector3d& point, Eigen::Vector3d& gradient) const;
    // Whether the point lies closer than `limit`, with distance and gradient as above when it does. When one voxel read
    // proves it does not (a distance changes no faster than the point moves, so it is within half a voxel diagonal of
    // the nearest voxel's value), `distance` is that proof's lower bound and the gradient is left alone. Most points a
    // muscle has are far from every bone: one read each.
    bool closerThan(const Eigen::Vector3d& point, double limit, double& distance, Eigen::Vector3d& gradient) const;

   private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
  };
  Probe probe() const { return Probe(*this); }

  const std::string& name() const { return name_; }
  const BoneFieldSettings& settings() const { return settings_; }
  // The grid spacing used: settings().voxel_m, or coarser for a bone so large that its inside would take more than
  // kMaxInsideVoxels (a human pelvis takes about 5e5 at 1 mm). The exterior band is at least two voxels.
  double voxel() const { return voxel_m_; }
  double exteriorBand() const { return std::max(settings_.exterior_band_m, 2 * voxel_m_); }
  static constexpr double kMaxInsideVoxels = 2e6;
  // Rest-frame box of the surface grown by the exterior band: outside it the field reads "far".
  const AlignedBox& reach() const { return reach_; }
  // The same box around the bone placed by `pose` (rest frame to world), axis-aligned again.
  AlignedBox reachIn(const Eigen::Isometry3d& pose) const;
  double buildMilliseconds() const { return build_ms_; }
  std::size_t memoryBytes() const;

 private:
  struct Grid;
  std::unique_ptr<Grid> grid_;
  std::string name_;
  BoneFieldSettings settings_;
  AlignedBox reach_;
  double voxel_m_ = 0;
  double build_ms_ = 0;
};

// What earlier reads of one bone's field proved about a set of points: for each point the distance (or the lower bound
// a read proved) at the point of the bone's frame where it was read. The interpolated field changes at most sqrt(3)
// times as fast as a point moves (each axis at most as fast), so a point that has not moved far enough from there to
// come within a limit need not be read again: skipping is exact. Frame to frame most points of a muscle stay far from
// most bones, which is what makes the contacts and the inside-bone metrics cheap.
class FieldReadCache {
 public:
  static constexpr double kSlope = 1.7320508075688772;  // sqrt(3)

  FieldReadCache() = default;
  // `points` points, none read yet (every one is read on its first query).
  explicit FieldReadCache(Eigen::Index points);

  // Whether point k, now at `local` (bone frame), is still proven at least `limit` from the bone:
  // distance - sqrt(3) |moved| >= limit, compared in squares (no square root on the hot path).
  bool provenBeyond(Eigen::Index k, const Eigen::Vector3d& local, double limit) const {
    const double room = distance_[k] - limit;
    return room >= 0 && 3.0 * (local - at_.col(k)).squaredNorm() <= room * room;
  }
  // What a read of point k at `local` gave (Probe::closerThan's distance, exact or a lower bound).
  void remember(Eigen::Index k, const Eigen::Vector3d& local, double distance) {
    at_.col(k) = local;
    distance_[k] = distance;
  }
  Eigen::Index size() const { return distance_.size(); }

 private:
  Eigen::Matrix3Xd at_;
  Eigen::VectorXd distance_;
};

// One field per bone, shared: built once per scene and handed to every simulation, pipeline and metrics that use it
// (building them is most of a scene's start-up).
using BoneFields = std::vector<std::shared_ptr<const BoneDistanceField>>;

struct Bone;
// Builds every bone's field (names in error messages are "bone '<name>'").
BoneFields buildBoneFields(const std::vector<Bone>& bones, const BoneFieldSettings& settings);

}  // namespace muscle_deformation
