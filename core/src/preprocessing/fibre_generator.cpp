// Fibre generation inside a closed surface (Choi & Blemker 2013): voxelise, solve Laplace's equation with Dirichlet
// patches at origin and insertion, trace gradient streamlines from seeds spread over a cross-section (an iso-surface).
#include "muscle_deformation/preprocessing/fibre_generator.hpp"

#include "muscle_deformation/core/collision/point_index.hpp"
#include "muscle_deformation/core/io/mesh_io.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/IterativeLinearSolvers>
#include <Eigen/Sparse>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <fstream>
#include <iomanip>
#include <limits>
#include <numeric>
#include <sstream>

namespace muscle_deformation {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

std::string mm(double metres, int precision = 2) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(precision) << metres * 1e3 << " mm";
  return out.str();
}

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

// Inside test of every voxel centre by vertical rays: each column collects the heights where it crosses the surface,
// signed by the triangle's facing, and a centre is inside where the running winding count is non-zero. Crossings on a
// shared edge or vertex are counted once thanks to a top-left ownership rule, so the count is exact.
std::vector<char> voxelise(const TriangleMesh& mesh, const Grid& g) {
  std::vector<std::vector<std::pair<double, int>>> columns(static_cast<std::size_t>(g.n[0]) * g.n[1]);
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    Eigen::Vector3d a = mesh.vertices.col(mesh.triangles(0, t));
    Eigen::Vector3d b = mesh.vertices.col(mesh.triangles(1, t));
    Eigen::Vector3d c = mesh.vertices.col(mesh.triangles(2, t));
    const double area2 = (b.x() - a.x()) * (c.y() - a.y()) - (b.y() - a.y()) * (c.x() - a.x());
    if (area2 == 0.0) continue;  // seen edge-on by vertical rays: its neighbours carry the crossing
    // Upward-facing triangles are where a rising ray leaves the volume.
    const int sign = area2 > 0 ? -1 : +1;
    if (area2 < 0) std::swap(b, c);  // counter-clockwise in the xy projection from here on
    const double xmin = std::min({a.x(), b.x(), c.x()}), xmax = std::max({a.x(), b.x(), c.x()});
    const double ymin = std::min({a.y(), b.y(), c.y()}), ymax = std::max({a.y(), b.y(), c.y()});
    const int i0 = std::max(0, static_cast<int>(std::ceil((xmin - g.lower.x()) / g.h - 0.5)));
    const int i1 = std::min(g.n[0] - 1, static_cast<int>(std::floor((xmax - g.lower.x()) / g.h - 0.5)));
    const int j0 = std::max(0, static_cast<int>(std::ceil((ymin - g.lower.y()) / g.h - 0.5)));
    const int j1 = std::min(g.n[1] - 1, static_cast<int>(std::floor((ymax - g.lower.y()) / g.h - 0.5)));
    const Eigen::Vector3d* v[3] = {&a, &b, &c};
    const double area = std::abs(area2);
    for (int j = j0; j <= j1; ++j) {
      const double y = g.lower.y() + (j + 0.5) * g.h;
      for (int i = i0; i <= i1; ++i) {
        const double x = g.lower.x() + (i + 0.5) * g.h;
        double w[3];
        bool inside = true;
        for (int e = 0; e < 3 && inside; ++e) {
          const Eigen::Vector3d& p0 = *v[(e + 1) % 3];
          const Eigen::Vector3d& p1 = *v[(e + 2) % 3];
          const double dx = p1.x() - p0.x(), dy = p1.y() - p0.y();
          w[e] = dx * (y - p0.y()) - dy * (x - p0.x());  // twice the area opposite vertex e
          // A point on an edge belongs to the triangle only if the edge is a "top" or "left" one: of two triangles
          // sharing the edge (traversed in opposite directions) exactly one owns it.
          const bool owns_edge = dy < 0 || (dy == 0 && dx < 0);
          inside = w[e] > 0 || (w[e] == 0 && owns_edge);
        }
        if (!inside) continue;
        const double z = (w[0] * a.z() + w[1] * b.z() + w[2] * c.z()) / area;
        columns[static_cast<std::size_t>(i) + static_cast<std::size_t>(g.n[0]) * j].emplace_back(z, sign);
      }
    }
  }
  std::vector<char> inside(static_cast<std::size_t>(g.cells()), 0);
  for (int j = 0; j < g.n[1]; ++j) {
    for (int i = 0; i < g.n[0]; ++i) {
      auto& hits = columns[static_cast<std::size_t>(i) + static_cast<std::size_t>(g.n[0]) * j];
      if (hits.empty()) continue;
      std::sort(hits.begin(), hits.end());
      int winding = 0;
      std::size_t next = 0;
      for (int k = 0; k < g.n[2]; ++k) {
        const double z = g.lower.z() + (k + 0.5) * g.h;
        while (next < hits.size() && hits[next].first < z) winding += hits[next++].second;
        if (winding != 0) inside[static_cast<std::size_t>(g.index(i, j, k))] = 1;
      }
    }
  }
  return inside;
}

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

void requireClosed(const TriangleMesh& surface) {
  if (surface.vertexCount() == 0 || surface.triangleCount() == 0) {
    throw FibreGenerationError("the muscle surface is empty");
  }
  if (!surface.vertices.allFinite()) throw FibreGenerationError("the muscle surface has non-finite vertices");
  const SurfaceTopologyReport topology = checkSurfaceTopology(surface);
  if (!topology.closedManifold()) {
    throw FibreGenerationError("the muscle surface must be closed and 2-manifold to have an inside: " +
                               topology.describe());
  }
}

double effectiveVoxel(const TriangleMesh& surface, const FibreGeneratorOptions& options) {
  if (!(options.voxel_size > 0) || !std::isfinite(options.voxel_size)) {
    throw FibreGenerationError("voxel size must be a positive number of metres");
  }
  double h = options.voxel_size;
  const double volume = std::abs(enclosedVolume(surface));
  if (!(volume > 0)) throw FibreGenerationError("the muscle surface encloses no volume");
  if (options.min_inside_voxels > 0 && volume / (h * h * h) < static_cast<double>(options.min_inside_voxels)) {
    h = std::cbrt(volume / static_cast<double>(options.min_inside_voxels));
  }
  return h;
}

void validateOptions(const FibreGeneratorOptions& options) {
  if (options.fibre_count < 1) throw FibreGenerationError("the number of fibres must be at least 1");
  if (options.points_per_fibre < 2) throw FibreGenerationError("a fibre needs at least 2 points");
  if (!(options.attachment_distance > 0)) throw FibreGenerationError("the attachment distance must be positive");
  if (!(options.step_voxels > 0 && options.step_voxels <= 1)) {
    throw FibreGenerationError("the streamline step must be in (0, 1] voxels");
  }
}

void validatePatches(const TriangleMesh& surface, const AttachmentPatches& patches) {
  if (patches.origin_vertices.empty() || patches.insertion_vertices.empty()) {
    throw FibreGenerationError("both the origin and the insertion patch need at least one surface vertex");
  }
  std::vector<char> seen(static_cast<std::size_t>(surface.vertexCount()), 0);
  for (int v : patches.origin_vertices) {
    if (v < 0 || v >= surface.vertexCount()) throw FibreGenerationError("origin patch vertex index out of range");
    seen[static_cast<std::size_t>(v)] = 1;
  }
  for (int v : patches.insertion_vertices) {
    if (v < 0 || v >= surface.vertexCount()) throw FibreGenerationError("insertion patch vertex index out of range");
    if (seen[static_cast<std::size_t>(v)]) throw FibreGenerationError("the origin and insertion patches overlap");
  }
}

