#include "muscle_deformation/core/model/fibre_sampling.hpp"

#include <random>
#include <stdexcept>

namespace muscle_deformation {

Eigen::Vector3d pointAtArcLength(const Polyline& line, double s) {
  if (line.cols() == 0) throw std::invalid_argument("pointAtArcLength: empty polyline");
  double travelled = 0;
  for (Eigen::Index i = 0; i + 1 < line.cols(); ++i) {
    const double segment = (line.col(i + 1) - line.col(i)).norm();
    if (segment > 0 && s <= travelled + segment) {
      const double t = std::max(0.0, (s - travelled) / segment);
      return line.col(i) + t * (line.col(i + 1) - line.col(i));
    }
    travelled += segment;
  }
  return line.col(line.cols() - 1);
}

FibreSamples sampleFibres(const std::vector<Polyline>& fibres, int particles_per_fibre, std::uint32_t seed,
                          double min_fibre_length_m) {
  if (particles_per_fibre < 2)
    throw std::invalid_argument("particles per fibre must be at least 2 (got " + std::to_string(particles_per_fibre) +
                                ")");
  FibreSamples samples;
  std::vector<int> usable;
  for (int f = 0; f < static_cast<int>(fibres.size()); ++f) {
    if (fibres[f].cols() >= 2 && fibres[f].allFinite() && polylineLength(fibres[f]) >= min_fibre_length_m)
      usable.push_back(f);
    else
      samples.skipped_fibres.push_back(f);
  }
  const Eigen::Index total = static_cast<Eigen::Index>(usable.size()) * particles_per_fibre;
  samples.position.resize(3, total);
  samples.fibre_of.reserve(total);
  samples.sample_of.reserve(total);

  std::mt19937 generator(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Eigen::Index next = 0;
  for (int f : usable) {
    const Polyline& fibre = fibres[f];
    const double interval = polylineLength(fibre) / (particles_per_fibre - 1);
    for (int i = 0; i < particles_per_fibre; ++i) {
      const double s = i == 0 ? 0.0 : (i - 1 + unit(generator)) * interval;
      samples.position.col(next++) = pointAtArcLength(fibre, s);
      samples.fibre_of.push_back(f);
      samples.sample_of.push_back(i);
    }
  }
  return samples;
}

}  // namespace muscle_deformation
