#include "muscle_deformation/core/model/rigid_pretransform.hpp"

#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/base/median.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

namespace {
// Below these counts a pass is not worth the threads' start (a small analytic model stays on one thread): particles
// or springs, and fibres.
constexpr Eigen::Index kParallelElements = 4096;
constexpr std::int64_t kParallelFibres = 256;

void checkTransforms(const MassSpringSystem& system, const BoneTransforms& transforms) {
  for (Eigen::Index i = 0; i < system.blend_bone.cols(); ++i)
    for (int k = 0; k < MassSpringSystem::kBlendBones; ++k)
      if (system.blend_bone(k, i) >= static_cast<int>(transforms.size()))
        throw std::invalid_argument("bone transforms: " + std::to_string(transforms.size()) +
                                    " given, but the model refers to bone " + std::to_string(system.blend_bone(k, i)));
}
}  // namespace

namespace {
// The weighted mean over the particle's bones of `moved(bone)`, or `unblended` for a particle without bones.
template <class Moved>
Eigen::Vector3d blendOverBones(const MassSpringSystem& system, Eigen::Index particle, const Eigen::Vector3d& unblended,
                              const Moved& moved) {
  Eigen::Vector3d blended = Eigen::Vector3d::Zero();
  double weight_sum = 0;
  for (int k = 0; k < MassSpringSystem::kBlendBones; ++k) {
    const int bone = system.blend_bone(k, particle);
    if (bone == kNoBone) continue;
    blended += system.blend_weight(k, particle) * moved(bone);
    weight_sum += system.blend_weight(k, particle);
  }
  return weight_sum > 0 ? Eigen::Vector3d(blended / weight_sum) : unblended;
}

// Linear blend of the particle's bones' transforms applied to `point`.
Eigen::Vector3d blendedMotion(const MassSpringSystem& system, const BoneTransforms& transforms, Eigen::Index particle,
                              const Eigen::Vector3d& point) {
  return blendOverBones(system, particle, point, [&](int bone) { return Eigen::Vector3d(transforms[bone] * point); });
}
}  // namespace

void rigidPretransform(const MassSpringSystem& system, const BoneTransforms& transforms, ParticleState& state,
                       int threads) {
  checkTransforms(system, transforms);
  const Eigen::Index n = system.particleCount();
  state.position.resize(3, n);
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(static) if (n > kParallelElements)
  for (Eigen::Index i = 0; i < n; ++i) state.position.col(i) = blendedMotion(system, transforms, i, system.rest_position.col(i));
  state.previous_position = state.position;
}

Eigen::Matrix3Xd carryRestVectors(const MassSpringSystem& system, const BoneTransforms& transforms,
                                  const Eigen::Matrix3Xd& rest_vectors, int threads) {
  checkTransforms(system, transforms);
  const Eigen::Index n = system.particleCount();
  if (rest_vectors.cols() != n)
    throw std::invalid_argument("carryRestVectors: " + std::to_string(rest_vectors.cols()) + " vectors for " +
                                std::to_string(n) + " particles");
  Eigen::Matrix3Xd carried(3, n);
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(static) if (n > kParallelElements)
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d vector = rest_vectors.col(i);
    carried.col(i) = blendOverBones(system, i, vector,
                                    [&](int bone) { return Eigen::Vector3d(transforms[bone].linear() * vector); });
  }
  return carried;
}

