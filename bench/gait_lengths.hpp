// Muscle lengths over the gait against gait2392, the field's reference for the bundled skeleton, as the benchmarks
// that judge the model's anatomy measure them.
//
// The product's length of a muscle in a frame is the mean over its fibres of the fibre's belly length (the polyline of
// its particles, as ~fibres shows it) and of its belly + tendon length (plus, at each end that hangs from its bone by a
// tendon, the tendon from the fibre end over its path to the site). The reference is the musculotendon length of the
// muscle's gait2392 counterpart(s) (the scene's `reference_muscles`, their mean), computed from the .osim the scene
// names (`reference_model`, scaled by its `body_scales` to the scene's skeleton) at the trial's joint angles (the .mot
// the 1-cycle bag was made from).
#pragma once

#include "worst_folding.hpp"

#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/scene/motion_file.hpp"
#include "muscle_deformation/core/scene/opensim_model.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace bench {

// Per muscle and frame (m): the mean belly length of its fibres and the mean belly + tendon length; and the length
// the belly's tone aims at (`spanned`): the mean, over the fibres attached at both ends, of the fibre's rest belly
// length plus its attachment span's change (anchors carried by their bones, through the muscle's belly path, tendon
// paths beyond them: fibreSpanLength), the whole
// change and without the tone's limit (empty when the tone is off). It tells a miss of the attachments and paths
// (the span itself does not follow gait2392) from a miss inside the model (the span does, the belly does not).
struct MuscleLengths {
  std::vector<std::vector<double>> belly, whole, spanned;  // [muscle][frame]
  // What the tone sets (`toned`): the same mean with each fibre's change held to the tone's limit (kMaxToneChange), the
  // rest lengths the belly's springs are given along the fibres; where it falls short of `spanned`, the limit binds.
  std::vector<std::vector<double>> toned;  // [muscle][frame]
  // Per muscle: fibre-frames whose tone met its limit, of those counted; the fibres' mean rest belly length (m).
  std::vector<long> tone_limited, tone_counted;
  std::vector<double> rest_belly_m;
  // Whether the fibres kept their line (an arc length measures a muscle's length only then), the worst frame.
  WorstFolding folding;
};

// Appends the lengths of the pipeline's current state as one more frame.
inline void addLengthsOf(const muscle_deformation::DeformationPipeline& pipeline, MuscleLengths& lengths) {
  using namespace muscle_deformation;
  const MassSpringSystem& system = pipeline.system();
  const Eigen::Matrix3Xd& x = pipeline.state().position;
  const int muscles = system.muscleCount();
  lengths.folding.measure(system, x);
  if (lengths.belly.empty()) {
    lengths.belly.resize(static_cast<std::size_t>(muscles));
    lengths.whole.resize(static_cast<std::size_t>(muscles));
    lengths.spanned.resize(static_cast<std::size_t>(muscles));
    lengths.toned.resize(static_cast<std::size_t>(muscles));
    lengths.tone_limited.assign(static_cast<std::size_t>(muscles), 0);
    lengths.tone_counted.assign(static_cast<std::size_t>(muscles), 0);
    lengths.rest_belly_m.assign(static_cast<std::size_t>(muscles), std::nan(""));
  }
  if (!system.belly_tone.empty()) {
    const BellyTone& tone = system.belly_tone;
    std::vector<double> sum(static_cast<std::size_t>(muscles), 0.0), toned(sum.size(), 0.0), rest(sum.size(), 0.0);
    std::vector<int> count(static_cast<std::size_t>(muscles), 0);
    for (const FibreSpan& span : tone.fibres) {
      if (span.first_anchor < 0 || !(span.belly_length_m > 0)) continue;
      const auto m = static_cast<std::size_t>(span.muscle);
      const double change = fibreSpanLength(system, tone, span, pipeline.boneTransforms()) - span.rest_span_m;
      sum[m] += span.belly_length_m + change;
      bool limited = false;
      toned[m] += span.belly_length_m * fibreToneFactor(tone, span, change, &limited);
      rest[m] += span.belly_length_m;
      lengths.tone_limited[m] += limited;
      ++lengths.tone_counted[m];
      ++count[m];
    }
    for (std::size_t m = 0; m < sum.size(); ++m) {
      if (count[m] == 0) continue;
      lengths.spanned[m].push_back(sum[m] / count[m]);
      lengths.toned[m].push_back(toned[m] / count[m]);
      lengths.rest_belly_m[m] = rest[m] / count[m];
    }
  }
  // Tendon length beyond each anchor (via points to the site), by anchor particle.
  std::vector<double> beyond(static_cast<std::size_t>(system.particleCount()), 0.0);
  for (const TendonPath& tendon : system.tendon_paths)
    beyond[static_cast<std::size_t>(tendon.anchor)] = tendonPathBeyondAnchor(system, tendon, pipeline.boneTransforms());
  // The particle each tendon anchor's spring joins it to (the first spring naming it), by anchor particle.
  std::vector<std::int32_t> tendon_partner(static_cast<std::size_t>(system.particleCount()), -1);
  for (std::size_t s = system.springs.size(); s-- > 0;) {
    const std::int32_t a = system.springs.first[s], b = system.springs.second[s];
    if (system.fibre_of[static_cast<std::size_t>(a)] == kTendonAnchor) tendon_partner[static_cast<std::size_t>(a)] = b;
    if (system.fibre_of[static_cast<std::size_t>(b)] == kTendonAnchor) tendon_partner[static_cast<std::size_t>(b)] = a;
  }
  for (int m = 0; m < muscles; ++m) {
    const std::int32_t begin = system.muscle_begin[static_cast<std::size_t>(m)];
    const std::int32_t end = system.muscle_begin[static_cast<std::size_t>(m) + 1];
    std::vector<double> belly, tendon;
    for (std::int32_t i = begin; i < end; ++i) {
      const std::size_t p = static_cast<std::size_t>(i);
      const int fibre = system.fibre_of[p];
      if (fibre == kTendonAnchor) {
        // sample_of of an anchor is the fibre it ends; its spring joins it to that fibre's end particle.
        const std::size_t f = static_cast<std::size_t>(system.sample_of[p]);
        if (tendon.size() <= f) tendon.resize(f + 1, 0.0);
        const std::int32_t other = tendon_partner[p];
        tendon[f] += (other >= 0 ? (x.col(other) - x.col(i)).norm() : 0.0) + beyond[p];
        continue;
      }
      if (belly.size() <= static_cast<std::size_t>(fibre)) belly.resize(static_cast<std::size_t>(fibre) + 1, 0.0);
      if (i + 1 < end && system.fibre_of[p + 1] == fibre) belly[static_cast<std::size_t>(fibre)] += (x.col(i + 1) - x.col(i)).norm();
    }
    tendon.resize(belly.size(), 0.0);
    double belly_mean = 0, whole_mean = 0;
    for (std::size_t f = 0; f < belly.size(); ++f) {
      belly_mean += belly[f] / static_cast<double>(belly.size());
      whole_mean += (belly[f] + tendon[f]) / static_cast<double>(belly.size());
    }
    lengths.belly[static_cast<std::size_t>(m)].push_back(belly_mean);
    lengths.whole[static_cast<std::size_t>(m)].push_back(whole_mean);
  }
}