Field solveField(const TriangleMesh& surface, const AttachmentPatches& patches, double h,
                 const FibreGeneratorOptions& options) {
  Field f;
  Grid& g = f.grid;
  g.h = h;
  const AlignedBox box = boundsOf(surface.vertices);
  const int pad = 3;
  // A tiny irrational shift keeps voxel centres off mesh vertices that happen to lie on round coordinates.
  g.lower = box.min - Eigen::Vector3d::Constant(pad * h) + h * Eigen::Vector3d(1e-7 * M_SQRT2, 1e-7 * M_PI, 1e-7 * M_E);
  for (int a = 0; a < 3; ++a) g.n[a] = static_cast<int>(std::ceil((box.max[a] - box.min[a]) / h)) + 2 * pad;
  if (g.cells() > options.max_grid_cells) {
    std::ostringstream msg;
    msg << "the voxel grid would have " << g.cells() << " cells (limit " << options.max_grid_cells
        << "): use a larger voxel size than " << h << " m";
    throw FibreGenerationError(msg.str());
  }
  const std::vector<char> inside = voxelise(surface, g);
  const std::size_t cells = static_cast<std::size_t>(g.cells());

  // Dirichlet voxels: inside voxels on the boundary whose nearest surface vertex belongs to a patch.
  std::vector<signed char> vertex_label(static_cast<std::size_t>(surface.vertexCount()), -1);
  for (int v : patches.origin_vertices) vertex_label[static_cast<std::size_t>(v)] = 0;
  for (int v : patches.insertion_vertices) vertex_label[static_cast<std::size_t>(v)] = 1;
  f.label.assign(cells, -1);
  std::vector<long> boundary;
  long nb[6];
  for (std::size_t v = 0; v < cells; ++v) {
    if (!inside[v]) continue;
    g.neighbours(static_cast<long>(v), nb);
    for (long w : nb) {
      if (w < 0 || !inside[static_cast<std::size_t>(w)]) {
        boundary.push_back(static_cast<long>(v));
        break;
      }
    }
  }
  if (boundary.empty()) {
    throw FibreGenerationError("no voxel centre lies inside the surface at voxel size " + mm(h, 3) +
                               ": use a smaller voxel size");
  }
  const PointIndex surface_vertices(surface.vertices);
  long labelled[2] = {0, 0};
  for (long v : boundary) {
    const int l = vertex_label[static_cast<std::size_t>(surface_vertices.nearest(g.centre(v)).first)];
    f.label[static_cast<std::size_t>(v)] = static_cast<signed char>(l);
    if (l >= 0) ++labelled[l];
  }
  // A patch smaller than the voxels may be nobody's nearest vertex: then each of its vertices claims its nearest
  // boundary voxel, so that a non-empty patch always gets Dirichlet voxels.
  Eigen::Matrix3Xd boundary_centres(3, static_cast<Eigen::Index>(boundary.size()));
  for (std::size_t b = 0; b < boundary.size(); ++b) boundary_centres.col(static_cast<Eigen::Index>(b)) = g.centre(boundary[b]);
  const PointIndex boundary_index(boundary_centres);
  for (int l = 0; l < 2; ++l) {
    if (labelled[l] > 0) continue;
    for (int v : l == 0 ? patches.origin_vertices : patches.insertion_vertices) {
      const long voxel = boundary[static_cast<std::size_t>(boundary_index.nearest(surface.vertices.col(v)).first)];
      if (f.label[static_cast<std::size_t>(voxel)] < 0) {
        f.label[static_cast<std::size_t>(voxel)] = static_cast<signed char>(l);
        ++labelled[l];
      }
    }
  }

  // Keep only the connected pieces of the interior that touch both patches: elsewhere the field is undefined.
  f.domain.assign(cells, 0);
  std::vector<int> component(cells, -1);
  int components = 0;
  for (std::size_t start = 0; start < cells; ++start) {
    if (!inside[start] || component[start] >= 0) continue;
    std::vector<long> members{static_cast<long>(start)};
    component[start] = components;
    bool has[2] = {false, false};
    for (std::size_t m = 0; m < members.size(); ++m) {
      const long v = members[m];
      if (f.label[static_cast<std::size_t>(v)] >= 0) has[f.label[static_cast<std::size_t>(v)]] = true;
      g.neighbours(v, nb);
      for (long w : nb) {
        if (w >= 0 && inside[static_cast<std::size_t>(w)] && component[static_cast<std::size_t>(w)] < 0) {
          component[static_cast<std::size_t>(w)] = components;
          members.push_back(w);
        }
      }
    }
    ++components;
    if (has[0] && has[1]) {
      for (long v : members) f.domain[static_cast<std::size_t>(v)] = 1;
      f.inside += static_cast<long>(members.size());
    } else {
      f.dropped += static_cast<long>(members.size());
    }
  }
  if (f.inside == 0) {
    throw FibreGenerationError("the origin and insertion patches are not connected through the voxelised interior at "
                               "voxel size " + mm(h, 3) + ": use a smaller voxel size or check the patches");
  }

  // Laplace's equation on the 7-point stencil. Free voxel rows: sum over domain neighbours of (phi_v - phi_w) = 0;
  // neighbours outside the domain are left out, which is the zero-flux condition on the rest of the surface.
  std::vector<long> unknown(cells, -1);
  long unknowns = 0;
  for (std::size_t v = 0; v < cells; ++v)
    if (f.domain[v] && f.label[v] < 0) unknown[v] = unknowns++;
  f.phi.assign(cells, 0.0);
  for (std::size_t v = 0; v < cells; ++v)
    if (f.domain[v] && f.label[v] == 1) f.phi[v] = 1.0;
  if (unknowns > 0) {
    std::vector<Eigen::Triplet<double>> entries;
    entries.reserve(static_cast<std::size_t>(unknowns) * 7);
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(unknowns);
    for (std::size_t v = 0; v < cells; ++v) {
      const long row = unknown[v];
      if (row < 0) continue;
      g.neighbours(static_cast<long>(v), nb);
      double diagonal = 0;
      for (long w : nb) {
        if (w < 0 || !f.domain[static_cast<std::size_t>(w)]) continue;
        diagonal += 1;
        const long col = unknown[static_cast<std::size_t>(w)];
        if (col >= 0) {
          entries.emplace_back(row, col, -1.0);
        } else if (f.label[static_cast<std::size_t>(w)] == 1) {
          rhs[row] += 1.0;
        }
      }
      entries.emplace_back(row, row, diagonal);
    }
    Eigen::SparseMatrix<double> laplacian(unknowns, unknowns);
    laplacian.setFromTriplets(entries.begin(), entries.end());
    Eigen::ConjugateGradient<Eigen::SparseMatrix<double>, Eigen::Lower | Eigen::Upper,
                             Eigen::IncompleteCholesky<double>>
        cg;
    cg.setTolerance(1e-10);
    cg.setMaxIterations(20000);
    cg.compute(laplacian);
    if (cg.info() != Eigen::Success) throw FibreGenerationError("could not factor the Laplacian preconditioner");
    const Eigen::VectorXd solution = cg.solve(rhs);
    f.iterations = static_cast<int>(cg.iterations());
    f.error = cg.error();
    if (cg.info() != Eigen::Success && !(f.error < 1e-6)) {
      std::ostringstream msg;
      msg << "the Laplace solve did not converge (" << f.iterations << " iterations, relative residual " << f.error
          << ")";
      throw FibreGenerationError(msg.str());
    }
    for (std::size_t v = 0; v < cells; ++v)
      if (unknown[v] >= 0) f.phi[v] = std::clamp(solution[unknown[v]], 0.0, 1.0);
  }

  // Continue the field two layers outside by neighbour averages (a discrete zero-flux extension), so interpolation and
  // gradients work right up to the surface.
  f.valid = f.domain;
  for (int layer = 0; layer < 2; ++layer) {
    std::vector<std::pair<long, double>> added;
    for (std::size_t v = 0; v < cells; ++v) {
      if (f.valid[v]) continue;
      g.neighbours(static_cast<long>(v), nb);
      double sum = 0;
      int count = 0;
      for (long w : nb) {
        if (w >= 0 && f.valid[static_cast<std::size_t>(w)]) {
          sum += f.phi[static_cast<std::size_t>(w)];
          ++count;
        }
      }
      if (count > 0) added.emplace_back(static_cast<long>(v), sum / count);
    }
    for (const auto& [v, value] : added) {
      f.valid[static_cast<std::size_t>(v)] = 1;
      f.phi[static_cast<std::size_t>(v)] = value;
    }
  }
  f.grad.assign(cells, Eigen::Vector3d::Zero());
  for (std::size_t v = 0; v < cells; ++v) {
    if (!f.valid[v]) continue;
    g.neighbours(static_cast<long>(v), nb);
    for (int a = 0; a < 3; ++a) {
      const long lo = nb[2 * a], hi = nb[2 * a + 1];
      const bool has_lo = lo >= 0 && f.valid[static_cast<std::size_t>(lo)];
      const bool has_hi = hi >= 0 && f.valid[static_cast<std::size_t>(hi)];
      if (has_lo && has_hi) {
        f.grad[v][a] = (f.phi[static_cast<std::size_t>(hi)] - f.phi[static_cast<std::size_t>(lo)]) / (2 * h);
      } else if (has_hi) {
        f.grad[v][a] = (f.phi[static_cast<std::size_t>(hi)] - f.phi[v]) / h;
      } else if (has_lo) {
        f.grad[v][a] = (f.phi[v] - f.phi[static_cast<std::size_t>(lo)]) / h;
      }
    }
  }
  return f;
}

