// Bone proxies side by side on the bundled scene (all 26 muscles, node defaults otherwise): the seeds' one-ring
// spheres against each bone's signed distance field. Both are measured with the same yardsticks, which neither proxy
// defines: depths inside the real bone (its mesh, read through its distance field at 1 mm), the skinned surfaces'
// volume error and inside-bone vertices, and frame time.
//
//   gait:       the 1-cycle gait streamed as the node does (the core's StreamSession with the node's stream settings,
//               poses 1/60 s apart; surfaces and metrics every frame)
//   hard pose:  hip flexion 110 deg, knee 130 deg solved cold (the real-time issue's hard case)
//
// "Deeper than at rest": a free particle's depth inside a bone beyond the depth it had at rest (the bundled hip bone
// overlaps four muscles at rest; no proxy is asked to undo data).
//
// Writes out/bench/bone_proxy.json, one object per (proxy, case).
//
//   bone_proxy_bench [--out DIR] [--quick]
#include "bench_util.hpp"
#include "node_defaults.hpp"
#include "progress.hpp"
#include "stream_play.hpp"

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

using namespace muscle_deformation;

namespace {

constexpr double kMillimetresPerMetre = 1000.0;
constexpr double kDegree = 3.14159265358979323846 / 180.0;

double maxOf(const std::vector<double>& values) {
  return values.empty() ? 0.0 : *std::max_element(values.begin(), values.end());
}

double meanOf(const std::vector<double>& values) {
  double sum = 0;
  for (const double v : values) sum += v;
  return values.empty() ? 0.0 : sum / static_cast<double>(values.size());
}

// Depth of every free particle inside the real bones (0 outside), per particle: the deepest over bones.
Eigen::VectorXd depthInsideBones(const DeformationMetrics& metrics, const MassSpringSystem& system,
                                 const Eigen::Matrix3Xd& position, const BoneTransforms& transforms) {
  Eigen::VectorXd depth = Eigen::VectorXd::Zero(position.cols());
  for (std::size_t b = 0; b < transforms.size(); ++b) {
    const BoneDistanceField::Probe probe = metrics.boneField(static_cast<int>(b)).probe();
    const Eigen::Isometry3d to_rest = transforms[b].inverse();
    for (Eigen::Index p = 0; p < position.cols(); ++p) {
      if (system.is_fixed[static_cast<std::size_t>(p)]) continue;
      double distance = 0;
      Eigen::Vector3d unused;
      if (probe.closerThan(to_rest * position.col(p), 0.0, distance, unused)) depth[p] = std::max(depth[p], -distance);
    }
  }
  return depth;
}

struct Yardsticks {
  double deeper_than_rest_mm = 0;  // max over frames and free particles
  double particle_depth_mm = 0;    // max over frames and free particles, absolute
  double proxy_penetration_mm = 0; // what the proxy itself reports (its own contacts)
  std::vector<double> volume_mean_pct, volume_max_pct, inside_vertices, inside_depth_mm, solve_ms, bone_cd_ms,
      metrics_ms;
};

void measureFrame(const DeformationPipeline& pipeline, const FrameResult& frame, const Eigen::VectorXd& rest_depth,
                  Yardsticks& out) {
  const Eigen::VectorXd depth = depthInsideBones(*pipeline.metrics(), pipeline.system(), pipeline.state().position,
                                                 frame.bone_transforms);
  out.particle_depth_mm = std::max(out.particle_depth_mm, kMillimetresPerMetre * depth.maxCoeff());
  out.deeper_than_rest_mm =
      std::max(out.deeper_than_rest_mm, kMillimetresPerMetre * (depth - rest_depth).cwiseMax(0.0).maxCoeff());
  out.proxy_penetration_mm =
      std::max(out.proxy_penetration_mm, kMillimetresPerMetre * frame.stats.collision.max_penetration_muscle_bone_m);
  out.volume_mean_pct.push_back(frame.metrics.volume_error_mean_pct);
  out.volume_max_pct.push_back(frame.metrics.volume_error_max_pct);
  out.inside_vertices.push_back(frame.metrics.vertices_inside_bone);
  out.inside_depth_mm.push_back(kMillimetresPerMetre * frame.metrics.max_inside_bone_depth_m);
  out.solve_ms.push_back(frame.stats.solve_ms);
  out.bone_cd_ms.push_back(frame.stats.collision.bone_cd_ms);
  out.metrics_ms.push_back(frame.metrics_ms);
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  std::filesystem::create_directories(options.out_dir);
  const CoreSettings defaults = bench::loadNodeDefaults();
  const BundledScene all = loadBundledScene(MD_PACKAGE_DIR, {});
  const std::size_t frame_count = options.quick ? std::min<std::size_t>(all.gait.frames.size(), 6) : all.gait.frames.size();
  const Pose hard_pose = poseFor(all, {{"hip_flexion_r", 110 * kDegree}, {"knee_angle_r", -130 * kDegree}});

  bench::Progress progress("bone_proxy", 2.0 * static_cast<double>(frame_count + 1));
  bench::JsonRecords records;
  for (const BoneProxyKind proxy : {BoneProxyKind::one_ring_spheres, BoneProxyKind::distance_field}) {
    PipelineSettings settings = defaults.pipeline;  // the node's, surfaces and metrics included
    settings.simulation.collision.bone_proxy = proxy;
    std::unique_ptr<StreamSession> session;
    const double setup_ms = bench::millisecondsOf([&] {
      session = std::make_unique<StreamSession>(all.scene.muscle_descriptions, all.scene.muscles, all.scene.bones,
                                                settings, defaults.stream);
    });
    const DeformationPipeline* pipeline = &session->pipeline();
    if (!pipeline->metrics()) {
      std::fprintf(stderr, "bone_proxy_bench: no metrics: %s\n", pipeline->metricsProblem().c_str());
      return 1;
    }
    const DeformationPipeline& simulation = *pipeline;
    const BoneTransforms rest_transforms(simulation.bones().size(), Eigen::Isometry3d::Identity());
    const Eigen::VectorXd rest_depth =
        depthInsideBones(*pipeline->metrics(), simulation.system(), simulation.system().rest_position, rest_transforms);
    double field_ms = 0, field_bytes = 0;
    for (const auto& field : simulation.boneFields()) {
      field_ms += field->buildMilliseconds();
      field_bytes += static_cast<double>(field->memoryBytes());
    }
    const CollisionWorld* world = simulation.collisionWorld();
    const auto common = [&](const std::string& scenario, const Yardsticks& y) {
      records.begin();
      records.add("proxy", toString(proxy));
      records.add("case", scenario);
      records.add("muscles", static_cast<double>(simulation.system().muscleCount()));
      records.add("particles", static_cast<double>(simulation.system().particleCount()));
      records.add("solver", toString(simulation.settings().simulation.solver_kind));
      records.add("threads", static_cast<double>(simulation.settings().threads));
      records.add("setup_ms", setup_ms);
      records.add("field_build_ms", field_ms);
      records.add("field_bytes", field_bytes);
      double bone_spheres = 0;
      for (const int count : world->boneSphereCounts()) bone_spheres += count;
      records.add("bone_spheres", bone_spheres);
      records.add("collision_spheres", static_cast<double>(world->muscleSphereCount()));
      records.add("rest_spheres_removed", static_cast<double>(simulation.restOverlaps().spheres_removed));
      records.add("rest_particle_depth_mm", kMillimetresPerMetre * rest_depth.maxCoeff());
      records.add("frames", static_cast<double>(y.solve_ms.size()));
      records.add("solve_ms", bench::median(y.solve_ms));
      records.add("solve_max_ms", maxOf(y.solve_ms));
      records.add("bone_cd_ms", bench::median(y.bone_cd_ms));
      records.add("metrics_ms", bench::median(y.metrics_ms));
      records.add("deeper_than_rest_mm", y.deeper_than_rest_mm);
      records.add("particle_depth_mm", y.particle_depth_mm);
      records.add("proxy_penetration_mm", y.proxy_penetration_mm);
      records.add("volume_error_mean_pct", meanOf(y.volume_mean_pct));
      records.add("volume_error_max_pct", maxOf(y.volume_max_pct));
      records.add("inside_bone_vertices_median", bench::median(y.inside_vertices));
      records.add("inside_bone_depth_mm", maxOf(y.inside_depth_mm));
      records.end();
    };

    const FrameWants everything{true, true};
    Yardsticks gait;
    for (std::size_t f = 0; f < frame_count; ++f) {
      const FrameResult* frame = bench::frameOf(
          session->offer(bench::streamStamp(f), boneTransformsOf(simulation.bones(), gaitPose(all, f)), everything));
      if (frame) measureFrame(*pipeline, *frame, rest_depth, gait);  // no frame: no bone moved, nothing solved
    }
    progress.finished(std::string(toString(proxy)) + " gait", static_cast<double>(frame_count));
    common("gait", gait);

    // A single pose solved cold: a stream of its own, whose first pose starts cold.
    Yardsticks hard;
    session->restart();
    const FrameResult& frame = bench::solvedFrame(
        session->offer(bench::streamStamp(0), boneTransformsOf(simulation.bones(), hard_pose), everything));
    measureFrame(*pipeline, frame, rest_depth, hard);
    progress.finished(std::string(toString(proxy)) + " hard pose", 1.0);
    common("hip_flexion_110_knee_130_cold", hard);
    std::printf("%s: gait solve %.1f ms median, deeper than rest %.2f mm, volume %.2f %% mean / %.1f %% worst; "
                "hard pose deeper than rest %.2f mm\n",
                toString(proxy), bench::median(gait.solve_ms), gait.deeper_than_rest_mm, meanOf(gait.volume_mean_pct),
                maxOf(gait.volume_max_pct), hard.deeper_than_rest_mm);
  }
  return bench::finish(records, options, "bone_proxy.json");
}
