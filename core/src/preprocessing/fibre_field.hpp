// Fibre generation, the field step (private header): the voxel grid, the harmonic field on it, its cross-sections.
#pragma once

#include "fibre_steps.hpp"

#include <Eigen/Core>

#include <cmath>
#include <limits>
#include <vector>

namespace muscle_deformation::fibre_steps {

// ---------------------------------------------------------------------------------------------------------------
// Voxel grid: voxel (i, j, k) has its centre at lower + h * (i + 0.5, j + 0.5, k + 0.5).

struct Grid {
  Eigen::Vector3d lower = Eigen::Vector3d::Zero();
  double h = 0;
  int n[3] = {0, 0, 0};

  long cells() const { return static_cast<long>(n[0]) * n[1] * n[2]; }
  long index(int i, int j, int k) const { return i + static_cast<long>(n[0]) * (j + static_cast<long>(n[1]) * k); }
  void coords(long v, int& i, int& j, int& k) const {
    i = static_cast<int>(v % n[0]);
    j = static_cast<int>((v / n[0]) % n[1]);
    k = static_cast<int>(v / (static_cast<long>(n[0]) * n[1]));
  }
  Eigen::Vector3d centre(long v) const {
    int i, j, k;
    coords(v, i, j, k);
    return lower + h * Eigen::Vector3d(i + 0.5, j + 0.5, k + 0.5);
  }
  // The 6 face neighbours of v, -1 where the grid ends.
  void neighbours(long v, long out[6]) const {
    int i, j, k;
    coords(v, i, j, k);
    const long sy = n[0], sz = static_cast<long>(n[0]) * n[1];
    out[0] = i > 0 ? v - 1 : -1;
    out[1] = i + 1 < n[0] ? v + 1 : -1;
    out[2] = j > 0 ? v - sy : -1;
    out[3] = j + 1 < n[1] ? v + sy : -1;
    out[4] = k > 0 ? v - sz : -1;
    out[5] = k + 1 < n[2] ? v + sz : -1;
  }
};

// ---------------------------------------------------------------------------------------------------------------
// The harmonic field

struct Field {
  Grid grid;
  std::vector<char> domain;         // inside voxels of the solved pieces
  std::vector<signed char> label;   // -1 free, 0 origin (phi = 0), 1 insertion (phi = 1)
  std::vector<double> phi;          // defined where valid
  std::vector<char> valid;          // domain plus two extension layers outside (zero-flux continuation)
  std::vector<Eigen::Vector3d> grad;
  long inside = 0, dropped = 0;
  int iterations = 0;
  double error = 0;

  // Trilinear interpolation of phi and its gradient; false where a cell corner is undefined.
  bool sample(const Eigen::Vector3d& p, double* value, Eigen::Vector3d* gradient) const {
    const Eigen::Vector3d u = (p - grid.lower) / grid.h - Eigen::Vector3d::Constant(0.5);
    int c[3];
    double f[3];
    for (int a = 0; a < 3; ++a) {
      if (!(u[a] >= 0.0)) return false;
      c[a] = static_cast<int>(std::floor(u[a]));
      if (c[a] + 1 >= grid.n[a]) return false;
      f[a] = u[a] - c[a];
    }
    double v = 0;
    Eigen::Vector3d g = Eigen::Vector3d::Zero();
    for (int corner = 0; corner < 8; ++corner) {
      const int di = corner & 1, dj = (corner >> 1) & 1, dk = (corner >> 2) & 1;
      const long idx = grid.index(c[0] + di, c[1] + dj, c[2] + dk);
      if (!valid[static_cast<std::size_t>(idx)]) return false;
      const double w = (di ? f[0] : 1 - f[0]) * (dj ? f[1] : 1 - f[1]) * (dk ? f[2] : 1 - f[2]);
      v += w * phi[static_cast<std::size_t>(idx)];
      g += w * grad[static_cast<std::size_t>(idx)];
    }
    if (value) *value = v;
    if (gradient) *gradient = g;
    return true;
  }