// Points where the field crosses `level` along voxel edges, each with the iso-surface area it stands for.
struct CrossSection {
  std::vector<Eigen::Vector3d> points;
  std::vector<double> areas;
  double area = 0;
  double level = 0.5;
  double volume_fraction = 0;  // share of the solved voxels with a field value below `level`
};

CrossSection crossSectionAt(const Field& f, double level) {
  CrossSection out;
  out.level = level;
  const Grid& g = f.grid;
  long nb[6], domain = 0, below = 0;
  for (std::size_t v = 0; v < f.domain.size(); ++v) {
    if (!f.domain[v]) continue;
    ++domain;
    if (f.phi[v] < level) ++below;
    g.neighbours(static_cast<long>(v), nb);
    for (int a = 0; a < 3; ++a) {
      const long w = nb[2 * a + 1];
      if (w < 0 || !f.domain[static_cast<std::size_t>(w)]) continue;
      const double p0 = f.phi[v] - level, p1 = f.phi[static_cast<std::size_t>(w)] - level;
      if (!((p0 < 0 && p1 >= 0) || (p0 >= 0 && p1 < 0))) continue;
      const double t = p0 / (p0 - p1);
      const Eigen::Vector3d p = (1 - t) * g.centre(static_cast<long>(v)) + t * g.centre(w);
      Eigen::Vector3d n = (1 - t) * f.grad[v] + t * f.grad[static_cast<std::size_t>(w)];
      // An axis-a edge crossing stands for h^2 of area projected along a, i.e. h^2/|n_a| of surface; weighting the three
      // axes by n_a^2 (which sums to 1) counts each bit of surface once: h^2 |n_a|.
      const double weight = n.norm() > 0 ? g.h * g.h * std::abs(n[a]) / n.norm() : g.h * g.h / 3;
      out.points.push_back(p);
      out.areas.push_back(weight);
      out.area += weight;
    }
  }
  out.volume_fraction = domain > 0 ? static_cast<double>(below) / static_cast<double>(domain) : 0;
  return out;
}

// The cross-sections the seeds may be spread over (FibreGeneratorOptions::seed_section), the preferred first: the
// field's 0.5 iso-surface alone, or the iso-surfaces at 10, 15, ... 90 % of the volume from the origin, largest first.
// Those are taken at shares of the volume rather than at field values because where a muscle narrows into a tendon the
// field drops steeply: equal steps of the field would crowd into the tendon and skip over the belly. Levels within
// kPatchLevelMargin of a patch's value are left out: there the field is flat, in pockets of the muscle beyond a patch
// that no streamline runs through.
constexpr double kPatchLevelMargin = 0.02;
std::vector<CrossSection> seedingCrossSections(const Field& f, const FibreGeneratorOptions& options) {
  if (options.seed_section == SeedSection::mid_value) return {crossSectionAt(f, 0.5)};
  std::vector<double> values;
  for (std::size_t v = 0; v < f.domain.size(); ++v)
    if (f.domain[v]) values.push_back(f.phi[v]);
  std::sort(values.begin(), values.end());
  std::vector<CrossSection> sections;
  double previous = -1;
  for (int percent = 10; percent <= 90; percent += 5) {
    const double level = values[static_cast<std::size_t>(percent / 100.0 * static_cast<double>(values.size() - 1))];
    if (level < kPatchLevelMargin || level > 1.0 - kPatchLevelMargin || level == previous) continue;
    previous = level;
    CrossSection section = crossSectionAt(f, level);
    if (!section.points.empty()) sections.push_back(std::move(section));
  }
  if (sections.empty()) return {crossSectionAt(f, 0.5)};
  std::stable_sort(sections.begin(), sections.end(),
                   [](const CrossSection& a, const CrossSection& b) { return a.area > b.area; });
  return sections;
}

// ---------------------------------------------------------------------------------------------------------------
// Geometry helpers

double segmentSegmentDistance(const Eigen::Vector3d& p1, const Eigen::Vector3d& q1, const Eigen::Vector3d& p2,
                              const Eigen::Vector3d& q2) {
  const Eigen::Vector3d d1 = q1 - p1, d2 = q2 - p2, r = p1 - p2;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  double s = 0, t = 0;
  if (a <= 1e-30 && e <= 1e-30) return r.norm();
  if (a <= 1e-30) {
    t = std::clamp(f / e, 0.0, 1.0);
  } else {
    const double c = d1.dot(r);
    if (e <= 1e-30) {
      s = std::clamp(-c / a, 0.0, 1.0);
    } else {
      const double b = d1.dot(d2), denom = a * e - b * b;
      s = denom > 1e-30 ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
      t = (b * s + f) / e;
      if (t < 0) {
        t = 0;
        s = std::clamp(-c / a, 0.0, 1.0);
      } else if (t > 1) {
        t = 1;
        s = std::clamp((b - c) / a, 0.0, 1.0);
      }
    }
  }
  return ((p1 + s * d1) - (p2 + t * d2)).norm();
}

double pointSegmentDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

