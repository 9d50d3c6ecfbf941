// Real time against accuracy on the bundled scene (all 26 muscles, and thigh13), 20 particles per fibre, the node's
// model and collision settings: the 1-cycle gait streamed frame by frame as the node does, and single poses solved
// cold. Frame time is the solve (mass-spring system and collision), wall clock.
//
// References, converged by a force residual where the model allows it:
//   stream: the converged stream. Frame 0 is solved cold, every later frame from the previous reference frame moved
//           with the bones, each with kReferenceSweeps block-descent sweeps (two threads). Every compared stream starts
//           from reference frame 0, so frames 1.. measure what a configuration does with one frame's time from the
//           history it made itself.
//   cold:   five gait poses (paper frames), each with 2 x kReferenceSweeps sweeps from its rigid pre-transform.
// How converged the references are is measured and written too: their force residual, and how far a reference frame
// still moves when given as many sweeps again.
//
// Every state is also measured by one common yardstick, the relative RMS net force on the free particles under the
// springs and the block-descent contact energy (BlockDescentSolver::residualOf), whichever solver produced it.
//
// Writes out/bench/realtime.json: one object per (scene, mode, configuration) with the keys the real-time issue asks
// for, plus the references' own figures (solver "reference").
//
//   realtime_bench [--out DIR] [--quick]
#include "bench_util.hpp"
#include "convergence_run.hpp"
#include "gait_stream.hpp"
#include "node_defaults.hpp"

#include "muscle_deformation/core/pipeline/simulation.hpp"
#include "muscle_deformation/core/solvers/block_descent_solver.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

using namespace muscle_deformation;

