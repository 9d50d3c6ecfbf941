// Spring layouts the seeds compare (thesis 5.1, GRAPP 3.2): which particle pairs of one muscle get a spring.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace muscle_deformation {

enum class SpringLayout {
  nearest_neighbours,  // each particle joined to its N closest particles (thesis recommends N = 15..20)
  cubic6,              // template grid fibre row x fibre column x sample, edges only
  cubic26,             // the same grid with face and space diagonals
  delaunay,            // edges of a Delaunay tetrahedralisation of the particles (qhull)
};

std::string toString(SpringLayout layout);
// Accepts "nearest_neighbours", "cubic6", "cubic26", "delaunay"; throws std::invalid_argument otherwise.
SpringLayout springLayoutFromString(const std::string& name);

using ParticlePairs = std::vector<std::pair<std::int32_t, std::int32_t>>;  // first < second, sorted, unique

// Pairs among `points` (indices local to this point set).
ParticlePairs nearestNeighbourPairs(const Eigen::Matrix3Xd& points, int neighbours);

// Grid layouts. Particle i sits on fibre fibre_of[i] at sample sample_of[i]. Fibres are placed on a rows x columns
// template grid by their mean positions (principal axes of the cross-section, then rank order), which is exact when
// the fibres come from a grid. Neighbouring grid nodes (6- or 26-neighbourhood) that both exist get a spring.
ParticlePairs cubicLatticePairs(const Eigen::Matrix3Xd& points, const std::vector<std::int32_t>& fibre_of,
                                const std::vector<std::int32_t>& sample_of, bool with_diagonals);

// Delaunay tetrahedralisation of the points (qhull "d Qbb Qt Qz"), each tetrahedron as four point indices. Throws
// std::runtime_error if qhull fails (e.g. fewer than 5 points or all coplanar).
std::vector<Eigen::Vector4i> delaunayTetrahedra(const Eigen::Matrix3Xd& points);

// Edges of that tetrahedralisation.
ParticlePairs delaunayPairs(const Eigen::Matrix3Xd& points);

}  // namespace muscle_deformation