// The surface triangles touching a patch (any corner in it).
TriangleMesh patchSurface(const TriangleMesh& surface, const std::vector<int>& vertices) {
  std::vector<char> in(static_cast<std::size_t>(surface.vertexCount()), 0);
  for (int v : vertices) in[static_cast<std::size_t>(v)] = 1;
  std::vector<Eigen::Index> keep;
  for (Eigen::Index t = 0; t < surface.triangleCount(); ++t)
    if (in[surface.triangles(0, t)] || in[surface.triangles(1, t)] || in[surface.triangles(2, t)]) keep.push_back(t);
  TriangleMesh out;
  out.vertices = surface.vertices;
  out.triangles.resize(3, static_cast<Eigen::Index>(keep.size()));
  for (std::size_t i = 0; i < keep.size(); ++i) out.triangles.col(static_cast<Eigen::Index>(i)) = surface.triangles.col(keep[i]);
  return out;
}

// Where the ray from `from` through `to` first leaves `surface`, within `reach` beyond `to` (Moller-Trumbore);
// false if it does not.
bool rayExit(const TriangleMesh& surface, const Eigen::Vector3d& from, const Eigen::Vector3d& to, double reach,
             Eigen::Vector3d& hit) {
  const Eigen::Vector3d d = (to - from).normalized();
  if (!d.allFinite()) return false;
  double best = kInf;
  for (Eigen::Index t = 0; t < surface.triangleCount(); ++t) {
    const Eigen::Vector3d a = surface.vertices.col(surface.triangles(0, t));
    const Eigen::Vector3d e1 = surface.vertices.col(surface.triangles(1, t)) - a;
    const Eigen::Vector3d e2 = surface.vertices.col(surface.triangles(2, t)) - a;
    const Eigen::Vector3d q = d.cross(e2);
    const double det = e1.dot(q);
    if (std::abs(det) < 1e-18) continue;
    const Eigen::Vector3d r = to - a;
    const double u = r.dot(q) / det;
    if (u < 0 || u > 1) continue;
    const Eigen::Vector3d w = r.cross(e1);
    const double v = d.dot(w) / det;
    if (v < 0 || u + v > 1) continue;
    const double dist = e2.dot(w) / det;
    if (dist >= 0 && dist <= reach && dist < best) best = dist;
  }
  if (!std::isfinite(best)) return false;
  hit = to + best * d;
  return true;
}

Polyline resample(const std::vector<Eigen::Vector3d>& points, int count) {
  std::vector<double> s(points.size(), 0.0);
  for (std::size_t i = 1; i < points.size(); ++i) s[i] = s[i - 1] + (points[i] - points[i - 1]).norm();
  Polyline out(3, count);
  std::size_t seg = 1;
  for (int k = 0; k < count; ++k) {
    const double target = s.back() * k / (count - 1);
    while (seg + 1 < points.size() && s[seg] < target) ++seg;
    const double span = s[seg] - s[seg - 1];
    const double t = span > 0 ? std::clamp((target - s[seg - 1]) / span, 0.0, 1.0) : 0.0;
    out.col(k) = (1 - t) * points[seg - 1] + t * points[seg];
  }
  out.col(0) = points.front();
  out.col(count - 1) = points.back();
  return out;
}

// ---------------------------------------------------------------------------------------------------------------
// Seeds and streamlines

// `count` well-spread samples of the cross-section: farthest-point sampling, then Lloyd iterations (each seed moves to
// the area-weighted centroid of the samples nearest to it, snapped back onto a sample), which evens out the spacing
// and keeps seeds half a spacing away from the rim.
std::vector<std::size_t> spreadSeeds(const CrossSection& section, const std::vector<char>& allowed, int count) {
  std::vector<std::size_t> candidates;
  for (std::size_t i = 0; i < section.points.size(); ++i)
    if (allowed[i]) candidates.push_back(i);
  if (candidates.size() <= static_cast<std::size_t>(count)) return candidates;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double total = 0;
  for (std::size_t i : candidates) {
    centroid += section.areas[i] * section.points[i];
    total += section.areas[i];
  }
  centroid /= total;
  std::vector<double> nearest(candidates.size(), kInf);
  std::vector<std::size_t> seeds;
  std::size_t pick = 0;
  double best = kInf;
  for (std::size_t c = 0; c < candidates.size(); ++c) {
    const double d = (section.points[candidates[c]] - centroid).squaredNorm();
    if (d < best) {
      best = d;
      pick = c;
    }
  }
  for (int s = 0; s < count; ++s) {
    seeds.push_back(candidates[pick]);
    const Eigen::Vector3d& p = section.points[candidates[pick]];
    double farthest = -1;
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      nearest[c] = std::min(nearest[c], (section.points[candidates[c]] - p).squaredNorm());
      if (nearest[c] > farthest) {
        farthest = nearest[c];
        pick = c;
      }
    }
  }
  std::vector<int> owner(candidates.size(), 0);
  for (int iteration = 0; iteration < 40; ++iteration) {
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      double d_best = kInf;
      for (int s = 0; s < count; ++s) {
        const double d = (section.points[candidates[c]] - section.points[seeds[static_cast<std::size_t>(s)]]).squaredNorm();
        if (d < d_best) {
          d_best = d;
          owner[c] = s;
        }
      }
    }
    std::vector<Eigen::Vector3d> sums(static_cast<std::size_t>(count), Eigen::Vector3d::Zero());
    std::vector<double> weights(static_cast<std::size_t>(count), 0.0);
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      sums[static_cast<std::size_t>(owner[c])] += section.areas[candidates[c]] * section.points[candidates[c]];
      weights[static_cast<std::size_t>(owner[c])] += section.areas[candidates[c]];
    }
    std::vector<double> snap(static_cast<std::size_t>(count), kInf);
    std::vector<std::size_t> moved = seeds;
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      const std::size_t s = static_cast<std::size_t>(owner[c]);
      if (!(weights[s] > 0)) continue;
      const double d = (section.points[candidates[c]] - sums[s] / weights[s]).squaredNorm();
      if (d < snap[s]) {
        snap[s] = d;
        moved[s] = candidates[c];
      }
    }
    if (moved == seeds) break;
    seeds.swap(moved);
  }
  return seeds;
}

