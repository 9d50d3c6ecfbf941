// What each economy of "model only what a scene needs" buys, on the bundled scene with the node's defaults
// (config/muscle_deformation.yaml: 20 particles per fibre, the node's solver and frame stopping, warm start), playing
// the bundled gait frame by frame through the node's stream protocol (the core's StreamSession: warm from the previous
// frame, cold when a bone jumps, a pose no bone moved in not solved again, a reset after a failed frame):
//   muscle_subset:      one muscle, the 13 thigh13 muscles, all 26: frame time, build time, size and memory.
//   bone_reach:         the collision stage's skip of muscle-bone tests whose bounds cannot meet, on and off, for the
//                       hip muscles and the thigh13 muscles; the results must not change.
//   collision_particles: only boundary particles collide (the seeds' choice) or every particle does: time and
//                       penetration, each state measured with both sphere sets.
//   unchanged_pose:     the node's check that no bone moved (largestBoneMotion) against the solve it saves, on
//                       streams that repeat poses: the gait as recorded, re-published at 2x and 4x its rate with
//                       each pose held, and the gait followed by a held pose as long as the cycle.
// Writes out/bench/economy.json: one object per economy and variant.
#include "bench_util.hpp"
#include "node_defaults.hpp"
#include "progress.hpp"
#include "stream_play.hpp"

#include "muscle_deformation/core/base/bone_transforms.hpp"
#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

using namespace muscle_deformation;

namespace {

constexpr double kMillimetresPerMetre = 1000.0;

// One played frame.
struct FrameRecord {
  double wall_ms = 0, cpu_ms = 0;
  FrameStats stats;
};

// Plays poses through a stream session as the node's stream plays them, stamped at the gait's 60 Hz. A pose the
// session does not solve again (no bone moved) leaves no frame record, as the node solves nothing for it.
class GaitPlayer {
 public:
  explicit GaitPlayer(StreamSession& session) : session_(session) {}

  void play(const Pose& pose, std::vector<FrameRecord>& frames) {
    const BoneTransforms transforms = boneTransformsOf(session_.bones(), pose);
    FrameRecord record;
    const FrameResult* frame = nullptr;
    record.cpu_ms = bench::cpuMillisecondsOf([&] {
      record.wall_ms = bench::millisecondsOf(
          [&] { frame = bench::frameOf(session_.offer(bench::streamStamp(played_++), transforms, FrameWants{})); });
    });
    if (!frame) return;
    record.stats = frame->stats;
    frames.push_back(record);
  }