void warmStart(const MassSpringSystem& system, const BoneTransforms& previous_transforms,
               const BoneTransforms& transforms, ParticleState& state, int threads) {
  checkTransforms(system, transforms);
  checkTransforms(system, previous_transforms);
  if (state.position.cols() != system.particleCount())
    throw std::invalid_argument("warm start: previous state has " + std::to_string(state.position.cols()) +
                                " particles, the model " + std::to_string(system.particleCount()));
  BoneTransforms motion(transforms.size());
  for (std::size_t b = 0; b < transforms.size(); ++b) motion[b] = transforms[b] * previous_transforms[b].inverse();
  const Eigen::Index n = system.particleCount();
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(static) if (n > kParallelElements)
  for (Eigen::Index i = 0; i < n; ++i) {
    if (system.is_fixed[i] && system.fixed_bone[i] != kNoBone)
      state.position.col(i) = transforms[system.fixed_bone[i]] * system.rest_position.col(i);
    else if (!system.is_fixed[i])
      state.position.col(i) = blendedMotion(system, motion, i, state.position.col(i));
  }
  state.previous_position = state.position;
}

void moveAttachments(const MassSpringSystem& system, const BoneTransforms& transforms, ParticleState& state) {
  checkTransforms(system, transforms);
  if (state.position.cols() != system.particleCount())
    throw std::invalid_argument("warm start: previous state has " + std::to_string(state.position.cols()) +
                                " particles, the model " + std::to_string(system.particleCount()));
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (!system.is_fixed[i] || system.fixed_bone[i] == kNoBone) continue;
    state.position.col(i) = transforms[system.fixed_bone[i]] * system.rest_position.col(i);
    state.previous_position.col(i) = state.position.col(i);
  }
}

namespace {
// A point given at rest on `bone`, where the pose puts it (at rest for no bone, or a pose without that bone).
Eigen::Vector3d placed(int bone, const Eigen::Vector3d& rest, const BoneTransforms& transforms) {
  return bone != kNoBone && bone < static_cast<int>(transforms.size()) ? Eigen::Vector3d(transforms[bone] * rest) : rest;
}
}  // namespace

double tendonPathBeyondAnchor(const MassSpringSystem& system, const TendonPath& tendon, const BoneTransforms& transforms) {
  Eigen::Vector3d previous = placed(system.fixed_bone[static_cast<std::size_t>(tendon.anchor)],
                                    system.rest_position.col(tendon.anchor), transforms);
  double length = 0;
  for (std::size_t k = 0; k < tendon.bones.size(); ++k) {
    const Eigen::Vector3d next = placed(tendon.bones[k], tendon.points.col(static_cast<Eigen::Index>(k)), transforms);
    length += (next - previous).norm();
    previous = next;
  }
  return length;
}

bool updateTendonRestLengths(MassSpringSystem& system, const BoneTransforms& transforms) {
  bool changed = false;
  for (const TendonPath& tendon : system.tendon_paths) {
    const double rest =
        std::max(kMinTendonRestLengthM, tendon.length_m - tendonPathBeyondAnchor(system, tendon, transforms));
    double& current = system.springs.rest_length[tendon.spring];
    if (rest != current) {
      current = rest;
      changed = true;
    }
  }
  return changed;
}

double fibreSpanLength(const MassSpringSystem& system, const BellyTone& tone, const FibreSpan& span,
                       const BoneTransforms& transforms) {
  const auto anchorAt = [&](std::int32_t anchor) {
    return placed(system.fixed_bone[static_cast<std::size_t>(anchor)], system.rest_position.col(anchor), transforms);
  };
  double length = 0;
  Eigen::Vector3d previous = anchorAt(span.first_anchor);
  if (span.muscle >= 0 && static_cast<std::size_t>(span.muscle) < tone.belly_paths.size()) {
    const BellyPath& path = tone.belly_paths[static_cast<std::size_t>(span.muscle)];
    for (std::size_t k = 0; k < path.bones.size(); ++k) {
      const Eigen::Vector3d next = placed(path.bones[k], path.points.col(static_cast<Eigen::Index>(k)), transforms);
      length += (next - previous).norm();
      previous = next;
    }
  }
  length += (anchorAt(span.last_anchor) - previous).norm();
  for (const std::int32_t path : {span.first_path, span.last_path})
    if (path >= 0) length += tendonPathBeyondAnchor(system, system.tendon_paths[static_cast<std::size_t>(path)], transforms);
  return length;
}