// Follows the normalised gradient (direction +1 towards the insertion, -1 towards the origin) with RK4 until the
// nearest voxel is a Dirichlet voxel of `target`. Appends the points after `start`; false if it left the muscle or
// stalled first.
bool traceStreamline(const Field& f, const Eigen::Vector3d& start, double direction, int target,
                     const SurfaceDistance& target_patch, double step, int max_steps,
                     std::vector<Eigen::Vector3d>& out) {
  // Stop a voxel and a half short of the patch: in the last voxels streamlines funnelled into a small patch run along
  // the staircase rim and would be squeezed together; the fibre is finished with a straight segment instead.
  const double arrive = 1.5 * f.grid.h;
  auto heading = [&](const Eigen::Vector3d& p, Eigen::Vector3d& d) {
    Eigen::Vector3d g;
    if (!f.sample(p, nullptr, &g)) return false;
    const double norm = g.norm();
    if (!(norm > 1e-9)) return false;
    d = direction * g / norm;
    return true;
  };
  Eigen::Vector3d p = start;
  double value = 0;
  f.sample(p, &value, nullptr);
  int regressions = 0;
  for (int s = 0; s < max_steps; ++s) {
    if (target_patch.distanceWithin(p, arrive) <= arrive) return true;
    // In a Dirichlet voxel labelled through a coarse patch vertex, but not near the patch itself: the field is flat
    // here, so the streamline cannot reach the patch (it is reseeded).
    if (f.labelAt(p) == target) return target_patch.distanceWithin(p, 2 * f.grid.h) <= 2 * f.grid.h;
    Eigen::Vector3d k1, k2, k3, k4;
    if (!heading(p, k1)) return false;
    Eigen::Vector3d next;
    if (heading(p + 0.5 * step * k1, k2) && heading(p + 0.5 * step * k2, k3) && heading(p + step * k3, k4)) {
      next = p + step / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4);
    } else {
      next = p + step * k1;  // at the rim the RK4 stages may fall off the grid: an Euler step still moves on
    }
    if (!f.inDomain(next) && !f.pullInside(next)) return false;
    double next_value = value;
    if (!f.sample(next, &next_value, nullptr)) return false;
    // The field must keep rising (or falling): several steps against it mean a stagnation point.
    // Likewise a step that the rim pull undid: the streamline is pinned in a corner of the staircase, where it would
    // converge onto the same point as its neighbours.
    if ((next_value - value) * direction <= 0 || (next - p).norm() < 0.25 * step) {
      if (++regressions > 5) return false;
    }
    value = next_value;
    p = next;
    out.push_back(p);
  }
  return false;
}

// Closest approach of two polylines (segment to segment), skipping the work when their boxes are farther apart than
// `bound` (then returns bound).
double polylineDistance(const Polyline& a, const Polyline& b, const AlignedBox& box_a, const AlignedBox& box_b,
                        double bound) {
  const Eigen::Vector3d gap =
      (box_a.min - box_b.max).cwiseMax(box_b.min - box_a.max).cwiseMax(Eigen::Vector3d::Zero());
  if (gap.norm() >= bound) return bound;
  double best = bound;
  for (Eigen::Index i = 0; i + 1 < a.cols(); ++i)
    for (Eigen::Index j = 0; j + 1 < b.cols(); ++j)
      best = std::min(best, segmentSegmentDistance(a.col(i), a.col(i + 1), b.col(j), b.col(j + 1)));
  return best;
}

// The fibres traced from seeds spread over one cross-section, and what it took.
struct TracedFibres {
  std::vector<Polyline> fibres;
  int failed_seeds = 0, merged_fibres = 0, reseed_rounds = 0;  // as in FibreGenerationResult
};

// Streamlines of a field from seeds on a cross-section to both patches, finished on the surface and resampled.
class StreamlineTracer {
 public:
  StreamlineTracer(const Field& field, const TriangleMesh& surface, const AttachmentPatches& patches,
                   const FibreGeneratorOptions& options)
      : field_(field),
        surface_(surface),
        options_(options),
        h_(field.grid.h),
        step_(options.step_voxels * field.grid.h),
        origin_surface_(patchSurface(surface, patches.origin_vertices)),
        insertion_surface_(patchSurface(surface, patches.insertion_vertices)),
        origin_distance_(origin_surface_.vertices, origin_surface_.triangles),
        insertion_distance_(insertion_surface_.vertices, insertion_surface_.triangles) {
    const AlignedBox box = boundsOf(surface.vertices);
    max_steps_ = static_cast<int>(4.0 * (box.max - box.min).norm() / step_) + 10;
  }

  // Seeds whose streamline misses a patch (it runs into the rim or a stagnation point) are excluded with their
  // neighbourhood and the seeds are spread again, up to five times.
  TracedFibres traceFrom(const CrossSection& section) const {
    TracedFibres out;
    std::vector<char> allowed(section.points.size(), 1);
    const double spacing = std::sqrt(section.area / (M_PI * options_.fibre_count));
    for (int round = 0; round < 6; ++round) {
      const std::vector<std::size_t> seeds = spreadSeeds(section, allowed, options_.fibre_count);
      std::vector<Polyline> fibres;
      std::vector<std::size_t> failed, traced_seeds;
      for (std::size_t seed : seeds) {
        Polyline fibre;
        if (!traceFibre(section.points[seed], fibre)) {
          failed.push_back(seed);
          continue;
        }
        fibres.push_back(std::move(fibre));
        traced_seeds.push_back(seed);
      }
      // Streamlines funnelled into a narrow tendon can come within micrometres of each other (and would coincide once
      // written with finite precision): keep the first of such a pair, reseed near the other.
      const double min_separation = options_.min_separation;
      std::vector<AlignedBox> boxes;
      for (const Polyline& fibre : fibres) boxes.push_back(boundsOf(fibre));
      std::vector<char> drop(fibres.size(), 0);
      for (std::size_t a = 0; a < fibres.size(); ++a)
        for (std::size_t b = a + 1; b < fibres.size(); ++b)
          if (!drop[a] && !drop[b] &&
              polylineDistance(fibres[a], fibres[b], boxes[a], boxes[b], min_separation) < min_separation) {
            drop[b] = 1;
          }
      std::vector<Polyline> kept;
      int merged = 0;
      for (std::size_t i = 0; i < fibres.size(); ++i) {
        if (drop[i]) {
          failed.push_back(traced_seeds[i]);
          ++merged;
        } else {
          kept.push_back(std::move(fibres[i]));
        }
      }
      fibres.swap(kept);
      if (failed.empty() || round == 5) {  // the last round's losses are not reseeded: the count shows them
        out.fibres = std::move(fibres);
        break;
      }
      out.failed_seeds += static_cast<int>(failed.size());
      out.merged_fibres += merged;
      ++out.reseed_rounds;
      for (std::size_t s = 0; s < section.points.size(); ++s)
        for (std::size_t f : failed)
          if ((section.points[s] - section.points[f]).norm() < 0.5 * spacing) allowed[s] = 0;
    }
    return out;
  }

 private:
  // The fibre through `start`, origin first; false if its streamline misses a patch either way.
  bool traceFibre(const Eigen::Vector3d& start, Polyline& fibre) const {
    std::vector<Eigen::Vector3d> back, forward;
    if (!traceStreamline(field_, start, -1.0, 0, origin_distance_, step_, max_steps_, back) ||
        !traceStreamline(field_, start, +1.0, 1, insertion_distance_, step_, max_steps_, forward)) {
      return false;
    }
    std::vector<Eigen::Vector3d> points;
    for (auto it = back.rbegin(); it != back.rend(); ++it) points.push_back(*it);
    points.push_back(start);
    points.insert(points.end(), forward.begin(), forward.end());
    // End exactly on the attachment: continue the last step until it meets the patch (distinct streamlines meet it
    // at distinct points, unlike closest-point projection, which sends neighbours to the same patch vertex).
    // If that exit is not on the patch (the last step ran along the surface), the streamline keeps its own end,
    // which lies in a Dirichlet voxel next to the patch.
    Eigen::Vector3d hit;
    if (points.size() >= 2 && rayExit(surface_, points[1], points[0], 3 * h_, hit) &&
        origin_distance_.distance(hit) <= h_) {
      points.insert(points.begin(), hit);
    }
    if (points.size() >= 2 && rayExit(surface_, points[points.size() - 2], points.back(), 3 * h_, hit) &&
        insertion_distance_.distance(hit) <= h_) {
      points.push_back(hit);
    }
    fibre = resample(points, options_.points_per_fibre);
    return true;
  }

