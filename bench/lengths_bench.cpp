// Muscle lengths over the gait against gait2392, the field's reference for the bundled skeleton.
//
// The product's length of a muscle in a frame is the mean over its fibres of the fibre's belly length (the polyline of
// its particles, as ~fibres shows it) and of its belly + tendon length (plus, at each end that hangs from its bone by a
// tendon, the tendon from the fibre end over its path to the site). The reference is the musculotendon length of the
// muscle's gait2392 counterpart(s) (the scene's `reference_muscles`, their mean), computed from the .osim the scene
// names (`reference_model`, scaled by its `body_scales` to the scene's skeleton) at the trial's joint angles (the .mot
// the 1-cycle bag was made from). Per muscle: the correlation r over the frames, the excursion (max - min) both ways
// and its ratio, and each joint's slope (mm/rad, a least-squares fit of the length against the four right-leg joint
// angles). Two product streams: the node's defaults frame by frame ("stream") and every frame refined until it meets
// its residual criterion ("converged"), so that solver lag and the model's answer can be told apart.
//
// Writes out/bench/lengths.json.   lengths_bench [--out DIR] [--quick]
#include "bench_util.hpp"
#include "gait_lengths.hpp"
#include "node_defaults.hpp"

#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/scene/motion_file.hpp"
#include "muscle_deformation/core/scene/opensim_model.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <numeric>
#include <cstdio>
#include <string>
#include <vector>

using namespace muscle_deformation;

namespace {

const std::vector<std::string> kJoints = {"hip_flexion_r", "hip_adduction_r", "hip_rotation_r", "knee_angle_r"};

// Least-squares slopes (m/rad) of `length` against the joint angles (one row per frame), with an intercept.
Eigen::VectorXd slopes(const Eigen::MatrixXd& angles, const std::vector<double>& length) {
  Eigen::MatrixXd design(angles.rows(), angles.cols() + 1);
  design << angles, Eigen::VectorXd::Ones(angles.rows());
  const Eigen::Map<const Eigen::VectorXd> y(length.data(), static_cast<Eigen::Index>(length.size()));
  const Eigen::VectorXd solution = design.colPivHouseholderQr().solve(y);
  return solution.head(angles.cols());
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR, {});
  const bench::Gait2392Lengths reference = bench::gait2392LengthsFor(bundled);
  const std::size_t frames = reference.frames;
  std::printf("lengths: %zu frames of the 1-cycle gait, gait2392 scaled to the skeleton\n", frames);

  // The joint angles per frame (radians): the trial's (the reference's) and the bag's (the product's).
  Eigen::MatrixXd trial_angles(static_cast<Eigen::Index>(frames), static_cast<Eigen::Index>(kJoints.size()));
  Eigen::MatrixXd gait_angles(static_cast<Eigen::Index>(frames), static_cast<Eigen::Index>(kJoints.size()));
  for (std::size_t f = 0; f < frames; ++f) {
    for (std::size_t j = 0; j < kJoints.size(); ++j) {
      trial_angles(static_cast<Eigen::Index>(f), static_cast<Eigen::Index>(j)) = reference.coordinates[f].at(kJoints[j]);
      const JointValues& joints = bundled.gait.frames[f];
      const auto found = joints.find(kJoints[j]);
      gait_angles(static_cast<Eigen::Index>(f), static_cast<Eigen::Index>(j)) = found == joints.end() ? 0.0 : found->second;
    }
  }

  // The product, streamed as the node streams it, and converged frame by frame.
  const CoreSettings node = bench::loadNodeDefaults();
  bench::MuscleLengths stream_lengths, converged_lengths;
  for (const bool converged : {false, true}) {
    CoreSettings settings = node;
    settings.pipeline.skin_surfaces = settings.pipeline.measure_fidelity = false;
    settings.stream.refine_unfinished_frames = true;
    StreamSession session(bundled.scene.muscle_descriptions, bundled.scene.muscles, bundled.scene.bones,
                          settings.pipeline, settings.stream);
    bench::MuscleLengths& lengths = converged ? converged_lengths : stream_lengths;
    const int refinements = options.quick ? 20 : 300;
    for (std::size_t f = 0; f < frames; ++f) {
      session.offer(bundled.gait.times_s[f], boneTransformsOf(session.bones(), gaitPose(bundled, f)), {});
      for (int k = 0; converged && k < refinements && session.wantsRefinement(); ++k) session.refine({});
      bench::addLengthsOf(session.pipeline(), lengths);
    }
  }