// Pearson's r of two series of the same length; NaN when either is constant.
inline double correlation(const std::vector<double>& a, const std::vector<double>& b) {
  const Eigen::Map<const Eigen::VectorXd> x(a.data(), static_cast<Eigen::Index>(a.size()));
  const Eigen::Map<const Eigen::VectorXd> y(b.data(), static_cast<Eigen::Index>(b.size()));
  const Eigen::VectorXd dx = x.array() - x.mean(), dy = y.array() - y.mean();
  const double denominator = std::sqrt(dx.squaredNorm() * dy.squaredNorm());
  return denominator > 0 ? dx.dot(dy) / denominator : std::nan("");
}

inline double range(const std::vector<double>& values) {
  return *std::max_element(values.begin(), values.end()) - *std::min_element(values.begin(), values.end());
}

// gait2392's musculotendon lengths over the 1-cycle trial for the muscles of a bundled scene selection.
struct Gait2392Lengths {
  std::size_t frames = 0;
  std::vector<std::vector<double>> length;  // [muscle][frame] (m); empty for a muscle without a counterpart
  std::vector<muscle_deformation::CoordinateValues> coordinates;  // the trial's, per frame
};

inline Gait2392Lengths gait2392LengthsFor(const muscle_deformation::BundledScene& bundled) {
  using namespace muscle_deformation;
  const std::string package = MD_PACKAGE_DIR;
  const SceneDescription description = loadSceneDescription(package + "/config/scenes/right_hip_thigh.yaml");
  const std::string osim = resolveScenePath(description, description.reference_model.osim_file);
  const OpenSimModel reference = OpenSimModel::fromFile(osim).scaled(description.reference_model.body_scales);
  const MotionTable trial = loadMotionFile(package + "/data/opensim/subject01_walk1_ik_1cycle.mot");
  Gait2392Lengths out;
  out.frames = std::min(trial.rowCount(), bundled.gait.frames.size());
  for (std::size_t f = 0; f < out.frames; ++f) out.coordinates.push_back(coordinateValuesAt(reference, trial, f));
  for (const MuscleDescription& muscle : bundled.scene.muscle_descriptions) {
    std::vector<double> length;
    if (!muscle.reference_muscles.empty()) {
      length.assign(out.frames, 0.0);
      for (std::size_t f = 0; f < out.frames; ++f)
        for (const std::string& name : muscle.reference_muscles)
          length[f] += reference.musculotendonLength(name, out.coordinates[f]) /
                       static_cast<double>(muscle.reference_muscles.size());
    }
    out.length.push_back(std::move(length));
  }
  return out;
}

}  // namespace bench
