#include "muscle_deformation/core/model/spring_layout.hpp"

#include "muscle_deformation/core/base/point_index.hpp"

#include <Eigen/Eigenvalues>

extern "C" {
#include <libqhull_r/qhull_ra.h>
}

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <numeric>
#include <stdexcept>
#include <tuple>

namespace muscle_deformation {

std::string toString(SpringLayout layout) {
  switch (layout) {
    case SpringLayout::nearest_neighbours: return "nearest_neighbours";
    case SpringLayout::cubic6: return "cubic6";
    case SpringLayout::cubic26: return "cubic26";
    case SpringLayout::delaunay: return "delaunay";
  }
  return "unknown";
}

SpringLayout springLayoutFromString(const std::string& name) {
  for (SpringLayout layout : {SpringLayout::nearest_neighbours, SpringLayout::cubic6, SpringLayout::cubic26,
                              SpringLayout::delaunay})
    if (toString(layout) == name) return layout;
  throw std::invalid_argument("unknown spring layout '" + name +
                              "' (expected nearest_neighbours, cubic6, cubic26 or delaunay)");
}

namespace {
void sortUnique(ParticlePairs& pairs) {
  for (auto& pair : pairs)
    if (pair.first > pair.second) std::swap(pair.first, pair.second);
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  pairs.erase(std::remove_if(pairs.begin(), pairs.end(), [](const auto& p) { return p.first == p.second; }),
              pairs.end());
}
}  // namespace

ParticlePairs nearestNeighbourPairs(const Eigen::Matrix3Xd& points, int neighbours) {
  if (neighbours < 1) throw std::invalid_argument("nearest-neighbour layout needs at least 1 neighbour");
  ParticlePairs pairs;
  if (points.cols() < 2) return pairs;
  const PointIndex index(points);
  std::vector<std::pair<std::int32_t, double>> found;
  pairs.reserve(static_cast<std::size_t>(points.cols()) * neighbours);
  for (Eigen::Index i = 0; i < points.cols(); ++i) {
    // k + 1 because the particle finds itself first (or a coincident twin, which sortUnique keeps as a real pair).
    index.nearest(points.col(i), neighbours + 1, found);
    int added = 0;
    for (const auto& [j, distance] : found) {
      if (j == i || added == neighbours) continue;
      pairs.emplace_back(static_cast<std::int32_t>(i), j);
      ++added;
    }
  }
  sortUnique(pairs);
  return pairs;
}

ParticlePairs cubicLatticePairs(const Eigen::Matrix3Xd& points, const std::vector<std::int32_t>& fibre_of,
                                const std::vector<std::int32_t>& sample_of, bool with_diagonals) {
  const auto count = static_cast<std::size_t>(points.cols());
  if (fibre_of.size() != count || sample_of.size() != count)
    throw std::invalid_argument("cubic lattice: fibre_of and sample_of must have one entry per particle");
  ParticlePairs pairs;
  if (count == 0) return pairs;

  // Mean position of every fibre: the fibre's place in the muscle cross-section.
  std::map<std::int32_t, std::pair<Eigen::Vector3d, int>> fibre_sum;
  for (std::size_t i = 0; i < count; ++i) {
    auto& entry = fibre_sum.try_emplace(fibre_of[i], Eigen::Vector3d::Zero(), 0).first->second;
    entry.first += points.col(static_cast<Eigen::Index>(i));
    entry.second += 1;
  }
  std::vector<std::int32_t> fibre_ids;
  Eigen::Matrix3Xd centres(3, static_cast<Eigen::Index>(fibre_sum.size()));
  for (const auto& [id, sum] : fibre_sum) {
    centres.col(static_cast<Eigen::Index>(fibre_ids.size())) = sum.first / sum.second;
    fibre_ids.push_back(id);
  }
  const int fibre_count = static_cast<int>(fibre_ids.size());

  // Fibre centres lie roughly in the muscle's mid cross-section, so their two directions of largest spread span it.
  const Eigen::Vector3d mean = centres.rowwise().mean();
  const Eigen::Matrix3Xd centred = centres.colwise() - mean;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(centred * centred.transpose());
  const Eigen::Vector3d plane_x = eigen.eigenvectors().col(2);
  const Eigen::Vector3d plane_y = eigen.eigenvectors().col(1);

  // Rows x columns as square as possible. For a trial grid orientation, fibres are ranked along the row direction
  // into rows, then along the column direction within each row. The orientation whose grid neighbours lie closest
  // together wins: that recovers a grid however it is rotated in the cross-section, and gives the nearest grid
  // assignment for scattered fibres.
  const int columns = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(fibre_count))));
  const int rows = (fibre_count + columns - 1) / columns;
  auto assign = [&](double angle, std::vector<int>& order) {
    const Eigen::Vector3d u = std::cos(angle) * plane_x + std::sin(angle) * plane_y;
    const Eigen::Vector3d v = -std::sin(angle) * plane_x + std::cos(angle) * plane_y;
    order.resize(fibre_count);
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(),
                     [&](int a, int b) { return u.dot(centred.col(a)) < u.dot(centred.col(b)); });
    for (int row = 0; row < rows; ++row) {
      const int begin = row * columns;
      const int end = std::min(fibre_count, begin + columns);
      std::stable_sort(order.begin() + begin, order.begin() + end,
                       [&](int a, int b) { return v.dot(centred.col(a)) < v.dot(centred.col(b)); });
    }
    double neighbour_distance = 0;  // order[row * columns + column] is the fibre in that cell
    for (int k = 0; k < fibre_count; ++k) {
      if (k % columns + 1 < columns && k + 1 < fibre_count)
        neighbour_distance += (centred.col(order[k]) - centred.col(order[k + 1])).norm();
      if (k + columns < fibre_count) neighbour_distance += (centred.col(order[k]) - centred.col(order[k + columns])).norm();
    }
    return neighbour_distance;
  };
  constexpr int kTrialAngles = 180;  // 1 degree apart over half a turn
  std::vector<int> order, best_order;
  double best_cost = std::numeric_limits<double>::infinity();
  for (int trial = 0; trial < kTrialAngles; ++trial) {
    const double cost = assign(M_PI * trial / kTrialAngles, order);
    if (cost < best_cost - 1e-12) {
      best_cost = cost;
      best_order = order;
    }
  }
  std::map<std::int32_t, std::pair<int, int>> cell_of_fibre;
  for (int k = 0; k < fibre_count; ++k) cell_of_fibre[fibre_ids[best_order[k]]] = {k / columns, k % columns};

  // Node (row, column, sample) -> particle index.
  std::map<std::tuple<int, int, int>, std::int32_t> node;
  for (std::size_t i = 0; i < count; ++i) {
    const auto [row, column] = cell_of_fibre[fibre_of[i]];
    node[{row, column, sample_of[i]}] = static_cast<std::int32_t>(i);
  }
  for (const auto& [key, i] : node) {
    const auto [row, column, sample] = key;
    for (int dr = -1; dr <= 1; ++dr)
      for (int dc = -1; dc <= 1; ++dc)
        for (int ds = -1; ds <= 1; ++ds) {
          const int nonzero = (dr != 0) + (dc != 0) + (ds != 0);
          if (nonzero == 0 || (!with_diagonals && nonzero != 1)) continue;
          const auto it = node.find({row + dr, column + dc, sample + ds});
          if (it != node.end() && it->second > i) pairs.emplace_back(i, it->second);
        }
  }
  sortUnique(pairs);
  return pairs;
}