  bench::JsonRecords records;
  const std::vector<MuscleDescription>& muscles = bundled.scene.muscle_descriptions;
  for (std::size_t m = 0; m < muscles.size(); ++m) {
    const MuscleDescription& muscle = muscles[m];
    std::string names;
    for (const std::string& name : muscle.reference_muscles) names += (names.empty() ? "" : "+") + name;
    records.begin();
    records.add("muscle", muscle.name);
    records.add("reference", names.empty() ? std::string("none") : names);
    if (muscle.reference_muscles.empty()) {
      records.add("counterpart", "none in gait2392");
      records.end();
      std::printf("  %-28s no counterpart in gait2392\n", muscle.name.c_str());
      continue;
    }
    const std::vector<double>& reference_length = reference.length[m];
    const Eigen::VectorXd reference_slopes = slopes(trial_angles, reference_length);
    records.add("range_mm_reference", 1e3 * bench::range(reference_length));
    for (std::size_t j = 0; j < kJoints.size(); ++j)
      records.add("mm_per_rad_reference_" + kJoints[j], 1e3 * reference_slopes[static_cast<Eigen::Index>(j)]);
    for (const auto& [label, lengths] : {std::pair<std::string, const bench::MuscleLengths*>{"", &stream_lengths},
                                         std::pair<std::string, const bench::MuscleLengths*>{"converged_", &converged_lengths}}) {
      for (const auto& [part, series] : {std::pair<std::string, const std::vector<double>*>{"", &lengths->belly[m]},
                                          std::pair<std::string, const std::vector<double>*>{"with_tendon_", &lengths->whole[m]},
                                          std::pair<std::string, const std::vector<double>*>{"spanned_", &lengths->spanned[m]},
                                          std::pair<std::string, const std::vector<double>*>{"toned_", &lengths->toned[m]}}) {
        // The span and what the tone sets are the bones' and paths' alone: the same in both streams, recorded once.
        if ((part == "spanned_" || part == "toned_") && (!label.empty() || series->size() != frames)) continue;
        const std::string prefix = label + part;
        const Eigen::VectorXd product_slopes = slopes(gait_angles, *series);
        records.add(prefix + "r", bench::correlation(*series, reference_length));
        records.add(prefix + "range_mm_product", 1e3 * bench::range(*series));
        records.add(prefix + "range_ratio", bench::range(*series) / bench::range(reference_length));
        for (std::size_t j = 0; j < kJoints.size(); ++j)
          records.add(prefix + "mm_per_rad_product_" + kJoints[j], 1e3 * product_slopes[static_cast<Eigen::Index>(j)]);
      }
    }
    if (stream_lengths.tone_counted[m] > 0) {
      // The strain the reference's excursion asks of the belly as segmented, and how often the tone's limit held it.
      records.add("rest_belly_length_mm", 1e3 * stream_lengths.rest_belly_m[m]);
      records.add("reference_excursion_strain", bench::range(reference_length) / stream_lengths.rest_belly_m[m]);
      records.add("tone_limited_share", static_cast<double>(stream_lengths.tone_limited[m]) /
                                            static_cast<double>(stream_lengths.tone_counted[m]));
    }
    records.add("mean_length_mm_product", 1e3 * std::accumulate(stream_lengths.belly[m].begin(), stream_lengths.belly[m].end(), 0.0) / static_cast<double>(frames));
    records.add("mean_length_mm_reference", 1e3 * std::accumulate(reference_length.begin(), reference_length.end(), 0.0) / static_cast<double>(frames));
    records.end();
    const Eigen::VectorXd s = slopes(gait_angles, stream_lengths.belly[m]);
    std::printf("  %-28s r %.3f (converged %.3f); excursion %.1f / %.1f mm (x%.2f, converged x%.2f); knee %.0f / %.0f mm/rad, hip flexion %.0f / %.0f\n",
                muscle.name.c_str(), bench::correlation(stream_lengths.belly[m], reference_length),
                bench::correlation(converged_lengths.belly[m], reference_length), 1e3 * bench::range(stream_lengths.belly[m]),
                1e3 * bench::range(reference_length), bench::range(stream_lengths.belly[m]) / bench::range(reference_length),
                bench::range(converged_lengths.belly[m]) / bench::range(reference_length), 1e3 * s[3],
                1e3 * reference_slopes[3], 1e3 * s[0], 1e3 * reference_slopes[0]);
    if (stream_lengths.spanned[m].size() == frames) {
      const Eigen::VectorXd span_slopes = slopes(gait_angles, stream_lengths.spanned[m]);
      std::printf("  %-28s its attachment span: r %.3f, excursion x%.2f, knee %.0f mm/rad, hip flexion %.0f; the tone "
                  "sets x%.2f (limit held %.0f %% of fibre-frames; rest belly %.0f mm, gait2392's excursion %.0f %% of it)\n", "",
                  bench::correlation(stream_lengths.spanned[m], reference_length),
                  bench::range(stream_lengths.spanned[m]) / bench::range(reference_length), 1e3 * span_slopes[3],
                  1e3 * span_slopes[0], bench::range(stream_lengths.toned[m]) / bench::range(reference_length),
                  100.0 * static_cast<double>(stream_lengths.tone_limited[m]) / static_cast<double>(stream_lengths.tone_counted[m]),
                  1e3 * stream_lengths.rest_belly_m[m], 100.0 * bench::range(reference_length) / stream_lengths.rest_belly_m[m]);
    }
    std::fflush(stdout);
  }
  // Whether the fibres kept their line over the gait, both streams (the arc lengths above measure a muscle's length only
  // if they did).
  records.begin();
  records.add("fibre_folding", std::string("1-cycle gait, all muscles, worst frame"));
  for (const auto& [label, lengths] : {std::pair<std::string, const bench::MuscleLengths*>{"", &stream_lengths},
                                       std::pair<std::string, const bench::MuscleLengths*>{"converged_", &converged_lengths}}) {
    lengths->folding.record(records, label);
    std::printf("  %s: %d fibres folded at most (%s), tortuosity x%.2f of rest at most (%s)\n",
                label.empty() ? "stream" : "converged", lengths->folding.folded_fibres_max,
                lengths->folding.most_folded_muscle.empty() ? "none" : lengths->folding.most_folded_muscle.c_str(),
                lengths->folding.tortuosity_ratio_max, lengths->folding.most_tortuous_muscle.c_str());
  }
  records.end();
  return bench::finish(records, options, "lengths.json");
}