  const Field& field_;
  const TriangleMesh& surface_;
  const FibreGeneratorOptions& options_;
  double h_, step_;
  int max_steps_ = 0;
  TriangleMesh origin_surface_, insertion_surface_;
  SurfaceDistance origin_distance_, insertion_distance_;
};

// The checks, with the coverage measured on `section` (the one the seeds were spread over).
FibreCheckReport runChecks(const TriangleMesh& surface, const AttachmentPatches& patches,
                           const std::vector<Polyline>& fibres, const Field& field, const CrossSection& section,
                           const FibreGeneratorOptions& options) {
  FibreCheckReport r;
  r.fibre_count = static_cast<int>(fibres.size());
  r.tolerance = field.grid.h;
  if (fibres.empty()) {
    r.failures.push_back("no fibres");
    return r;
  }
  if (r.fibre_count < options.fibre_count) {
    r.failures.push_back(std::to_string(r.fibre_count) + " fibres instead of " + std::to_string(options.fibre_count));
  }
  r.min_length = kInf;
  double total = 0;
  for (const Polyline& fibre : fibres) {
    const double length = polylineLength(fibre);
    r.min_length = std::min(r.min_length, length);
    r.max_length = std::max(r.max_length, length);
    total += length;
    r.points += fibre.cols();
  }
  r.mean_length = total / static_cast<double>(fibres.size());

  // Inside: exact winding number, and points outside measured to the surface.
  const SurfaceDistance distance(surface.vertices, surface.triangles);
  for (const Polyline& fibre : fibres) {
    for (Eigen::Index i = 0; i < fibre.cols(); ++i) {
      if (windingNumber(surface, fibre.col(i)) >= 0.5) continue;
      const double d = distance.distance(fibre.col(i));
      r.max_outside_distance = std::max(r.max_outside_distance, d);
      if (d > r.tolerance) ++r.points_outside;
    }
  }
  if (r.points_outside > 0) {
    r.failures.push_back(std::to_string(r.points_outside) + " fibre points more than a voxel (" + mm(r.tolerance) +
                         ") outside the surface");
  }

  // Ends: start on the origin patch, end on the insertion patch (within two voxels).
  const TriangleMesh origin = patchSurface(surface, patches.origin_vertices);
  const TriangleMesh insertion = patchSurface(surface, patches.insertion_vertices);
  const SurfaceDistance to_origin(origin.vertices, origin.triangles);
  const SurfaceDistance to_insertion(insertion.vertices, insertion.triangles);
  for (const Polyline& fibre : fibres) {
    const double ds = to_origin.distance(fibre.col(0));
    const double de = to_insertion.distance(fibre.col(fibre.cols() - 1));
    r.max_start_distance = std::max(r.max_start_distance, ds);
    r.max_end_distance = std::max(r.max_end_distance, de);
    if (ds > 2 * r.tolerance) ++r.bad_starts;
    if (de > 2 * r.tolerance) ++r.bad_ends;
  }
  if (r.bad_starts > 0) r.failures.push_back(std::to_string(r.bad_starts) + " fibres do not start on the origin patch");
  if (r.bad_ends > 0) r.failures.push_back(std::to_string(r.bad_ends) + " fibres do not end on the insertion patch");

  // Crossing: the closest approach of any two fibres.
  r.min_pairwise_distance = kInf;
  std::vector<AlignedBox> boxes;
  for (const Polyline& fibre : fibres) boxes.push_back(boundsOf(fibre));
  for (std::size_t a = 0; a < fibres.size(); ++a)
    for (std::size_t b = a + 1; b < fibres.size(); ++b)
      r.min_pairwise_distance =
          polylineDistance(fibres[a], fibres[b], boxes[a], boxes[b], r.min_pairwise_distance);
  if (fibres.size() < 2) r.min_pairwise_distance = 0;
  if (fibres.size() >= 2 && !(r.min_pairwise_distance > 0)) r.failures.push_back("two fibres touch or cross");

  // Coverage of the seeding cross-section.
  r.cross_section_area = section.area;
  r.section_level = section.level;
  r.section_volume_fraction = section.volume_fraction;
  r.coverage_radius = 1.5 * std::sqrt(section.area / (M_PI * static_cast<double>(fibres.size())));
  double covered = 0;
  for (std::size_t s = 0; s < section.points.size(); ++s) {
    double d_best = kInf;
    for (const Polyline& fibre : fibres)
      for (Eigen::Index i = 0; i + 1 < fibre.cols(); ++i)
        d_best = std::min(d_best, pointSegmentDistance(section.points[s], fibre.col(i), fibre.col(i + 1)));
    r.max_gap = std::max(r.max_gap, d_best);
    if (d_best <= r.coverage_radius) covered += section.areas[s];
  }
  r.coverage = section.area > 0 ? covered / section.area : 0;
  if (r.coverage < r.min_coverage) {
    std::ostringstream msg;
    msg << "fibres cover " << std::fixed << std::setprecision(1) << 100 * r.coverage << " % of the seeding cross-section";
    r.failures.push_back(msg.str());
  }
  return r;
}

}  // namespace

// -----------------------------------------------------------------------------------------------------------------

double windingNumber(const TriangleMesh& surface, const Eigen::Vector3d& p) {
  // Sum of the signed solid angles of the triangles seen from p (Van Oosterom & Strackee), over 4 pi.
  double total = 0;
  for (Eigen::Index t = 0; t < surface.triangleCount(); ++t) {
    const Eigen::Vector3d a = surface.vertices.col(surface.triangles(0, t)) - p;
    const Eigen::Vector3d b = surface.vertices.col(surface.triangles(1, t)) - p;
    const Eigen::Vector3d c = surface.vertices.col(surface.triangles(2, t)) - p;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    const double numerator = a.dot(b.cross(c));
    const double denominator = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
    total += 2.0 * std::atan2(numerator, denominator);
  }
  return std::abs(total / (4.0 * M_PI));
}

std::string FibreCheckReport::describe() const {
  std::ostringstream out;
  out << std::fixed << std::setprecision(1);
  out << fibre_count << " fibres, length " << min_length * 1e3 << "-" << max_length * 1e3 << " mm (mean "
      << mean_length * 1e3 << "); outside by > " << tolerance * 1e3 << " mm: " << points_outside << "/" << points
      << " points (max " << std::setprecision(2) << max_outside_distance * 1e3 << " mm); ends to patches max "
      << max_start_distance * 1e3 << " / " << max_end_distance * 1e3 << " mm; min fibre distance "
      << std::setprecision(1) << min_pairwise_distance * 1e6 << " um; seeding cross-section " << cross_section_area * 1e4
      << " cm^2 (field value " << std::setprecision(2) << section_level << ", " << std::setprecision(0)
      << 100 * section_volume_fraction << " % of the volume from the origin), coverage " << std::setprecision(1)
      << 100 * coverage << " % within " << coverage_radius * 1e3 << " mm, max gap " << max_gap * 1e3 << " mm";
  out << (failures.empty() ? "; checks passed" : "; FAILED:");
  for (const std::string& f : failures) out << " [" << f << "]";
  return out.str();
}