double fibreToneFactor(const BellyTone& tone, const FibreSpan& span, double span_change_m, bool* limited) {
  if (limited) *limited = false;
  if (!(span.belly_length_m > 0)) return 1.0;
  const double asked = tone.gain * span_change_m / span.belly_length_m;
  const double held = std::clamp(asked, -kMaxToneChange, kMaxToneChange);
  if (limited) *limited = held != asked;
  return 1.0 + held;
}

bool updateBellyTone(MassSpringSystem& system, const BoneTransforms& transforms, int threads) {
  BellyTone& tone = system.belly_tone;
  if (tone.empty()) return false;
  std::vector<double>& factor = tone.factor;
  factor.assign(tone.fibres.size(), 1.0);
  const auto fibres = static_cast<std::int64_t>(tone.fibres.size());
  threads = std::max(1, threads);
#pragma omp parallel for num_threads(threads) schedule(static) if (fibres > kParallelFibres)
  for (std::int64_t f = 0; f < fibres; ++f) {
    const FibreSpan& span = tone.fibres[static_cast<std::size_t>(f)];
    if (span.first_anchor < 0) continue;
    factor[static_cast<std::size_t>(f)] =
        fibreToneFactor(tone, span, fibreSpanLength(system, tone, span, transforms) - span.rest_span_m);
  }
  bool changed = false;
  const auto springs = static_cast<std::int64_t>(tone.first_fibre.size());
#pragma omp parallel for num_threads(threads) schedule(static) reduction(|| : changed) if (springs > kParallelElements)
  for (std::int64_t s = 0; s < springs; ++s) {
    const std::int32_t a = tone.first_fibre[static_cast<std::size_t>(s)], b = tone.second_fibre[static_cast<std::size_t>(s)];
    if (a < 0 || b < 0) continue;
    const auto e = static_cast<Eigen::Index>(s);
    const double f = 0.5 * (factor[static_cast<std::size_t>(a)] + factor[static_cast<std::size_t>(b)]);
    const double rest = tone.untoned_rest_length[e] * (1.0 + tone.alignment_squared[e] * (f - 1.0));
    if (rest != system.springs.rest_length[e]) {
      system.springs.rest_length[e] = rest;
      changed = true;
    }
  }
  return changed;
}

std::vector<double> fibreArcLengths(const MassSpringSystem& system, const Eigen::Matrix3Xd& positions) {
  std::vector<double> arcs;
  forEachFibre(system, [&](Eigen::Index begin, Eigen::Index count) {
    arcs.push_back(polylineLength(positions.middleCols(begin, count)));
  });
  return arcs;
}

