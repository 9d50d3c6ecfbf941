#include "muscle_deformation/core/model/mass_spring_system.hpp"

#include "muscle_deformation/core/base/median.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace muscle_deformation {

std::size_t MassSpringSystem::modelBytes() const {
  const auto particles = static_cast<std::size_t>(particleCount());
  const std::size_t per_particle = sizeof(double) * (3 /*rest*/ + 1 /*mass*/ + 1 /*radius*/) + 2 /*flags*/ +
                                   4 * sizeof(std::int32_t) + kBlendBones * (sizeof(std::int32_t) + sizeof(double));
  const std::size_t per_spring = 2 * sizeof(std::int32_t) + 2 * sizeof(double);
  return per_particle * particles + per_spring * springs.size();
}

Eigen::VectorXd springStiffnessSums(const MassSpringSystem& system) {
  Eigen::VectorXd sums = Eigen::VectorXd::Zero(system.particleCount());
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const double k = system.springs.stiffness[static_cast<Eigen::Index>(s)];
    sums[system.springs.first[s]] += k;
    sums[system.springs.second[s]] += k;
  }
  return sums;
}

double MassSpringSystem::medianCollisionRadius() const {
  std::vector<double> radii;
  for (Eigen::Index i = 0; i < radius.size(); ++i)
    if (radius[i] > 0) radii.push_back(radius[i]);
  return radii.empty() ? 0.0 : upperMedian(std::move(radii));
}

namespace {
// Per point of the polyline, whether it turns back there (the segments before and after it more than 90 degrees
// apart); false at the ends.
std::vector<bool> turnsBack(const Eigen::Ref<const Eigen::Matrix3Xd>& fibre) {
  std::vector<bool> back(static_cast<std::size_t>(fibre.cols()), false);
  for (Eigen::Index i = 1; i + 1 < fibre.cols(); ++i)
    back[static_cast<std::size_t>(i)] = (fibre.col(i) - fibre.col(i - 1)).dot(fibre.col(i + 1) - fibre.col(i)) < 0;
  return back;
}

double tortuosity(const Eigen::Ref<const Eigen::Matrix3Xd>& fibre) {
  double arc = 0;
  for (Eigen::Index i = 1; i < fibre.cols(); ++i) arc += (fibre.col(i) - fibre.col(i - 1)).norm();
  const double chord = (fibre.col(fibre.cols() - 1) - fibre.col(0)).norm();
  return chord > 0 ? arc / chord : std::numeric_limits<double>::infinity();
}
}  // namespace

BellyTone buildBellyTone(const MassSpringSystem& system, const std::vector<double>& alignment, double gain,
                         std::vector<BellyPath> belly_paths) {
  BellyTone tone;
  if (!(gain > 0)) return tone;
  tone.gain = gain;
  if (!belly_paths.empty() && belly_paths.size() != static_cast<std::size_t>(system.muscleCount()))
    throw std::invalid_argument("belly tone: " + std::to_string(belly_paths.size()) + " belly paths for " +
                                std::to_string(system.muscleCount()) + " muscles");
  tone.belly_paths = std::move(belly_paths);
  const std::size_t n = static_cast<std::size_t>(system.particleCount());
  std::vector<std::int32_t> fibre_of_particle(n, -1);
  // A fibre end's tendon: the spring joining it to an anchor (a particle of no fibre), and that spring's path.
  std::vector<std::int32_t> anchor_of(n, -1);
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const std::int32_t a = system.springs.first[s], b = system.springs.second[s];
    const bool a_anchor = system.fibre_of[static_cast<std::size_t>(a)] == kTendonAnchor;
    const bool b_anchor = system.fibre_of[static_cast<std::size_t>(b)] == kTendonAnchor;
    if (a_anchor != b_anchor) anchor_of[static_cast<std::size_t>(a_anchor ? b : a)] = a_anchor ? a : b;
  }
  std::vector<std::int32_t> path_of_anchor(n, -1);
  for (std::size_t t = 0; t < system.tendon_paths.size(); ++t)
    path_of_anchor[static_cast<std::size_t>(system.tendon_paths[t].anchor)] = static_cast<std::int32_t>(t);
  forEachFibre(system, [&](Eigen::Index begin, Eigen::Index count) {
    const auto fibre = static_cast<std::int32_t>(tone.fibres.size());
    FibreSpan span;
    const auto anchorOf = [&](Eigen::Index end) -> std::int32_t {
      if (system.is_fixed[static_cast<std::size_t>(end)]) return static_cast<std::int32_t>(end);
      return anchor_of[static_cast<std::size_t>(end)];
    };
    span.first_anchor = anchorOf(begin);
    span.last_anchor = anchorOf(begin + count - 1);
    for (Eigen::Index i = begin; i < begin + count; ++i) {
      fibre_of_particle[static_cast<std::size_t>(i)] = fibre;
      if (i > begin) span.belly_length_m += (system.rest_position.col(i) - system.rest_position.col(i - 1)).norm();
    }
    if (span.first_anchor >= 0 && span.last_anchor >= 0 && span.first_anchor != span.last_anchor) {
      span.first_path = path_of_anchor[static_cast<std::size_t>(span.first_anchor)];
      span.last_path = path_of_anchor[static_cast<std::size_t>(span.last_anchor)];
      span.muscle = system.muscle_of[static_cast<std::size_t>(begin)];
      span.rest_span_m = fibreSpanLength(system, tone, span, {});
    } else {
      span.first_anchor = span.last_anchor = -1;  // not attached at both ends: no span to follow
    }
    tone.fibres.push_back(span);
  });
  const std::size_t springs = system.springs.size();
  tone.first_fibre.assign(springs, -1);
  tone.second_fibre.assign(springs, -1);
  tone.alignment_squared.setZero(static_cast<Eigen::Index>(springs));
  tone.untoned_rest_length = system.springs.rest_length;
  for (std::size_t s = 0; s < springs; ++s) {
    if (s >= alignment.size() || std::isnan(alignment[s])) continue;
    tone.first_fibre[s] = fibre_of_particle[static_cast<std::size_t>(system.springs.first[s])];
    tone.second_fibre[s] = fibre_of_particle[static_cast<std::size_t>(system.springs.second[s])];
    tone.alignment_squared[static_cast<Eigen::Index>(s)] = alignment[s] * alignment[s];
  }
  return tone;
}