AttachmentPatches findAttachmentPatches(const TriangleMesh& surface, const TriangleMesh* origin_bone,
                                        const TriangleMesh* insertion_bone, const FibreGeneratorOptions& options) {
  validateOptions(options);
  const Eigen::Index n = surface.vertexCount();
  if (n == 0 || !surface.vertices.allFinite()) throw FibreGenerationError("the muscle surface has no (finite) vertices");
  if (origin_bone && origin_bone->triangleCount() == 0) origin_bone = nullptr;
  if (insertion_bone && insertion_bone->triangleCount() == 0) insertion_bone = nullptr;
  AttachmentPatches patches;

  // Principal axis of the vertices: the muscle's long direction; tn = position along it, 0..1.
  const Eigen::Vector3d centroid = surface.vertices.rowwise().mean();
  const Eigen::Matrix3Xd centred = surface.vertices.colwise() - centroid;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> pca(centred * centred.transpose());
  const Eigen::Vector3d axis = pca.eigenvectors().col(2);
  const Eigen::VectorXd t = (axis.transpose() * centred).transpose();
  const double t_min = t.minCoeff(), length = t.maxCoeff() - t_min;
  if (!(length > 0)) throw FibreGenerationError("the muscle surface is degenerate (no extent)");
  const Eigen::VectorXd tn = (t.array() - t_min) / length;
  const auto min_count = static_cast<std::size_t>(std::max(1, options.min_patch_vertices));

  // The two tips: vertices within end_fraction of the length from an end (at least min_count of them).
  auto tip = [&](bool low) {
    std::vector<int> order(static_cast<std::size_t>(n));
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return low ? tn[a] < tn[b] : tn[a] > tn[b]; });
    std::vector<int> out;
    for (int v : order) {
      if ((low ? tn[v] : 1 - tn[v]) > options.end_fraction && out.size() >= min_count) break;
      out.push_back(v);
    }
    return out;
  };
  const std::vector<int> low_tip = tip(true), high_tip = tip(false);

  // Which tip is the origin: the assignment that puts each named bone nearer its own end.
  auto tipDistance = [&](const TriangleMesh& bone, const std::vector<int>& vertices) {
    const SurfaceDistance to_bone(bone.vertices, bone.triangles);
    double best = kInf;
    for (int v : vertices) best = std::min(best, to_bone.distance(surface.vertices.col(v)));
    return best;
  };
  bool origin_low;
  if (!origin_bone && !insertion_bone) {
    origin_low = axis.z() < 0;  // origin = the end with greater Z: proximal in a Z-up anatomical frame
    patches.notes.push_back("no bones: origin = the end of the principal axis with greater Z");
  } else {
    double score = 0;  // > 0: origin at the low end
    if (origin_bone) score += tipDistance(*origin_bone, high_tip) - tipDistance(*origin_bone, low_tip);
    if (insertion_bone) score += tipDistance(*insertion_bone, low_tip) - tipDistance(*insertion_bone, high_tip);
    origin_low = score >= 0;
  }
  // s: position from the origin end (0) to the insertion end (1).
  const Eigen::VectorXd s = origin_low ? tn : Eigen::VectorXd(1.0 - tn.array());

  // Region of the surface nearest a bone: vertices within attachment_distance of the closest approach, which itself
  // must be within max_attachment_gap (registered bones rarely touch a segmented muscle exactly). Vertices inside the
  // bone count as touching it.
  const double cap = options.max_attachment_gap + options.attachment_distance;
  auto distances = [&](const TriangleMesh* bone) {
    std::vector<double> d(static_cast<std::size_t>(n), kInf);
    if (!bone) return d;
    const SurfaceDistance to_bone(bone->vertices, bone->triangles);
    for (Eigen::Index v = 0; v < n; ++v) {
      const Eigen::Vector3d p = surface.vertices.col(v);
      double& dv = d[static_cast<std::size_t>(v)];
      dv = to_bone.distanceWithin(p, cap);
      if (dv <= cap && dv > 0 && windingNumber(*bone, p) > 0.5) dv = 0;
    }
    return d;
  };
  const std::vector<double> d_origin = distances(origin_bone), d_insertion = distances(insertion_bone);
  const double closest_origin = *std::min_element(d_origin.begin(), d_origin.end());
  const double closest_insertion = *std::min_element(d_insertion.begin(), d_insertion.end());
  std::vector<int> origin, insertion;
  for (Eigen::Index v = 0; v < n; ++v) {
    const double a = d_origin[static_cast<std::size_t>(v)], b = d_insertion[static_cast<std::size_t>(v)];
    const bool near_a = closest_origin <= options.max_attachment_gap && a <= closest_origin + options.attachment_distance;
    const bool near_b =
        closest_insertion <= options.max_attachment_gap && b <= closest_insertion + options.attachment_distance;
    if (near_a && (!near_b || a <= b)) {
      origin.push_back(static_cast<int>(v));
    } else if (near_b) {
      insertion.push_back(static_cast<int>(v));
    }
  }
  auto describeBone = [&](const char* role, const TriangleMesh* bone, double closest) {
    if (!bone) return std::string(role) + " bone: none given";
    if (!std::isfinite(closest)) return std::string(role) + " bone: too far (farther than " + mm(cap, 1) + ")";
    if (closest > options.max_attachment_gap) {
      return std::string(role) + " bone: too far (closest approach " + mm(closest, 1) + " > " +
             mm(options.max_attachment_gap, 1) + ")";
    }
    return std::string(role) + " bone: closest approach " + mm(closest, 1);
  };
  patches.notes.push_back(describeBone("origin", origin_bone, closest_origin));
  patches.notes.push_back(describeBone("insertion", insertion_bone, closest_insertion));

  // Keep each bone region on its own side of the muscle: a muscle lying along its origin bone all the way to the
  // insertion touches it there too. Cut at the midpoint of the two regions' mean positions (or mid-length), with a gap.
  auto meanS = [&](const std::vector<int>& vs) {
    double sum = 0;
    for (int v : vs) sum += s[v];
    return sum / static_cast<double>(std::max<std::size_t>(1, vs.size()));
  };
  double split = 0.5;
  if (!origin.empty() && !insertion.empty() && meanS(origin) < meanS(insertion)) {
    split = 0.5 * (meanS(origin) + meanS(insertion));
  }
  const double gap = options.patch_gap_fraction;
  origin.erase(std::remove_if(origin.begin(), origin.end(), [&](int v) { return s[v] >= split - gap; }), origin.end());
  insertion.erase(std::remove_if(insertion.begin(), insertion.end(), [&](int v) { return s[v] <= split + gap; }),
                  insertion.end());

  // A bone region is used if it is big enough and reaches its end of the muscle; otherwise the tip stands in.
  double origin_reach = kInf, insertion_reach = -kInf;
  for (int v : origin) origin_reach = std::min(origin_reach, s[v]);
  for (int v : insertion) insertion_reach = std::max(insertion_reach, s[v]);
  patches.origin_from_bone = origin.size() >= min_count && origin_reach <= options.bone_patch_reach;
  patches.insertion_from_bone = insertion.size() >= min_count && insertion_reach >= 1 - options.bone_patch_reach;
  if (!patches.origin_from_bone) {
    if (!origin.empty()) patches.notes.push_back("origin bone region unusable (too small or away from its end)");
    origin = origin_low ? low_tip : high_tip;
  }
  if (!patches.insertion_from_bone) {
    if (!insertion.empty()) patches.notes.push_back("insertion bone region unusable (too small or away from its end)");
    insertion = origin_low ? high_tip : low_tip;
  }
  // Never share a vertex (tips and bone regions are cut apart above; this is a last guard): the origin keeps it.
  std::vector<char> in_origin(static_cast<std::size_t>(n), 0);
  for (int v : origin) in_origin[static_cast<std::size_t>(v)] = 1;
  insertion.erase(std::remove_if(insertion.begin(), insertion.end(),
                                 [&](int v) { return in_origin[static_cast<std::size_t>(v)] != 0; }),
                  insertion.end());
  if (origin.empty() || insertion.empty()) throw FibreGenerationError("could not find two separate attachment patches");
  std::sort(origin.begin(), origin.end());
  std::sort(insertion.begin(), insertion.end());
  patches.origin_vertices = origin;
  patches.insertion_vertices = insertion;
  return patches;
}