void stretchWithTone(const MassSpringSystem& system, const Eigen::VectorXd& stiffness_sum,
                     const std::vector<double>& previous_factor, const std::vector<double>& previous_arcs,
                     Eigen::Matrix3Xd& carried) {
  const BellyTone& tone = system.belly_tone;
  if (tone.empty() || tone.factor.size() != tone.fibres.size()) return;
  if (previous_arcs.size() != tone.fibres.size() || carried.cols() != system.particleCount() ||
      stiffness_sum.size() != system.particleCount())
    throw std::invalid_argument("stretchWithTone: " + std::to_string(previous_arcs.size()) + " arc lengths for " +
                                std::to_string(tone.fibres.size()) + " fibres, " + std::to_string(carried.cols()) +
                                " positions and " + std::to_string(stiffness_sum.size()) + " stiffness sums for " +
                                std::to_string(system.particleCount()) + " particles");
  if (!previous_factor.empty() && previous_factor.size() != tone.fibres.size())
    throw std::invalid_argument("stretchWithTone: " + std::to_string(previous_factor.size()) + " tone factors for " +
                                std::to_string(tone.fibres.size()) + " fibres");
  std::size_t fibre = 0;
  std::vector<double> arc, stiffness;
  forEachFibre(system, [&](Eigen::Index begin, Eigen::Index count) {
    const std::size_t f = fibre++;
    if (count < 3) return;
    const double tone_ratio = tone.factor[f] / (previous_factor.empty() ? 1.0 : previous_factor[f]);
    if (tone_ratio == 1.0) return;
    arc.assign(static_cast<std::size_t>(count), 0.0);
    for (Eigen::Index k = 1; k < count; ++k)
      arc[k] = arc[k - 1] + (carried.col(begin + k) - carried.col(begin + k - 1)).norm();
    const double length = arc.back();
    if (!(length > 0)) return;
    // What the bones' carrying already stretched is not added again, and the stretch never goes against the tone's
    // change: a fibre the carrying distorted (a blend of two bones across a joint) is left to its springs. (Aiming at
    // previous_arcs x tone_ratio whatever the carrying did made a fibre that crossed the knee run away frame by frame.)
    // At most kMaxToneStretchPerFrame a frame.
    const double ratio = std::clamp(std::clamp(previous_arcs[f] * tone_ratio / length, std::min(1.0, tone_ratio),
                                               std::max(1.0, tone_ratio)),
                                    1.0 - kMaxToneStretchPerFrame, 1.0 + kMaxToneStretchPerFrame);
    if (ratio == 1.0) return;
    // About the fibre's fixed particles: the part before its first fixed particle stretches about that one, the part
    // after its last about that one, the part between them not at all (its springs take the tone). Without one, about
    // the mean of its particles' positions along it weighted by their springs' stiffness (the drag's weights: the
    // centre that asks the least of the drag).
    Eigen::Index first_fixed = count, last_fixed = -1;
    double weighted_arc = 0, weight = 0;
    stiffness.clear();
    for (Eigen::Index k = 0; k < count; ++k) {
      if (system.is_fixed[static_cast<std::size_t>(begin + k)]) {
        first_fixed = std::min(first_fixed, k);
        last_fixed = k;
        continue;
      }
      stiffness.push_back(stiffness_sum[begin + k]);
      weighted_arc += stiffness_sum[begin + k] * arc[static_cast<std::size_t>(k)];
      weight += stiffness_sum[begin + k];
    }
    if (!(weight > 0)) return;
    // A particle stiffer than the fibre's median particle moves less by that ratio, so that the drag (weighted by the
    // same stiffness) pulls it no harder than the median one: a short tendon's end (its stiffness grows as its length
    // shrinks) moved with the rest held a stream at one sweep a frame at a residual of 11-16 instead of 0.02 (hundreds
    // of newtons on the particle); a tendon's end moved with the fibre while its tendon held it back let its neighbour
    // fold past it (semitendinosus, a fibre 1.8x as tortuous as at rest).
    const double typical = upperMedian(stiffness);
    const Eigen::Matrix3Xd fibre_before = carried.middleCols(begin, count);
    for (Eigen::Index k = 0; k < count; ++k) {
      if (system.is_fixed[static_cast<std::size_t>(begin + k)]) continue;
      double centre = weighted_arc / weight;
      if (last_fixed >= 0) {
        if (k > first_fixed && k < last_fixed) continue;
        centre = arc[static_cast<std::size_t>(k < first_fixed ? first_fixed : last_fixed)];
      }
      const Eigen::Vector3d along =
          fibre_before.col(std::min<Eigen::Index>(k + 1, count - 1)) - fibre_before.col(std::max<Eigen::Index>(k - 1, 0));
      const double norm = along.norm();
      const double held = std::min(1.0, typical / stiffness_sum[begin + k]);
      if (norm > 0)
        carried.col(begin + k) += held * (ratio - 1.0) * (arc[static_cast<std::size_t>(k)] - centre) / norm * along;
    }
  });
}

ParticleState restState(const MassSpringSystem& system) {
  ParticleState state;
  state.position = system.rest_position;
  state.previous_position = system.rest_position;
  return state;
}

}  // namespace muscle_deformation