std::vector<Eigen::Vector4i> delaunayTetrahedra(const Eigen::Matrix3Xd& points) {
  const int count = static_cast<int>(points.cols());
  if (count < 5) throw std::runtime_error("Delaunay tetrahedralisation needs at least 5 particles, got " + std::to_string(count));
  std::vector<coordT> coordinates(points.data(), points.data() + 3 * static_cast<std::size_t>(count));

  qhT qh_storage;
  qhT* qh = &qh_storage;
  QHULL_LIB_CHECK
  qh_zero(qh, stderr);
  // "Qz" adds a point at infinity so that the many cospherical points of a fibre grid triangulate cleanly.
  char options[] = "qhull d Qbb Qt Qz";
  // qhull reports problems through its own error stream; keep it quiet and turn the exit code into an exception.
  FILE* quiet = std::fopen("/dev/null", "w");
  const int status = qh_new_qhull(qh, 3, count, coordinates.data(), False, options, nullptr, quiet ? quiet : stderr);
  std::vector<Eigen::Vector4i> tetrahedra;
  if (status == 0) {
    facetT* facet;
    vertexT* vertex;
    vertexT** vertexp;
    FORALLfacets {
      if (facet->upperdelaunay) continue;
      Eigen::Vector4i corner;
      int corners = 0;
      bool finite = true;
      FOREACHvertex_(facet->vertices) {
        const int id = qh_pointid(qh, vertex->point);
        if (id < 0 || id >= count)
          finite = false;  // the Qz point at infinity
        else if (corners < 4)
          corner[corners++] = id;
      }
      if (finite && corners == 4) tetrahedra.push_back(corner);
    }
  }
  qh_freeqhull(qh, !qh_ALL);
  int current_long = 0, total_long = 0;
  qh_memfreeshort(qh, &current_long, &total_long);
  if (quiet) std::fclose(quiet);
  if (status != 0 || tetrahedra.empty())
    throw std::runtime_error("Delaunay tetrahedralisation failed (qhull exit code " + std::to_string(status) +
                             "): the particles may be coplanar or degenerate");
  return tetrahedra;
}

ParticlePairs delaunayPairs(const Eigen::Matrix3Xd& points) {
  ParticlePairs pairs;
  for (const Eigen::Vector4i& tetrahedron : delaunayTetrahedra(points))
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) pairs.emplace_back(tetrahedron[a], tetrahedron[b]);
  sortUnique(pairs);
  return pairs;
}

}  // namespace muscle_deformation