 private:
  StreamSession& session_;
  std::size_t played_ = 0;
};

// Plays the poses through several sessions frame by frame in turn (so slow spells of a shared machine hit all of
// them alike), calling after_frame() once every session has been offered a frame. One record list per session.
std::vector<std::vector<FrameRecord>> playInTurn(const std::vector<std::unique_ptr<StreamSession>>& sessions,
                                                 const std::vector<Pose>& poses,
                                                 const std::function<void()>& after_frame = {}) {
  std::vector<GaitPlayer> players;
  for (const auto& session : sessions) players.emplace_back(*session);
  std::vector<std::vector<FrameRecord>> played(sessions.size());
  for (const Pose& pose : poses) {
    for (std::size_t v = 0; v < players.size(); ++v) players[v].play(pose, played[v]);
    if (after_frame) after_frame();
  }
  return played;
}

std::vector<double> column(const std::vector<FrameRecord>& frames, double FrameRecord::*field) {
  std::vector<double> values;
  for (const FrameRecord& f : frames) values.push_back(f.*field);
  return values;
}

template <class Get>
std::vector<double> statColumn(const std::vector<FrameRecord>& frames, Get get) {
  std::vector<double> values;
  for (const FrameRecord& f : frames) values.push_back(get(f.stats));
  return values;
}

double maxOf(const std::vector<double>& values) {
  return values.empty() ? 0.0 : *std::max_element(values.begin(), values.end());
}

// Heap bytes of the model, the solver's copy and the state (positions and previous positions).
double memoryBytes(const StreamSession& session) {
  const DeformationPipeline& pipeline = session.pipeline();
  const MassSpringSystem& system = pipeline.system();
  const double state = 2.0 * 3.0 * sizeof(double) * static_cast<double>(system.particleCount());
  return static_cast<double>(system.modelBytes() +
                             VerletSolver(system, pipeline.settings().simulation.verlet).solverBytes()) +
         state;
}

// Fields every played variant reports: frame time, size, collision work and what collision left.
void addPlayedVariant(bench::JsonRecords& records, const std::string& economy, const std::string& variant,
                      const StreamSession& session, const std::vector<FrameRecord>& frames, double build_ms) {
  const DeformationPipeline& simulation = session.pipeline();
  const MassSpringSystem& system = simulation.system();
  records.add("economy", economy);
  records.add("variant", variant);
  records.add("frame_ms", bench::median(column(frames, &FrameRecord::wall_ms)));
  records.add("frame_cpu_ms", bench::median(column(frames, &FrameRecord::cpu_ms)));
  records.add("frame_max_ms", maxOf(column(frames, &FrameRecord::wall_ms)));
  records.add("frames", static_cast<double>(frames.size()));
  // Iterations a frame actually ran (under a time budget they vary), and which solver ran them.
  records.add("iterations_per_frame",
              bench::median(statColumn(frames, [](const FrameStats& s) { return static_cast<double>(s.solver.iterations); })));
  records.add("solver", toString(simulation.settings().simulation.solver_kind));
  records.add("mss_ms_per_frame", bench::median(statColumn(frames, [](const FrameStats& s) { return s.solver.mss_ms; })));
  records.add("collision_ms_per_frame",
              bench::median(statColumn(frames, [](const FrameStats& s) { return s.solver.collision_ms; })));
  records.add("bone_cd_ms_per_frame",
              bench::median(statColumn(frames, [](const FrameStats& s) { return s.collision.bone_cd_ms; })));
  records.add("muscle_cd_ms_per_frame",
              bench::median(statColumn(frames, [](const FrameStats& s) { return s.collision.muscle_cd_ms; })));
  records.add("build_ms", build_ms);
  records.add("muscles", static_cast<double>(system.muscleCount()));
  records.add("particles", static_cast<double>(system.particleCount()));
  records.add("springs", static_cast<double>(system.springs.size()));
  records.add("memory_bytes", memoryBytes(session));
  records.add("bones", static_cast<double>(simulation.bones().size()));
  const CollisionWorld* world = simulation.collisionWorld();
  double bone_spheres = 0;
  for (const int count : world->boneSphereCounts()) bone_spheres += count;
  records.add("bone_spheres", bone_spheres);
  records.add("collision_spheres", static_cast<double>(world->muscleSphereCount()));
  // Particles whose sphere was dropped at build time because its centre lay inside a bone sphere at rest.
  records.add("rest_spheres_removed", static_cast<double>(simulation.restOverlaps().spheres_removed));
  records.add("bones_skipped_median",
              bench::median(statColumn(frames, [](const FrameStats& s) { return s.collision.bones_skipped; })));
  records.add("penetration_mm", kMillimetresPerMetre * maxOf(statColumn(frames, [](const FrameStats& s) {
                                  return s.collision.max_penetration_muscle_bone_m;
                                })));
  records.add("muscle_penetration_mm", kMillimetresPerMetre * maxOf(statColumn(frames, [](const FrameStats& s) {
                                         return s.collision.max_penetration_muscle_muscle_m;
                                       })));
}

// A stream session of the node's (its pipeline settings with `settings` for the simulation, particles only, and its
// stream session settings).
std::unique_ptr<StreamSession> build(const Scene& scene, const SimulationSettings& settings, const CoreSettings& node,
                                     double& build_ms) {
  PipelineSettings pipeline = bench::particlesOnly(node.pipeline);
  pipeline.simulation = settings;
  std::unique_ptr<StreamSession> session;
  build_ms = bench::millisecondsOf([&] {
    session = std::make_unique<StreamSession>(scene.muscle_descriptions, scene.muscles, scene.bones, pipeline,
                                              node.stream);
  });
  return session;
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  std::filesystem::create_directories(options.out_dir);
  const CoreSettings defaults = bench::loadNodeDefaults();
  const SimulationSettings& node_simulation = defaults.pipeline.simulation;

  const BundledScene all = loadBundledScene(MD_PACKAGE_DIR, {});
  const BundledScene thigh13 = loadBundledScene(MD_PACKAGE_DIR, {"thigh13"});
  const BundledScene hip = loadBundledScene(MD_PACKAGE_DIR, {"hip"});
  const BundledScene one = loadBundledScene(MD_PACKAGE_DIR, {thigh13.scene.muscles.front().name});
  // A quick run plays a stretch of the gait from its start; the full run plays the whole cycle.
  const std::size_t frame_count = options.quick ? std::min<std::size_t>(all.gait.frames.size(), 6) : all.gait.frames.size();
  std::vector<Pose> poses;
  for (std::size_t f = 0; f < frame_count; ++f) poses.push_back(gaitPose(all, f));
  std::string bone_list;
  for (const Bone& bone : all.scene.bones) bone_list += " " + bone.name;
  std::printf("bones:%s; %zu gait frames per variant, at most %d iterations per frame, %d particles per fibre\n",
              bone_list.c_str(), frame_count, defaults.stream.stopping.sweeps.max_iterations,
              node_simulation.model.particles_per_fibre);

  // Work estimate for the progress line: frames played x muscles simulated, summed over the runs below.
  const double one_muscles = static_cast<double>(one.scene.muscles.size());
  const double thigh13_muscles = static_cast<double>(thigh13.scene.muscles.size());
  const double hip_muscles = static_cast<double>(hip.scene.muscles.size());
  const double all_muscles = static_cast<double>(all.scene.muscles.size());
  bench::Progress progress("economy", static_cast<double>(frame_count) *
                                          (one_muscles + thigh13_muscles + all_muscles +  // (a)
                                           4 * hip_muscles + 2 * thigh13_muscles +        // (b)
                                           2 * thigh13_muscles));                         // (c)
  bench::JsonRecords records;

  // (a) A requested subset of muscles against all of them; the default thigh13 run also serves (b) and (c).
  struct Subset {
    std::string name;
    const BundledScene* bundled;
  };
  double all_26_frame_ms = 0, thigh13_frame_ms = 0;
  for (const Subset& subset : {Subset{"one_muscle_" + one.scene.muscles.front().name, &one},
                               Subset{"thigh13", &thigh13}, Subset{"all_26", &all}}) {
    double build_ms = 0;
    auto session = build(subset.bundled->scene, node_simulation, defaults, build_ms);
    const DeformationPipeline& simulation = session->pipeline();
    GaitPlayer player(*session);
    std::vector<FrameRecord> frames;
    for (const Pose& pose : poses) player.play(pose, frames);
    records.begin();
    addPlayedVariant(records, "muscle_subset", subset.name, *session, frames, build_ms);
    records.end();
    const double frame_ms = bench::median(column(frames, &FrameRecord::wall_ms));
    if (subset.name == "all_26") all_26_frame_ms = frame_ms;
    if (subset.name == "thigh13") thigh13_frame_ms = frame_ms;
    std::printf("muscle_subset %-28s %3d muscles %6ld particles: frame %.1f ms, build %.0f ms, %.1f MB\n",
                subset.name.c_str(), simulation.system().muscleCount(),
                static_cast<long>(simulation.system().particleCount()), frame_ms, build_ms,
                memoryBytes(*session) / 1e6);
    progress.finished("muscle_subset " + subset.name,
                      static_cast<double>(frame_count * static_cast<std::size_t>(simulation.system().muscleCount())));
  }

  // (b) Skipping muscle-bone tests out of reach, on and off, with each broad phase (a non-skipped pair costs the
  // octree a root-box test, the hash grid a query per muscle sphere). The two runs of a pair are played frame by
  // frame in turn, so load on this shared machine hits both alike; they play the same poses from the same model, so
  // their final states must agree exactly.
  struct ReachCase {
    const Subset subset;
    BroadPhaseKind broad_phase;
  };
  for (const ReachCase& reach : {ReachCase{{"hip", &hip}, BroadPhaseKind::octree},
                                 ReachCase{{"hip", &hip}, BroadPhaseKind::hash_grid},
                                 ReachCase{{"thigh13", &thigh13}, BroadPhaseKind::octree}}) {
    std::vector<std::unique_ptr<StreamSession>> simulations;
    std::vector<double> build_ms;
    for (const bool skip : {true, false}) {
      SimulationSettings settings = node_simulation;
      settings.collision.broad_phase = reach.broad_phase;
      settings.collision.skip_bones_out_of_reach = skip;
      build_ms.push_back(0);
      simulations.push_back(build(reach.subset.bundled->scene, settings, defaults, build_ms.back()));
    }
    const std::vector<std::vector<FrameRecord>> played = playInTurn(simulations, poses);
    const double difference =
        (simulations[0]->pipeline().state().position - simulations[1]->pipeline().state().position).cwiseAbs().maxCoeff();
    const std::string prefix = reach.subset.name + "_" + toString(reach.broad_phase);
    for (std::size_t v = 0; v < simulations.size(); ++v) {
      const std::string variant = prefix + (v == 0 ? "_skip_out_of_reach" : "_test_every_bone");
      records.begin();
      addPlayedVariant(records, "bone_reach", variant, *simulations[v], played[v], build_ms[v]);
      records.add("broad_phase", std::string(toString(reach.broad_phase)));
      records.add("max_position_difference_m", difference);
      records.end();
      std::printf("bone_reach %-36s frame %.1f ms (CPU %.1f), bone CD %.2f ms/frame, bones skipped (median) %.0f of "
                  "%zu; final positions differ by %.3g m\n",
                  variant.c_str(), bench::median(column(played[v], &FrameRecord::wall_ms)),
                  bench::median(column(played[v], &FrameRecord::cpu_ms)),
                  bench::median(statColumn(played[v], [](const FrameStats& s) { return s.collision.bone_cd_ms; })),
                  bench::median(statColumn(played[v], [](const FrameStats& s) { return s.collision.bones_skipped; })),
                  simulations[v]->bones().size(), difference);
    }
    progress.finished("bone_reach " + prefix, static_cast<double>(frame_count) * 2 *
                                                  static_cast<double>(simulations[0]->pipeline().system().muscleCount()));
  }

  // (c) Boundary-only collision against every particle colliding. The two models share their particles (same
  // sampling), so each state is also measured with the other model's spheres: the boundary spheres say how far the
  // surface sank into bone, the every-particle spheres how far any particle did.
  {
    SimulationSettings every_settings = node_simulation;
    every_settings.model.boundary_fibre_fraction = 0;  // every fibre, hence every particle, collides
    double boundary_build_ms = 0, every_build_ms = 0;
    std::vector<std::unique_ptr<StreamSession>> simulations;
    simulations.push_back(build(thigh13.scene, node_simulation, defaults, boundary_build_ms));
    simulations.push_back(build(thigh13.scene, every_settings, defaults, every_build_ms));
    // Penetration into bone (m) of [variant] measured with [sphere set]: 0 boundary spheres, 1 every-particle ones.
    double penetration[2][2] = {{0, 0}, {0, 0}};
    const std::vector<std::vector<FrameRecord>> played_in_turn =
        playInTurn(simulations, poses, [&] {
          for (std::size_t v = 0; v < 2; ++v)
            for (std::size_t w = 0; w < 2; ++w)
              penetration[v][w] = std::max(penetration[v][w], simulations[w]->pipeline().collisionWorld()
                                                                  ->measure(simulations[v]->pipeline().state())
                                                                  .max_penetration_muscle_bone_m);
        });
    const char* names[2] = {"boundary_only", "every_particle"};
    const double build_ms[2] = {boundary_build_ms, every_build_ms};
    for (std::size_t v = 0; v < 2; ++v) {
      records.begin();
      addPlayedVariant(records, "collision_particles", names[v], *simulations[v],
                       played_in_turn[v], build_ms[v]);
      records.add("penetration_boundary_spheres_mm", kMillimetresPerMetre * penetration[v][0]);
      records.add("penetration_every_particle_spheres_mm", kMillimetresPerMetre * penetration[v][1]);
      records.end();
      std::printf("collision_particles %-15s %6d spheres: frame %.1f ms, collision %.1f ms/frame, max bone "
                  "penetration %.2f mm (boundary spheres) / %.2f mm (every-particle spheres)\n",
                  names[v], simulations[v]->pipeline().collisionWorld()->muscleSphereCount(),
                  bench::median(column(played_in_turn[v], &FrameRecord::wall_ms)),
                  bench::median(statColumn(played_in_turn[v],
                                           [](const FrameStats& s) { return s.solver.collision_ms; })),
                  kMillimetresPerMetre * penetration[v][0], kMillimetresPerMetre * penetration[v][1]);
    }
    progress.finished("collision_particles", static_cast<double>(frame_count) * 2 * thigh13_muscles);
  }

  // (d) Skipping unchanged poses: the check's cost against a solve, and how many messages realistic streams skip.
  {
    const std::vector<Eigen::Vector3d> centroids = boneRestCentroids(all.scene.bones);
    std::vector<BoneTransforms> recorded;
    for (std::size_t f = 0; f < all.gait.frames.size(); ++f)
      recorded.push_back(boneTransformsOf(all.scene.bones, gaitPose(all, f)));
    // The check itself, timed over many calls (one is far below the clock's resolution).
    const int calls = options.quick ? 20000 : 200000;
    std::vector<double> per_call_ms;
    double sink = 0;
    for (int r = 0; r < 7; ++r)
      per_call_ms.push_back(bench::millisecondsOf([&] {
                              for (int c = 0; c < calls; ++c)
                                sink += largestBoneMotion(recorded[static_cast<std::size_t>(c) % recorded.size()],
                                                          recorded[(static_cast<std::size_t>(c) + 1) % recorded.size()],
                                                          centroids)
                                            .translation_m;
                            }) /
                            calls);
    const double check_ms = bench::median(per_call_ms);
    std::printf("unchanged_pose check: %.2f us per pose (%zu bones; checksum %.3g)\n", 1e3 * check_ms,
                centroids.size(), sink);

    struct Stream {
      std::string name;
      std::vector<std::size_t> frames;  // recorded frame of each message
    };
    std::vector<Stream> streams;
    const std::size_t cycle = recorded.size();
    Stream as_recorded{"gait_as_recorded", {}};
    for (std::size_t f = 0; f < cycle; ++f) as_recorded.frames.push_back(f);
    streams.push_back(as_recorded);
    for (const std::size_t repeat : {std::size_t{2}, std::size_t{4}}) {
      Stream republished{"gait_republished_" + std::to_string(repeat) + "x", {}};
      for (std::size_t f = 0; f < cycle; ++f)
        for (std::size_t k = 0; k < repeat; ++k) republished.frames.push_back(f);
      streams.push_back(republished);
    }
    Stream held = as_recorded;
    held.name = "gait_then_held_one_cycle";
    for (std::size_t k = 0; k < cycle; ++k) held.frames.push_back(cycle - 1);
    streams.push_back(held);

    const std::pair<std::string, double> solves[] = {{"all_26", all_26_frame_ms}, {"thigh13", thigh13_frame_ms}};
    for (const auto& [muscles, solve_ms] : solves) {
      for (const Stream& stream : streams) {
        std::size_t skipped = 0;
        const BoneTransforms* previous_solved = nullptr;
        for (const std::size_t f : stream.frames) {
          if (previous_solved) {
            const BoneMotion motion = largestBoneMotion(*previous_solved, recorded[f], centroids);
            if (motion.translation_m <= defaults.stream.poses.unchanged_translation_m &&
                motion.rotation_rad <= defaults.stream.poses.unchanged_rotation_rad) {
              ++skipped;
              continue;
            }
          }
          previous_solved = &recorded[f];
        }
        const double messages = static_cast<double>(stream.frames.size());
        const double solved = messages - static_cast<double>(skipped);
        const double with_check_ms = (solved * solve_ms + messages * check_ms) / messages;
        records.begin();
        records.add("economy", std::string("unchanged_pose"));
        records.add("variant", stream.name + "_" + muscles);
        records.add("frame_ms", with_check_ms);
        records.add("frame_ms_without_check", solve_ms);
        records.add("check_ms", check_ms);
        records.add("solve_ms", solve_ms);
        records.add("messages", messages);
        records.add("solved", solved);
        records.add("skipped", static_cast<double>(skipped));
        records.add("unchanged_translation_m", defaults.stream.poses.unchanged_translation_m);
        records.add("unchanged_rotation_rad", defaults.stream.poses.unchanged_rotation_rad);
        records.end();
        std::printf("unchanged_pose %-26s %-7s %4.0f messages, %4zu skipped: %.1f ms per message with the check, "
                    "%.1f without\n",
                    stream.name.c_str(), muscles.c_str(), messages, skipped, with_check_ms, solve_ms);
      }
    }
  }

  std::printf("economy done in %.0f s\n", progress.elapsedSeconds());
  return bench::finish(records, options, "economy.json");
}
