// Fibre generation, the field step: voxelisation, the harmonic (Laplace) field solve, cross-sections of the field.
#include "fibre_field.hpp"

#include "muscle_deformation/core/base/point_index.hpp"

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/Sparse>

#include <algorithm>
#include <sstream>
#include <utility>

namespace muscle_deformation::fibre_steps {

namespace {

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

}  // namespace

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

namespace {

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

}  // namespace

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

}  // namespace muscle_deformation::fibre_steps