FibreGenerationResult generateFibres(const TriangleMesh& surface, const TriangleMesh* origin_bone,
                                     const TriangleMesh* insertion_bone, const FibreGeneratorOptions& options) {
  requireClosed(surface);
  const AttachmentPatches patches = findAttachmentPatches(surface, origin_bone, insertion_bone, options);
  FibreGenerationResult result = generateFibres(surface, patches, options);
  // Not a failure: the fibres still run end to end along the muscle, but where they start or end is a guess.
  for (const auto& [role, from_bone] : {std::pair{"origin", patches.origin_from_bone},
                                        std::pair{"insertion", patches.insertion_from_bone}}) {
    if (from_bone) continue;
    std::string why;
    for (const std::string& note : patches.notes)
      if (note.rfind(role, 0) == 0) why += (why.empty() ? "" : "; ") + note;
    result.warnings.push_back(std::string("no usable ") + role + " bone region (" + why + "): the " + role +
                              " patch is the muscle's end along its principal axis");
  }
  return result;
}

FibreGenerationResult generateFibres(const TriangleMesh& surface, const AttachmentPatches& patches,
                                     const FibreGeneratorOptions& options) {
  validateOptions(options);
  requireClosed(surface);
  validatePatches(surface, patches);
  FibreGenerationResult result;
  result.patches = patches;
  result.voxel_size = effectiveVoxel(surface, options);
  const Field field = solveField(surface, patches, result.voxel_size, options);
  result.inside_voxels = field.inside;
  result.dropped_voxels = field.dropped;
  result.solver_iterations = field.iterations;
  result.solver_error = field.error;
  if (field.dropped > 0) {
    result.warnings.push_back(std::to_string(field.dropped) +
                              " inside voxels lie in pieces not joining both patches and get no fibres");
  }

  // The preferred cross-section first; the next ones only if it gives fewer fibres than asked for (its seeds' streamlines
  // ran too close together or missed a patch in every reseeding round).
  constexpr std::size_t kSeedSectionAttempts = 3;
  const std::vector<CrossSection> sections = seedingCrossSections(field, options);
  const StreamlineTracer tracer(field, surface, patches, options);
  std::size_t used = 0;
  for (std::size_t attempt = 0; attempt < std::min(sections.size(), kSeedSectionAttempts); ++attempt) {
    TracedFibres traced = tracer.traceFrom(sections[attempt]);
    if (attempt == 0 || traced.fibres.size() > result.fibres.size()) {
      used = attempt;
      result.fibres = std::move(traced.fibres);
      result.failed_seeds = traced.failed_seeds;
      result.merged_fibres = traced.merged_fibres;
      result.reseed_rounds = traced.reseed_rounds;
    }
    if (result.fibres.size() >= static_cast<std::size_t>(options.fibre_count)) break;
  }
  if (used > 0) {
    std::ostringstream note;
    note << std::fixed << std::setprecision(1) << "the largest cross-section (" << sections[0].area * 1e4
         << " cm^2) gave fewer fibres than asked for: seeded on the one of " << sections[used].area * 1e4 << " cm^2";
    result.warnings.push_back(note.str());
  }
  if (result.failed_seeds > 0) {
    result.warnings.push_back(std::to_string(result.failed_seeds - result.merged_fibres) + " seeds missed a patch and " +
                              std::to_string(result.merged_fibres) + " fibres ran too close to another; reseeded " +
                              std::to_string(result.reseed_rounds) + " times");
  }
  if (result.fibres.empty()) throw FibreGenerationError("no streamline joined the two patches");
  result.checks = runChecks(surface, patches, result.fibres, field, sections[used], options);
  return result;
}

FibreCheckReport checkFibres(const TriangleMesh& surface, const AttachmentPatches& patches,
                             const std::vector<Polyline>& fibres, const FibreGeneratorOptions& options) {
  validateOptions(options);
  requireClosed(surface);
  validatePatches(surface, patches);
  for (const Polyline& fibre : fibres) {
    if (fibre.cols() < 2 || !fibre.allFinite()) {
      throw FibreGenerationError("a fibre needs at least two finite points");
    }
  }
  const Field field = solveField(surface, patches, effectiveVoxel(surface, options), options);
  return runChecks(surface, patches, fibres, field, seedingCrossSections(field, options).front(), options);
}

void saveFibresVtk(const std::string& path, const std::vector<Polyline>& fibres, int decimals,
                   const std::vector<std::string>& failed_checks) {
  if (decimals < 1 || decimals > 17) throw std::invalid_argument("saveFibresVtk: decimals must be in 1..17");
  std::size_t points = 0;
  for (std::size_t i = 0; i < fibres.size(); ++i) {
    if (fibres[i].cols() < 2) throw std::runtime_error(path + ": fibre " + std::to_string(i) + " has fewer than 2 points");
    if (!fibres[i].allFinite()) throw std::runtime_error(path + ": fibre " + std::to_string(i) + " has non-finite points");
    points += static_cast<std::size_t>(fibres[i].cols());
  }
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot open for writing: " + std::strerror(errno));
  std::string title = "muscle fibres, origin to insertion (metres)";
  if (!failed_checks.empty()) {
    title += std::string("; ") + kFibreChecksFailedMark;
    for (std::size_t i = 0; i < failed_checks.size(); ++i) title += (i ? "; " : "") + failed_checks[i];
    constexpr std::size_t kLegacyVtkTitleLimit = 255;  // the format's limit; the rest of the list is cut
    std::replace(title.begin(), title.end(), '\n', ' ');
    if (title.size() > kLegacyVtkTitleLimit) title = title.substr(0, kLegacyVtkTitleLimit - 3) + "...";
  }
  out << "# vtk DataFile Version 3.0\n" << title << "\nASCII\nDATASET POLYDATA\n";
  out << "POINTS " << points << " double\n";
  // Fixed decimals with trailing zeros dropped: short, exact to the chosen precision, readable by any VTK reader.
  auto number = [decimals](double value) {
    char buffer[64];
    std::snprintf(buffer, sizeof buffer, "%.*f", decimals, value);
    std::string text = buffer;
    text.erase(text.find_last_not_of('0') + 1);
    if (text.back() == '.') text.pop_back();
    if (text == "-0") text = "0";
    return text;
  };
  for (const Polyline& fibre : fibres) {
    for (Eigen::Index i = 0; i < fibre.cols(); ++i) {
      out << number(fibre(0, i)) << ' ' << number(fibre(1, i)) << ' ' << number(fibre(2, i)) << '\n';
    }
  }
  out << "LINES " << fibres.size() << ' ' << (points + fibres.size()) << '\n';
  std::size_t next = 0;
  for (const Polyline& fibre : fibres) {
    out << fibre.cols();
    for (Eigen::Index i = 0; i < fibre.cols(); ++i) out << ' ' << next++;
    out << '\n';
  }
  out.close();
  if (!out) throw std::runtime_error(path + ": write failed");
}

}  // namespace muscle_deformation
