// Fidelity of what the user sees, the skinned muscle surfaces, on the bundled scene (all 26 muscles): volume kept and
// depth inside bone, per skinning method, with and without the surface volume constraint, over
//   gait          the 1-cycle gait streamed as the node does (warm starts),
//   hip_flexion   the 2019 PBD thesis scenario on our data: hip_flexion_r 0 -> 1.5 rad -> 0 in warm frames
//                 (iliacus and psoas are the muscles to watch: the thesis saw the iliacus go into the pelvis),
// both played through the node's stream protocol (the core's StreamSession with the node's stream settings, poses
// 1/60 s apart).
// The particles are solved once per frame at the node's defaults (one block-descent sweep per frame, the sweep its time
// budget gives on this machine, run as a sweep count so that every figure is repeatable); every surface variant is
// skinned from the same particles. Volume errors are signed percent of the rest volume; depths are read from the bone
// fields (1 mm voxels). Writes out/bench/fidelity.json: one object per (case, variant), plus one per (case, muscle) for
// the node's default variant.
//
//   fidelity_bench [--out DIR] [--quick]
#include "bench_util.hpp"
#include "node_defaults.hpp"
#include "stream_play.hpp"

#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/solvers/block_descent_solver.hpp"
#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"
#include "muscle_deformation/core/surfaces/surface_bone_contact.hpp"
#include "muscle_deformation/core/surfaces/surface_skinning.hpp"
#include "muscle_deformation/core/surfaces/surface_volume.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

using namespace muscle_deformation;