  long nearestVoxel(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d u = (p - grid.lower) / grid.h;
    int c[3];
    for (int a = 0; a < 3; ++a) {
      if (!(u[a] >= 0.0)) return -1;
      c[a] = static_cast<int>(std::floor(u[a]));
      if (c[a] >= grid.n[a]) return -1;
    }
    return grid.index(c[0], c[1], c[2]);
  }
  bool inDomain(const Eigen::Vector3d& p) const {
    const long v = nearestVoxel(p);
    return v >= 0 && domain[static_cast<std::size_t>(v)];
  }
  // Moves p into the nearest domain voxel around it (false if there is none): streamlines hugging the zero-flux rim
  // drift out through the voxel staircase; this slides them back along it. p is pulled straight towards that voxel's
  // centre, just far enough to enter it, so that distinct streamlines stay distinct (clamping to the voxel's faces
  // would send neighbours to the same corner).
  bool pullInside(Eigen::Vector3d& p) const {
    const Eigen::Vector3d u = (p - grid.lower) / grid.h;
    const int c[3] = {static_cast<int>(std::floor(u[0])), static_cast<int>(std::floor(u[1])),
                      static_cast<int>(std::floor(u[2]))};
    double best = std::numeric_limits<double>::infinity();
    Eigen::Vector3d moved = p;
    for (int dk = -1; dk <= 1; ++dk)
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int i = c[0] + di, j = c[1] + dj, k = c[2] + dk;
          if (i < 0 || j < 0 || k < 0 || i >= grid.n[0] || j >= grid.n[1] || k >= grid.n[2]) continue;
          if (!domain[static_cast<std::size_t>(grid.index(i, j, k))]) continue;
          // Mirror the overshoot back across the faces of that voxel's cube (kept a hair inside it): a reflection
          // keeps the distance between neighbouring streamlines, where clamping or shrinking towards the centre
          // would contract them step after step until they coincide.
          const Eigen::Vector3d lo = grid.lower + grid.h * Eigen::Vector3d(i + 0.01, j + 0.01, k + 0.01);
          const Eigen::Vector3d hi = grid.lower + grid.h * Eigen::Vector3d(i + 0.99, j + 0.99, k + 0.99);
          const Eigen::Vector3d clamped = p.cwiseMax(lo).cwiseMin(hi);
          Eigen::Vector3d q = 2 * clamped - p;
          if ((q.array() < lo.array()).any() || (q.array() > hi.array()).any()) q = clamped;  // overshoot > a voxel
          const double d = (clamped - p).squaredNorm();
          if (d < best) {
            best = d;
            moved = q;
          }
        }
    if (!std::isfinite(best)) return false;
    p = moved;
    return true;
  }
  int labelAt(const Eigen::Vector3d& p) const {
    const long v = nearestVoxel(p);
    return v >= 0 && domain[static_cast<std::size_t>(v)] ? label[static_cast<std::size_t>(v)] : -1;
  }
};

// Points where the field crosses `level` along voxel edges, each with the iso-surface area it stands for.
struct CrossSection {
  std::vector<Eigen::Vector3d> points;
  std::vector<double> areas;
  double area = 0;
  double level = 0.5;
  double volume_fraction = 0;  // share of the solved voxels with a field value below `level`
};

// The voxel edge used: options.voxel_size, or finer for a small muscle (FibreGeneratorOptions::min_inside_voxels).
double effectiveVoxel(const TriangleMesh& surface, const FibreGeneratorOptions& options);

// The harmonic field of `patches` (0 origin, 1 insertion) on voxels of edge h.
Field solveField(const TriangleMesh& surface, const AttachmentPatches& patches, double h,
                 const FibreGeneratorOptions& options);

// The cross-sections the seeds may be spread over, the preferred first (FibreGeneratorOptions::seed_section).
std::vector<CrossSection> seedingCrossSections(const Field& f, const FibreGeneratorOptions& options);

}  // namespace muscle_deformation::fibre_steps