std::vector<Eigen::Matrix3Xd> fibrePolylines(const MassSpringSystem& system, const Eigen::Matrix3Xd& position) {
  std::vector<Eigen::Matrix3Xd> fibres;
  forEachFibre(system, [&](Eigen::Index begin, Eigen::Index count) { fibres.push_back(position.middleCols(begin, count)); });
  return fibres;
}

FibreFolding measureFibreFolding(const MassSpringSystem& system, const Eigen::Matrix3Xd& position) {
  FibreFolding folding;
  if (position.cols() != system.particleCount()) return folding;
  std::vector<int> folded_per_muscle(static_cast<std::size_t>(system.muscleCount()), 0);
  forEachFibre(system, [&](Eigen::Index begin, Eigen::Index count) {
    if (count < 2) return;
    const auto fibre = position.middleCols(begin, count);
    const auto at_rest = system.rest_position.middleCols(begin, count);
    const int muscle = system.muscle_of[static_cast<std::size_t>(begin)];
    ++folding.fibres;
    const double ratio = tortuosity(fibre) / tortuosity(at_rest);
    if (std::isnan(folding.worst_tortuosity_ratio) || ratio > folding.worst_tortuosity_ratio) {
      folding.worst_tortuosity_ratio = ratio;
      folding.worst_muscle = muscle;
    }
    const std::vector<bool> back = turnsBack(fibre), back_at_rest = turnsBack(at_rest);
    for (std::size_t k = 0; k < back.size(); ++k)
      if (back[k] && !back_at_rest[k]) {
        ++folding.folded_fibres;
        ++folded_per_muscle[static_cast<std::size_t>(muscle)];
        return;
      }
  });
  const auto most = std::max_element(folded_per_muscle.begin(), folded_per_muscle.end());
  if (most != folded_per_muscle.end() && *most > 0) folding.most_folded_muscle = static_cast<int>(most - folded_per_muscle.begin());
  return folding;
}

Eigen::Matrix3Xd fibreDirections(const MassSpringSystem& system, const Eigen::Matrix3Xd& position) {
  // Particles of one fibre are stored consecutively, in order from the fibre start (as fibrePolylines reads them).
  const Eigen::Index n = system.particleCount();
  const auto same_fibre = [&](Eigen::Index i, Eigen::Index j) {
    return j >= 0 && j < n && system.fibre_of[static_cast<std::size_t>(i)] == system.fibre_of[static_cast<std::size_t>(j)] &&
           system.muscle_of[static_cast<std::size_t>(i)] == system.muscle_of[static_cast<std::size_t>(j)];
  };
  Eigen::Matrix3Xd direction = Eigen::Matrix3Xd::Zero(3, n);
  // A system without fibre labels (hand-built) has no fibre direction anywhere.
  if (system.fibre_of.size() != static_cast<std::size_t>(n) || system.muscle_of.size() != static_cast<std::size_t>(n) ||
      position.cols() != n)
    return direction;
  for (Eigen::Index i = 0; i < n; ++i) {
    if (system.fibre_of[static_cast<std::size_t>(i)] == kTendonAnchor) continue;
    const Eigen::Index next = same_fibre(i, i + 1) ? i + 1 : i, previous = same_fibre(i, i - 1) ? i - 1 : i;
    const Eigen::Vector3d along = position.col(next) - position.col(previous);
    const double length = along.norm();
    if (length > 0) direction.col(i) = along / length;
  }
  return direction;
}

Eigen::Matrix3Xd restBalanceForces(const MassSpringSystem& system) {
  const Eigen::Index n = system.particleCount();
  Eigen::Matrix3Xd balance = Eigen::Matrix3Xd::Zero(3, n);
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const std::int32_t a = system.springs.first[s], b = system.springs.second[s];
    const Eigen::Vector3d d = system.rest_position.col(b) - system.rest_position.col(a);
    const double length = d.norm();
    if (!(length > 0)) continue;
    const auto e = static_cast<Eigen::Index>(s);
    // The spring pulls a towards b with k (l - l0); the balance is the opposite.
    const Eigen::Vector3d pull = system.springs.stiffness[e] * (length - system.springs.rest_length[e]) / length * d;
    balance.col(a) -= pull;
    balance.col(b) += pull;
  }
  for (Eigen::Index i = 0; i < n; ++i)
    if (system.is_fixed[static_cast<std::size_t>(i)]) balance.col(i).setZero();
  return balance;
}

}  // namespace muscle_deformation