namespace {

struct Config {
  std::string label;
  SolverKind kind = SolverKind::block_descent;
  StoppingRule rule = StoppingRule::iterations;
  int max_iterations = 1;
  double time_budget_ms = 0;
  int lbfgs_history = 0;
  int threads = 1;
  bool node_default = false;
};

SimulationSettings settingsFor(const SimulationSettings& defaults, const Config& config) {
  SimulationSettings settings = defaults;
  settings.solver_kind = config.kind;
  settings.stopping.rule = config.rule;
  settings.stopping.max_iterations = config.max_iterations;
  settings.stopping.time_budget_ms = config.time_budget_ms;
  settings.stopping.limits = {};
  shareStoppingRule(settings);
  settings.local_global.lbfgs_history = config.lbfgs_history;
  settings.block_descent.threads = config.threads;
  return settings;
}

Config blockDescent(int sweeps, int threads) {
  Config config;
  config.label = "block_descent " + std::to_string(sweeps) + (sweeps == 1 ? " sweep" : " sweeps");
  config.max_iterations = sweeps;
  config.threads = threads;
  return config;
}

struct Measured {
  double frame_ms = 0;
  double rms_mm = 0;
  double bone_penetration_mm = 0;
  double residual = 0;  // common yardstick
  int iterations = 0;
};

// The common yardstick (residualOf) for one simulation's states, with the simulation's own contacts.
BlockDescentSolver yardstickFor(const MuscleSimulation& simulation, const BlockDescentSettings& settings) {
  BlockDescentSolver yardstick(simulation.system(), settings);
  const CollisionWorld* world = simulation.collisionWorld();
  // The query refreshes the world's broad-phase caches only; MuscleSimulation hands out the world read-only.
  yardstick.setContactQuery(
      [world](const ParticleState& state, double margin_m, ContactSet& contacts) {
        const_cast<CollisionWorld*>(world)->findContacts(state, contacts, margin_m);
      },
      world->everyParticleCollides());
  return yardstick;
}

// One solved frame or pose against its reference.
Measured measured(MuscleSimulation& simulation, const FrameStats& stats, const Eigen::Matrix3Xd& reference,
                  BlockDescentSolver& yardstick) {
  Measured m;
  m.frame_ms = stats.solver.total_ms;
  m.rms_mm = bench::rmsMillimetres(simulation.state().position, reference);
  m.bone_penetration_mm = stats.collision.max_penetration_muscle_bone_m * 1e3;
  m.iterations = stats.solver.iterations;
  m.residual = yardstick.residualOf(simulation.state());
  return m;
}

struct Summary {
  double frame_ms_median = 0, frame_ms_max = 0, rms_mm_mean = 0, rms_mm_max = 0, bone_penetration_max_mm = 0;
  double iterations_mean = 0, residual_median = 0;
};

Summary summarise(const std::vector<Measured>& rows) {
  Summary s;
  std::vector<double> times, residuals;
  for (const Measured& m : rows) {
    times.push_back(m.frame_ms);
    residuals.push_back(m.residual);
    s.frame_ms_max = std::max(s.frame_ms_max, m.frame_ms);
    s.rms_mm_mean += m.rms_mm / static_cast<double>(rows.size());
    s.rms_mm_max = std::max(s.rms_mm_max, m.rms_mm);
    s.bone_penetration_max_mm = std::max(s.bone_penetration_max_mm, m.bone_penetration_mm);
    s.iterations_mean += m.iterations / static_cast<double>(rows.size());
  }
  s.frame_ms_median = bench::median(times);
  s.residual_median = bench::median(residuals);
  return s;
}

double elapsedSeconds() {
  static const auto start = std::chrono::steady_clock::now();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

void record(bench::JsonRecords& records, const std::string& scene, const std::string& mode, const Config& config,
            const Summary& s, int particles) {
  records.begin();
  records.add("scene", scene);
  records.add("mode", mode);
  records.add("solver", toString(config.kind));
  records.add("configuration", config.label);
  records.add("threads", static_cast<double>(config.threads));
  records.add("iterations", s.iterations_mean);
  records.add("frame_ms_median", s.frame_ms_median);
  records.add("frame_ms_max", s.frame_ms_max);
  records.add("rms_mm_mean", s.rms_mm_mean);
  records.add("rms_mm_max", s.rms_mm_max);
  records.add("bone_penetration_max_mm", s.bone_penetration_max_mm);
  records.add("residual_median", s.residual_median);
  records.add("node_default", config.node_default ? 1.0 : 0.0);
  records.add("particles", static_cast<double>(particles));
  records.end();
  std::printf("[%6.1f s] %-7s %-6s %-34s threads %d: frame %6.1f ms median, %6.1f max; RMS to reference %.3f mean, "
              "%.3f max mm; bone penetration %.2f mm; residual %.2e; %.1f iterations%s\n",
              elapsedSeconds(), scene.c_str(), mode.c_str(), config.label.c_str(), config.threads, s.frame_ms_median,
              s.frame_ms_max, s.rms_mm_mean, s.rms_mm_max, s.bone_penetration_max_mm, s.residual_median,
              s.iterations_mean, config.node_default ? " (node default)" : "");
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  const int reference_sweeps = options.quick ? 60 : 300;
  bench::JsonRecords records;
  const bench::NodeDefaults node = bench::loadNodeDefaults();
  const SimulationSettings& defaults = node.simulation;
  elapsedSeconds();

  // The configurations compared, the node's defaults among them (config/muscle_deformation.yaml).
  Config node_default;
  node_default.label = "node default: " + toString(defaults.solver_kind) + " " +
                       (defaults.stopping.rule == StoppingRule::time_budget
                            ? "budget " + std::to_string(static_cast<int>(defaults.stopping.time_budget_ms)) + " ms"
                            : std::to_string(defaults.stopping.max_iterations) + " iterations");
  node_default.kind = defaults.solver_kind;
  node_default.rule = defaults.stopping.rule;
  node_default.max_iterations = defaults.stopping.max_iterations;
  node_default.time_budget_ms = defaults.stopping.time_budget_ms;
  node_default.lbfgs_history = defaults.local_global.lbfgs_history;
  node_default.threads = defaults.block_descent.threads;
  node_default.node_default = true;
  std::vector<Config> stream_configs;
  {
    Config verlet;
    verlet.label = "verlet 30 iterations";
    verlet.kind = SolverKind::verlet;
    verlet.max_iterations = 30;
    stream_configs.push_back(verlet);
    for (const int sweeps : {1, 2, 4})
      for (const int threads : {1, 2}) stream_configs.push_back(blockDescent(sweeps, threads));
    stream_configs.push_back(node_default);
  }
  std::vector<Config> cold_configs;
  {
    for (const int sweeps : {10, 30, 100}) cold_configs.push_back(blockDescent(sweeps, 0));
    Config service;
    service.label = "local_global lbfgs16 120 iterations";
    service.kind = SolverKind::local_global;
    service.max_iterations = 120;
    service.lbfgs_history = 16;
    service.node_default = true;  // the service's defaults (service_solver, service_lbfgs_history, ..._max_iterations)
    cold_configs.push_back(service);
  }

  for (const std::string scene_name : {"all_26", "thigh13"}) {
    const BundledScene bundled =
        loadBundledScene(MD_PACKAGE_DIR, scene_name == "all_26" ? std::vector<std::string>{} : std::vector<std::string>{"thigh13"});
    const std::size_t frame_count = options.quick ? 8 : bundled.gait.frames.size();

    // ----- stream -----
    Config reference_config = blockDescent(reference_sweeps, 0);
    reference_config.label = "reference";
    std::vector<Eigen::Matrix3Xd> reference;
    std::vector<BoneTransforms> transforms;
    std::vector<double> reference_residuals;
    double reference_moves_mm = 0;  // largest RMS a reference frame still moves with as many sweeps again
    int particles = 0;
    {
      MuscleSimulation simulation(bundled.scene.muscles, bundled.scene.bones, settingsFor(defaults, reference_config));
      particles = static_cast<int>(simulation.system().particleCount());
      for (std::size_t f = 0; f < frame_count; ++f) {
        transforms.push_back(boneTransformsOf(simulation.bones(), gaitPose(bundled, f)));
        const FrameStats stats = simulation.solve(transforms.back(), f == 0 ? StartMode::cold : StartMode::warm);
        reference.push_back(simulation.state().position);
        reference_residuals.push_back(stats.solver.residual);
      }
      // How settled the references are: a few frames given as many sweeps again.
      for (const std::size_t f : {frame_count / 4, frame_count / 2, (3 * frame_count) / 4}) {
        if (f == 0) continue;
        simulation.continueFrom(transforms[f - 1], reference[f - 1]);
        simulation.solve(transforms[f], StartMode::warm);  // reproduces reference[f]
        simulation.continueFrom(transforms[f], simulation.state().position);
        simulation.solve(transforms[f], StartMode::warm);  // as many sweeps again
        reference_moves_mm = std::max(reference_moves_mm, bench::rmsMillimetres(simulation.state().position, reference[f]));
      }
      std::printf("[%6.1f s] %s: %d particles, stream reference of %zu frames, %d sweeps each: residual median %.2e, "
                  "max %.2e; a frame given as many sweeps again moves up to %.2f mm RMS\n",
                  elapsedSeconds(), scene_name.c_str(), particles, frame_count, reference_sweeps,
                  bench::median(reference_residuals),
                  *std::max_element(reference_residuals.begin(), reference_residuals.end()), reference_moves_mm);
      records.begin();
      records.add("scene", scene_name);
      records.add("mode", "stream");
      records.add("solver", "reference");
      records.add("reference_sweeps", reference_sweeps);
      records.add("frames", static_cast<double>(frame_count));
      records.add("reference_residual_median", bench::median(reference_residuals));
      records.add("reference_residual_max", *std::max_element(reference_residuals.begin(), reference_residuals.end()));
      records.add("reference_moves_mm", reference_moves_mm);
      records.add("particles", static_cast<double>(particles));
      records.end();
    }

    for (const Config& config : stream_configs) {
      MuscleSimulation simulation(bundled.scene.muscles, bundled.scene.bones, settingsFor(defaults, config));
      BlockDescentSolver yardstick = yardstickFor(simulation, defaults.block_descent);
      simulation.continueFrom(transforms[0], reference[0]);
      bench::GaitStream stream(simulation.bones(), node.stream);
      stream.solved(0, transforms[0]);
      std::vector<Measured> rows;
      for (std::size_t f = 1; f < frame_count; ++f) {
        const StartMode start = stream.start(f, transforms[f]);
        rows.push_back(measured(simulation, simulation.solve(transforms[f], start), reference[f], yardstick));
        stream.solved(f, transforms[f]);
      }
      record(records, scene_name, "stream", config, summarise(rows), particles);
    }

    // ----- cold single poses -----
    const std::vector<std::size_t> poses = options.quick ? std::vector<std::size_t>{fiveGaitFrames(bundled)[2]}
                                                         : fiveGaitFrames(bundled);
    std::vector<Eigen::Matrix3Xd> cold_reference;
    {
      Config cold_reference_config = blockDescent(2 * reference_sweeps, 0);
      MuscleSimulation simulation(bundled.scene.muscles, bundled.scene.bones, settingsFor(defaults, cold_reference_config));
      std::vector<double> residuals;
      for (const std::size_t f : poses) {
        const FrameStats stats = simulation.solve(gaitPose(bundled, f), StartMode::cold);
        cold_reference.push_back(simulation.state().position);
        residuals.push_back(stats.solver.residual);
      }
      records.begin();
      records.add("scene", scene_name);
      records.add("mode", "cold");
      records.add("solver", "reference");
      records.add("reference_sweeps", 2 * reference_sweeps);
      records.add("frames", static_cast<double>(poses.size()));
      records.add("reference_residual_median", bench::median(residuals));
      records.add("reference_residual_max", *std::max_element(residuals.begin(), residuals.end()));
      records.add("particles", static_cast<double>(particles));
      records.end();
    }
    for (const Config& config : cold_configs) {
      MuscleSimulation simulation(bundled.scene.muscles, bundled.scene.bones, settingsFor(defaults, config));
      BlockDescentSolver yardstick = yardstickFor(simulation, defaults.block_descent);
      std::vector<Measured> rows;
      for (std::size_t k = 0; k < poses.size(); ++k)
        rows.push_back(measured(simulation, simulation.solve(gaitPose(bundled, poses[k]), StartMode::cold),
                                cold_reference[k], yardstick));
      record(records, scene_name, "cold", config, summarise(rows), particles);
    }
  }

  const std::string path = options.out_dir + "/realtime.json";
  if (!records.write(path)) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    return 1;
  }
  std::printf("[%6.1f s] wrote %s\n", elapsedSeconds(), path.c_str());
  return 0;
}