namespace {

double elapsedSeconds() {
  static const auto start = std::chrono::steady_clock::now();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

struct Variant {
  std::string label;
  SkinningSettings skinning;
  bool keep_volume = false;
  bool keep_out_of_bones = false;  // the skin's contact with the bones, before the volume constraint
  bool node_default = false;
};

// Figures of one variant over the frames of one case.
struct Tally {
  std::vector<double> abs_volume_error_sum;  // per muscle, summed over frames
  std::vector<double> abs_volume_error_max;  // per muscle
  std::vector<double> skinned_error_max;     // per muscle: the skinning's own, before the volume projection
  std::vector<std::size_t> skinned_error_max_pose;  // per muscle: the pose (index in its case) where that was
  std::vector<double> inside_depth_max;      // per muscle, metres
  std::vector<double> particle_depth_max;    // per muscle: its deepest particle in bone, metres
  double rest_inside_depth_max = 0;          // first frame
  double offset_max_m = 0, offset_mean_sum_m = 0;
  int held_max = 0;
  std::vector<double> skinning_ms, contact_ms, volume_ms, metrics_ms;
  int frames = 0;

  explicit Tally(std::size_t muscles)
      : abs_volume_error_sum(muscles, 0), abs_volume_error_max(muscles, 0), skinned_error_max(muscles, 0),
        skinned_error_max_pose(muscles, 0),
        inside_depth_max(muscles, 0), particle_depth_max(muscles, 0) {}
};

struct SurfaceVariant {
  Variant variant;
  std::unique_ptr<SurfaceSkinning> skinning;
  std::unique_ptr<SurfaceBoneContact> contact;
  std::unique_ptr<SurfaceVolumeConstraint> volume;
  // Each variant measured by its own metrics, as a node has one (they remember what they read of the bones).
  std::unique_ptr<DeformationMetrics> metrics;
  std::vector<Vertices> surfaces;
};

void measureFrame(SurfaceVariant& v, const DeformationPipeline& simulation, const BoneTransforms& transforms,
                  std::size_t pose, int threads, Tally& tally) {
  tally.skinning_ms.push_back(
      bench::millisecondsOf([&] { v.skinning->update(simulation.state().position, transforms, v.surfaces); }));
  if (v.contact)
    tally.contact_ms.push_back(bench::millisecondsOf([&] { v.contact->apply(v.surfaces, transforms, threads); }));
  std::vector<SurfaceVolumeCorrection> corrections;
  if (v.volume)
    tally.volume_ms.push_back(
        bench::millisecondsOf([&] { corrections = v.volume->apply(v.surfaces, transforms, threads); }));
  SceneMetrics measured;
  tally.metrics_ms.push_back(
      bench::millisecondsOf([&] { measured = v.metrics->measure(v.surfaces, simulation.state().position, transforms, threads); }));
  double offset_sum = 0;
  for (std::size_t m = 0; m < measured.muscles.size(); ++m) {
    const MuscleMetrics& mm = measured.muscles[m];
    const double error = std::abs(mm.volume_error_pct);
    tally.abs_volume_error_sum[m] += error;
    tally.abs_volume_error_max[m] = std::max(tally.abs_volume_error_max[m], error);
    const double skinned = corrections.empty() ? error : std::abs(corrections[m].volume_error_before_pct);
    if (skinned > tally.skinned_error_max[m]) {
      tally.skinned_error_max[m] = skinned;
      tally.skinned_error_max_pose[m] = pose;
    }
    tally.inside_depth_max[m] = std::max(tally.inside_depth_max[m], mm.max_inside_bone_depth_m);
    tally.particle_depth_max[m] = std::max(tally.particle_depth_max[m], mm.max_particle_inside_bone_depth_m);
    if (tally.frames == 0) tally.rest_inside_depth_max = std::max(tally.rest_inside_depth_max, mm.max_inside_bone_depth_m);
    if (!corrections.empty()) {
      tally.offset_max_m = std::max(tally.offset_max_m, corrections[m].max_offset_m);
      offset_sum += corrections[m].mean_offset_m;
      tally.held_max = std::max(tally.held_max, corrections[m].vertices_held_by_bone);
    }
  }
  if (!measured.muscles.empty()) tally.offset_mean_sum_m += offset_sum / static_cast<double>(measured.muscles.size());
  ++tally.frames;
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  bench::JsonRecords records;
  elapsedSeconds();
  const CoreSettings node = bench::loadNodeDefaults();
  StreamSessionSettings stream_settings = node.stream;
  // The node's time budget gives one sweep a frame on this machine (real-time section); as a count it repeats exactly.
  StoppingSettings& sweeps = stream_settings.stopping.sweeps;
  sweeps.rule = StoppingRule::iterations;
  sweeps.max_iterations = 1;
  sweeps.limits = {};

  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR, {});
  // The particles only: every surface variant below is skinned and measured from them by the bench itself.
  StreamSession session(bundled.scene.muscle_descriptions, bundled.scene.muscles, bundled.scene.bones,
                        bench::particlesOnly(node.pipeline), stream_settings);
  const DeformationPipeline& simulation = session.pipeline();
  const MassSpringSystem& system = simulation.system();
  const std::size_t muscle_count = simulation.muscles().size();
  std::printf("[%6.1f s] %zu muscles, %ld particles\n", elapsedSeconds(), muscle_count,
              static_cast<long>(system.particleCount()));

  // The surface stages and metrics run on the node's threads (every core by default), as in its pipeline.
  const int surface_threads = parallelThreads(node.pipeline.threads, node.stream.stopping.sweeps.limits);
  std::printf("[%6.1f s] surface stages and metrics on %d threads\n", elapsedSeconds(), surface_threads);
  const SkinningSettings node_skinning;  // the node's skinning defaults are the core's (config/muscle_deformation.yaml)
  std::vector<Variant> variants;
  for (const bool keep : {false, true}) {
    for (const SkinningMethod method : {SkinningMethod::nearest_average, SkinningMethod::embedded,
                                        SkinningMethod::mean_value}) {
      SkinningSettings skinning = node_skinning;
      skinning.method = method;
      variants.push_back({toString(method) + (keep ? " + volume" : ""), skinning, keep, false, false});
    }
  }
  // What the node runs: the skinning, the skin's contact with the bones, then the volume constraint; the other
  // skinning methods the same way, so the choice of method is made on the whole chain.
  for (const SkinningMethod method : {SkinningMethod::nearest_average, SkinningMethod::embedded,
                                      SkinningMethod::mean_value}) {
    SkinningSettings skinning = node_skinning;
    skinning.method = method;
    variants.push_back({toString(method) + " + bone contact + volume", skinning, true, true,
                        method == node_skinning.method});
  }
  std::vector<SurfaceVariant> surfaces;
  for (const Variant& variant : variants) {
    SurfaceVariant v;
    v.variant = variant;
    try {
      v.skinning = std::make_unique<SurfaceSkinning>(system, simulation.muscles(), variant.skinning);
    } catch (const SkinningError& e) {
      std::printf("[%6.1f s] %s: not available on this scene: %s\n", elapsedSeconds(), variant.label.c_str(), e.what());
      records.begin();
      records.add("case", "precompute");
      records.add("variant", variant.label);
      records.add("unavailable", e.what());
      records.end();
      continue;
    }
    if (variant.keep_out_of_bones) {
      std::vector<Eigen::Index> vertex_counts;
      for (const Muscle& muscle : simulation.muscles()) vertex_counts.push_back(muscle.surface.vertexCount());
      v.contact = std::make_unique<SurfaceBoneContact>(vertex_counts, simulation.boneFields());
    }
    if (variant.keep_volume) {
      std::vector<Triangles> triangles;
      std::vector<Vertices> rest;
      for (std::size_t m = 0; m < muscle_count; ++m) {
        triangles.push_back(v.skinning->muscles()[m].triangles());
        rest.push_back(simulation.muscles()[m].surface.vertices);
      }
      v.volume = std::make_unique<SurfaceVolumeConstraint>(triangles, rest, simulation.boneFields(), SurfaceVolumeSettings{});
    }
    v.metrics = std::make_unique<DeformationMetrics>(simulation.bones(), simulation.muscles(), system,
                                                     simulation.boneFields());
    surfaces.push_back(std::move(v));
  }
  std::printf("[%6.1f s] %zu surface variants precomputed\n", elapsedSeconds(), surfaces.size());

  struct Case {
    std::string name;
    std::vector<BoneTransforms> frames;
  };
  std::vector<Case> cases;
  {
    Case gait{"gait", {}};
    const std::size_t count = options.quick ? 12 : bundled.gait.frames.size();
    for (std::size_t f = 0; f < count; ++f) gait.frames.push_back(boneTransformsOf(simulation.bones(), gaitPose(bundled, f)));
    cases.push_back(std::move(gait));
    Case flexion{"hip_flexion", {}};
    const int half = options.quick ? 15 : 60;  // frames from 0 to 1.5 rad, and as many back
    for (int f = 0; f <= 2 * half; ++f) {
      const double angle = 1.5 * (f <= half ? f : 2 * half - f) / half;
      flexion.frames.push_back(boneTransformsOf(
          simulation.bones(), poseFromLinkPoses(bundled.scene, bundled.scene.skeleton.linkPoses({{"hip_flexion_r", angle}}))));
    }
    cases.push_back(std::move(flexion));
  }

  for (const Case& c : cases) {
    std::vector<Tally> tallies(surfaces.size(), Tally(muscle_count));
    session.restart();  // each case a stream of its own: its first pose starts cold
    for (std::size_t f = 0; f < c.frames.size(); ++f) {
      // A pose no bone moved in is not solved again (the node publishes nothing new): nothing new to measure.
      if (!bench::frameOf(session.offer(bench::streamStamp(f), c.frames[f], FrameWants{}))) continue;
      // The node's first frame starts cold with cold_start_iterations sweeps (its time budget's rule for a cold start);
      // the sweep count above gave it one: the rest as refinements of the same pose and tissue pull.
      for (int sweep = 1; f == 0 && sweep < node.stream.stopping.cold_start_iterations; ++sweep)
        if (!bench::frameOf(session.refine(FrameWants{}))) break;
      for (std::size_t v = 0; v < surfaces.size(); ++v)
        measureFrame(surfaces[v], simulation, c.frames[f], f, surface_threads, tallies[v]);
    }
    const StreamCounters& counters = session.counters();
    std::printf("[%6.1f s] %s: %u poses offered in all so far, %u unchanged, %u refined, %u restarts\n",
                elapsedSeconds(), c.name.c_str(), counters.offered, counters.unchanged, counters.refined,
                counters.resets);
    for (std::size_t v = 0; v < surfaces.size(); ++v) {
      const Tally& t = tallies[v];
      double mean = 0, worst = 0, skinned_worst = 0, depth = 0, particle_depth = 0;
      std::size_t worst_muscle = 0, skinned_worst_muscle = 0;
      for (std::size_t m = 0; m < muscle_count; ++m) {
        mean += t.abs_volume_error_sum[m] / (t.frames * static_cast<double>(muscle_count));
        if (t.abs_volume_error_max[m] > worst) {
          worst = t.abs_volume_error_max[m];
          worst_muscle = m;
        }
        if (t.skinned_error_max[m] > skinned_worst) {
          skinned_worst = t.skinned_error_max[m];
          skinned_worst_muscle = m;
        }
        depth = std::max(depth, t.inside_depth_max[m]);
        particle_depth = std::max(particle_depth, t.particle_depth_max[m]);
      }
      records.begin();
      records.add("case", c.name);
      records.add("variant", surfaces[v].variant.label);
      records.add("skinning", toString(surfaces[v].variant.skinning.method));
      records.add("keep_volume", surfaces[v].variant.keep_volume ? 1.0 : 0.0);
      records.add("keep_out_of_bones", surfaces[v].variant.keep_out_of_bones ? 1.0 : 0.0);
      records.add("node_default", surfaces[v].variant.node_default ? 1.0 : 0.0);
      records.add("frames", static_cast<double>(t.frames));
      records.add("threads", static_cast<double>(surface_threads));
      records.add("volume_error_mean_pct", mean);
      records.add("volume_error_max_pct", worst);
      records.add("volume_error_max_muscle", system.muscle_name[worst_muscle]);
      records.add("skinned_volume_error_max_pct", skinned_worst);
      records.add("skinned_volume_error_max_muscle", system.muscle_name[skinned_worst_muscle]);
      records.add("skinned_volume_error_max_pose", static_cast<double>(t.skinned_error_max_pose[skinned_worst_muscle]));
      records.add("surface_inside_bone_max_mm", depth * 1e3);
      records.add("surface_inside_bone_rest_mm", t.rest_inside_depth_max * 1e3);
      records.add("particle_inside_bone_max_mm", particle_depth * 1e3);
      records.add("offset_max_mm", t.offset_max_m * 1e3);
      records.add("offset_mean_mm", t.offset_mean_sum_m / std::max(1, t.frames) * 1e3);
      records.add("vertices_held_max", t.held_max);
      records.add("skinning_ms_median", bench::median(t.skinning_ms));
      records.add("volume_ms_median", bench::median(t.volume_ms));
      if (!t.contact_ms.empty()) records.add("contact_ms_median", bench::median(t.contact_ms));
      records.add("metrics_ms_median", bench::median(t.metrics_ms));
      records.end();
      std::printf("[%6.1f s] %-11s %-26s volume error mean %5.2f %%, max %6.2f %% (%s; skinned %6.2f %%, %s pose %zu), inside bone "
                  "%5.2f mm (rest %5.2f), particles %5.2f mm, offsets mean %.3f / max %.2f mm, held %d, volume %.2f ms, "
                  "metrics %.2f ms\n",
                  elapsedSeconds(), c.name.c_str(), surfaces[v].variant.label.c_str(), mean, worst,
                  system.muscle_name[worst_muscle].c_str(), skinned_worst,
                  system.muscle_name[skinned_worst_muscle].c_str(), t.skinned_error_max_pose[skinned_worst_muscle],
                  depth * 1e3,
                  t.rest_inside_depth_max * 1e3, particle_depth * 1e3, t.offset_mean_sum_m / std::max(1, t.frames) * 1e3,
                  t.offset_max_m * 1e3, t.held_max, bench::median(t.volume_ms), bench::median(t.metrics_ms));
      std::fflush(stdout);
      // Per muscle, for the variant the node runs (nearest_average with the volume kept) and without the volume.
      if (surfaces[v].variant.skinning.method == node_skinning.method) {
        for (std::size_t m = 0; m < muscle_count; ++m) {
          records.begin();
          records.add("case", c.name);
          records.add("variant", surfaces[v].variant.label);
          records.add("muscle", system.muscle_name[m]);
          records.add("volume_error_mean_pct", t.abs_volume_error_sum[m] / t.frames);
          records.add("volume_error_max_pct", t.abs_volume_error_max[m]);
          records.add("skinned_volume_error_max_pct", t.skinned_error_max[m]);
          records.add("skinned_volume_error_max_pose", static_cast<double>(t.skinned_error_max_pose[m]));
          records.add("surface_inside_bone_max_mm", t.inside_depth_max[m] * 1e3);
          records.add("particle_inside_bone_max_mm", t.particle_depth_max[m] * 1e3);
          records.end();
        }
      }
    }
  }
  std::printf("[%6.1f s] done\n", elapsedSeconds());
  return bench::finish(records, options, "fidelity.json");
}
