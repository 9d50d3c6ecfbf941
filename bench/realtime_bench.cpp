// Real time against accuracy on the bundled scene (all 26 muscles, and thigh13), 20 particles per fibre, the node's
// model and collision settings: the 1-cycle gait streamed frame by frame as the node does (the core's StreamSession
// with the node's stream settings: warm, cold at a discontinuity, a pose no bone moved in not solved again, a reset
// after a failed frame), and single poses solved cold. Frame time is the solve (mass-spring system and collision),
// wall clock.
//
// What a frame's answer is (block_descent_solver.hpp): the minimiser of the springs, contacts and tissue drag towards
// where the tissue carries each particle (the previous answer moved with the bones; cold: the rigid pre-transform).
// References:
//   stream: the converged stream. Frame 0 is solved cold, every later frame from the previous reference frame, each
//           with kReferenceSweeps block-descent sweeps. Every compared stream starts from reference frame 0, so frames
//           1.. measure what a configuration does with one frame's time from the history it made itself.
//   cold:   five gait poses (paper frames), each with 2 x kReferenceSweeps sweeps from its rigid pre-transform.
// How converged the references are is measured and written too: their force residual, how far the same frame ends
// with twice the sweeps from another start, and how far the Newton-Krylov solver's answer of the same frame from the
// same start lies from it (a global solver against the local sweeps: the frame has one answer).
//
// Every state is also measured by one common yardstick, the relative RMS net force on the free particles under the
// springs, the block-descent contact energy and the node's tissue drag (BlockDescentSolver::residualOf), whichever
// solver produced it; solvers without drag are judged by the same yardstick. It has no volume term, so for the node's
// model it counts the muscles' volume pressure as an imbalance: the references also record their own residual (with
// the volume term, the one the residual criterion applies to).
//
// Writes out/bench/realtime.json: one object per (scene, mode, configuration) with the keys the real-time issue asks
// for, plus the references' own figures (solver "reference") and the solver agreement (solver "agreement").
//
//   realtime_bench [--out DIR] [--quick]
#include "bench_util.hpp"
#include "convergence_run.hpp"
#include "machine_floor.hpp"
#include "node_defaults.hpp"
#include "stream_play.hpp"

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/solvers/block_descent_solver.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>
#include <vector>

using namespace muscle_deformation;

namespace {

struct Config {
  std::string label;
  SolverKind kind = SolverKind::block_descent;
  StoppingRule rule = StoppingRule::iterations;
  int max_iterations = 1;
  double time_budget_ms = 0;
  double residual_tolerance = 0;  // force_residual rule
  int lbfgs_history = 0;
  int threads = 1;
  double tissue_relaxation_s = -1;  // < 0: the node's
  bool predict_start = true;
  bool node_default = false;
};

// A configuration as the node would run it: the node's pipeline (particles only) and frame stopping (its cold-start
// iterations and deep-contact sweeps) with the configuration's solver, rule and threads.
struct Setup {
  PipelineSettings pipeline;
  FrameStopping stopping;
  const SimulationSettings& simulation() const { return pipeline.simulation; }
};

Setup setupFor(const CoreSettings& node, const Config& config) {
  Setup setup;
  setup.pipeline = bench::particlesOnly(node.pipeline);
  SimulationSettings& settings = setup.pipeline.simulation;
  settings.solver_kind = config.kind;
  setup.stopping = node.stream.stopping;
  StoppingSettings& sweeps = setup.stopping.sweeps;
  sweeps.rule = config.rule;
  sweeps.max_iterations = config.max_iterations;
  sweeps.time_budget_ms = config.time_budget_ms;
  sweeps.limits = {};
  if (config.rule == StoppingRule::force_residual) sweeps.residual_tolerance = config.residual_tolerance;
  settings.local_global.lbfgs_history = config.lbfgs_history;
  setup.pipeline.threads = config.threads;
  if (config.tissue_relaxation_s >= 0) settings.block_descent.tissue_relaxation_s = config.tissue_relaxation_s;
  // The across-fibre tie rides on the drag (it shares its frame anchor): a configuration without the drag has no tie
  // either, as the former default had neither.
  if (!(settings.block_descent.tissue_relaxation_s > 0)) settings.block_descent.across_fibre_tie = 0;
  settings.prediction.predict_start = config.predict_start;
  return setup;
}

std::unique_ptr<DeformationPipeline> pipelineFor(const BundledScene& bundled, const Setup& setup,
                                                 const BoneFields& bone_fields = {}) {
  return std::make_unique<DeformationPipeline>(bundled.scene.muscle_descriptions, bundled.scene.muscles,
                                               bundled.scene.bones, setup.pipeline, bone_fields);
}

// Block descent with the node's tissue drag and predicted start.
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
  double sweep_ms = 0;  // the frame's solve time in its sweeps over their count (block descent; 0 otherwise)
  BlockDescentSolver::SweepCost sweep_cost;
};

// The common yardstick (residualOf) for one pipeline's states, with the pipeline's own contacts and the node's
// tissue drag.
BlockDescentSolver yardstickFor(const DeformationPipeline& pipeline, const BlockDescentSettings& settings) {
  BlockDescentSolver yardstick(pipeline.system(), settings);
  const CollisionWorld* world = pipeline.collisionWorld();
  // The query refreshes the world's broad-phase caches only; the pipeline hands out the world read-only.
  yardstick.setContactQuery(
      [world](const ParticleState& state, double margin_m, ContactSet& contacts) {
        const_cast<CollisionWorld*>(world)->findContacts(state, contacts, margin_m);
      },
      world->everyParticleCollides());
  return yardstick;
}

// What the reference's frame was given besides the bones: where the tissue carried the particles and, with the
// across-fibre tie, where the bones carried the rest shape and the rest balance turned with them (the reference's own
// problem, whatever the configuration solved; empty where the model has none).
struct FrameInputs {
  Eigen::Matrix3Xd carried, rest_carried, rest_balance;
  static FrameInputs of(const ParticleState& state) {
    return {state.carried_position, state.rest_carried_position, state.rest_balance_force};
  }
};

// One solved frame or pose against its reference, its residual judged on the reference's frame inputs.
Measured measured(const DeformationPipeline& pipeline, const FrameStats& stats, const Eigen::Matrix3Xd& reference,
                  const FrameInputs& inputs, BlockDescentSolver& yardstick) {
  Measured m;
  m.frame_ms = stats.solve_ms;
  m.rms_mm = bench::rmsMillimetres(pipeline.state().position, reference);
  m.bone_penetration_mm = stats.collision.max_penetration_muscle_bone_m * 1e3;
  m.iterations = stats.solver.iterations;
  ParticleState judged = pipeline.state();
  judged.carried_position = inputs.carried;
  judged.rest_carried_position = inputs.rest_carried;
  judged.rest_balance_force = inputs.rest_balance;
  m.residual = yardstick.residualOf(judged);
  if (pipeline.settings().simulation.solver_kind == SolverKind::block_descent && stats.solver.iterations > 0) {
    m.sweep_ms = stats.solver.mss_ms / stats.solver.iterations;
    m.sweep_cost = yardstick.sweepCost(judged);
  }
  return m;
}

struct Summary {
  double frame_ms_median = 0, frame_ms_max = 0, rms_mm_mean = 0, rms_mm_max = 0, bone_penetration_max_mm = 0;
  double iterations_mean = 0, residual_median = 0;
  double sweep_ms_median = 0, sweep_bytes_median = 0, sweep_flops_median = 0;  // 0: not a block-descent configuration
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
  std::vector<double> sweep_ms, bytes, flops;
  for (const Measured& m : rows)
    if (m.sweep_ms > 0) {
      sweep_ms.push_back(m.sweep_ms);
      bytes.push_back(m.sweep_cost.bytes);
      flops.push_back(m.sweep_cost.flops);
    }
  if (!sweep_ms.empty()) {
    s.sweep_ms_median = bench::median(sweep_ms);
    s.sweep_bytes_median = bench::median(bytes);
    s.sweep_flops_median = bench::median(flops);
  }
  return s;
}

double elapsedSeconds() {
  static const auto start = std::chrono::steady_clock::now();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// The machine's floor on one thread and on every core, measured once at the start of the run.
const bench::MachineFloor& machineFloor(int threads) {
  static const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  static const bench::MachineFloor one = bench::measureMachineFloor(1);
  static const bench::MachineFloor every = bench::measureMachineFloor(cores);
  return threads == 1 ? one : every;
}

void record(bench::JsonRecords& records, const std::string& scene, const std::string& mode, const Config& config,
            const SimulationSettings& settings, const Summary& s, int particles) {
  const bool drag = measuresForceResidual(config.kind) && settings.block_descent.tissue_relaxation_s > 0;
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
  records.add("tissue_relaxation_s", drag ? settings.block_descent.tissue_relaxation_s : 0.0);
  records.add("predict_start", drag && settings.prediction.predict_start ? 1.0 : 0.0);
  records.add("node_default", config.node_default ? 1.0 : 0.0);
  records.add("particles", static_cast<double>(particles));
  // Threads 0 = every core (as the node's default); kThreadsMeasured also sweeps on every core when it pays.
  const bench::MachineFloor& floor = machineFloor(config.threads);
  double roofline_ratio = 0;
  if (s.sweep_ms_median > 0) {
    roofline_ratio = s.sweep_ms_median / floor.floorMilliseconds(s.sweep_bytes_median, s.sweep_flops_median);
    records.add("sweep_ms", s.sweep_ms_median);
    records.add("sweep_bytes", s.sweep_bytes_median);
    records.add("sweep_flops", s.sweep_flops_median);
    records.add("bandwidth_gbs", floor.bandwidth_gbs);
    records.add("gflops", floor.gflops);
    records.add("floor_threads", floor.threads);
    records.add("roofline_ratio", roofline_ratio);
  }
  records.end();
  if (roofline_ratio > 0)
    std::printf("[%6.1f s]   sweep %.2f ms median: %.2f MB, %.1f Mflop; machine on %d threads %.1f GB/s, %.1f Gflop/s: "
                "%.1fx its floor\n", elapsedSeconds(), s.sweep_ms_median, 1e-6 * s.sweep_bytes_median,
                1e-6 * s.sweep_flops_median, floor.threads, floor.bandwidth_gbs, floor.gflops, roofline_ratio);
  std::printf("[%6.1f s] %-7s %-6s %-44s threads %d: frame %6.1f ms median, %6.1f max; RMS to reference %.3f mean, "
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
  const CoreSettings node = bench::loadNodeDefaults();
  const StoppingSettings& node_sweeps = node.stream.stopping.sweeps;
  elapsedSeconds();
  for (const int threads : {1, 0}) {
    const bench::MachineFloor& floor = machineFloor(threads);
    std::printf("[%6.1f s] machine on %d thread(s): triad %.1f GB/s, multiply-add %.1f Gflop/s\n", elapsedSeconds(),
                floor.threads, floor.bandwidth_gbs, floor.gflops);
  }

  // The configurations compared, the node's defaults among them (config/muscle_deformation.yaml).
  Config node_default;
  node_default.label = "node default: " + toString(node.pipeline.simulation.solver_kind) + " " +
                       (node_sweeps.rule == StoppingRule::time_budget
                            ? "budget " + std::to_string(static_cast<int>(node_sweeps.time_budget_ms)) + " ms"
                            : std::to_string(node_sweeps.max_iterations) + " iterations");
  node_default.kind = node.pipeline.simulation.solver_kind;
  node_default.rule = node_sweeps.rule;
  node_default.max_iterations = node_sweeps.max_iterations;
  node_default.time_budget_ms = node_sweeps.time_budget_ms;
  node_default.lbfgs_history = node.pipeline.simulation.local_global.lbfgs_history;
  node_default.threads = node.pipeline.threads;
  node_default.predict_start = node.pipeline.simulation.prediction.predict_start;
  node_default.node_default = true;
  std::vector<Config> stream_configs;
  {
    Config verlet;
    verlet.label = "verlet 30 iterations (former default)";
    verlet.kind = SolverKind::verlet;
    verlet.max_iterations = 30;
    stream_configs.push_back(verlet);
    Config quasi_static = blockDescent(1, 0);
    quasi_static.label = "block_descent 1 sweep, no drag (former default)";
    quasi_static.tissue_relaxation_s = 0;
    stream_configs.push_back(quasi_static);
    Config unpredicted = blockDescent(1, 2);
    unpredicted.label = "block_descent 1 sweep, drag, start not predicted";
    unpredicted.predict_start = false;
    stream_configs.push_back(unpredicted);
    for (const int sweeps : {1, 2})
      for (const int threads : {1, 2}) stream_configs.push_back(blockDescent(sweeps, threads));
    stream_configs.push_back(node_default);
  }
  std::vector<Config> cold_configs;
  {
    for (const int sweeps : {10, 20, 30}) {
      Config config = blockDescent(sweeps, 0);
      // The service's defaults (service_solver, service_max_iterations in config/muscle_deformation.yaml; the node
      // caps a call's threads so that the stream keeps a core, which this single-pose bench does not need).
      config.node_default = sweeps == 20;
      cold_configs.push_back(config);
    }
    Config service;
    service.label = "local_global lbfgs16 120 iterations, no drag (former service default)";
    service.kind = SolverKind::local_global;
    service.max_iterations = 120;
    service.lbfgs_history = 16;
    cold_configs.push_back(service);
  }

  for (const std::string scene_name : {"all_26", "thigh13"}) {
    const BundledScene bundled =
        loadBundledScene(MD_PACKAGE_DIR, scene_name == "all_26" ? std::vector<std::string>{} : std::vector<std::string>{"thigh13"});
    const std::size_t frame_count = options.quick ? 8 : bundled.gait.frames.size();

    // ----- stream -----
    Config reference_config = blockDescent(reference_sweeps, 0);
    reference_config.label = "reference";
    const Setup reference_setup = setupFor(node, reference_config);
    const SimulationSettings& reference_settings = reference_setup.simulation();
    std::vector<Eigen::Matrix3Xd> reference;
    std::vector<FrameInputs> carried;
    std::vector<BoneTransforms> transforms;
    std::vector<double> reference_residuals;
    // The reference's residual as its own solve measures it at its last sweep: with the muscles' volume term, whose
    // pressure the yardstick leaves out (it judges solvers that have none), so the yardstick's figure for a model with
    // the volume term includes that pressure as an imbalance.
    std::vector<double> reference_own_residuals;
    double reference_moves_mm = 0;  // largest RMS between a reference frame and the same frame given twice the sweeps
    int particles = 0;
    {
      // The reference is no stream of the node: every frame warm from the previous reference frame, whatever moved.
      const std::unique_ptr<DeformationPipeline> simulation = pipelineFor(bundled, reference_setup);
      BlockDescentSolver yardstick = yardstickFor(*simulation, reference_settings.block_descent);
      particles = static_cast<int>(simulation->system().particleCount());
      for (std::size_t f = 0; f < frame_count; ++f) {
        transforms.push_back(boneTransformsOf(simulation->bones(), gaitPose(bundled, f)));
        const FrameResult& frame = simulation->solve(
            transforms.back(), f == 0 ? StartMode::cold : StartMode::warm, reference_setup.stopping, false, false);
        reference.push_back(simulation->state().position);
        carried.push_back(FrameInputs::of(simulation->state()));
        reference_residuals.push_back(yardstick.residualOf(simulation->state()));
        reference_own_residuals.push_back(frame.stats.solver.residual);
      }
      // How settled the references are: a few frames given as many sweeps again, and the same frames solved from the
      // same start by the Newton-Krylov solver (a global method; the sweeps are local).
      Config newton_config = reference_config;
      newton_config.kind = SolverKind::newton_krylov;
      newton_config.rule = StoppingRule::force_residual;
      newton_config.residual_tolerance = 1e-3;
      // Up to 94 steps measured on a thigh13 gait frame (its residual 6.8e-4, 99 s); at 40 two of three frames stopped
      // unconverged.
      newton_config.max_iterations = options.quick ? 10 : 120;
      const Setup newton_setup = setupFor(node, newton_config);
      const std::unique_ptr<DeformationPipeline> newton = pipelineFor(bundled, newton_setup, simulation->boneFields());
      const Setup twice_setup = setupFor(node, blockDescent(2 * reference_sweeps, 0));
      const std::unique_ptr<DeformationPipeline> twice = pipelineFor(bundled, twice_setup, simulation->boneFields());
      // Per frame: the distance of Newton-Krylov's answer to the reference, whether it met its own tolerance (a
      // distance to a solve that did not converge says little), its own residual and the common yardstick's.
      std::vector<double> agreement_rms, agreement_max, newton_residual, newton_ms;
      std::vector<double> converged_rms, converged_max;
      int converged_frames = 0;
      for (const std::size_t f : {frame_count / 4, frame_count / 2, (3 * frame_count) / 4}) {
        if (f == 0) continue;
        // The same frame problem (the tissue carrying the previous reference frame) with twice the sweeps, from the
        // unpredicted start.
        twice->continueFrom(transforms[f - 1], reference[f - 1]);
        twice->solve(transforms[f], StartMode::warm, twice_setup.stopping, false, false);
        reference_moves_mm = std::max(reference_moves_mm, bench::rmsMillimetres(twice->state().position, reference[f]));
        newton->continueFrom(transforms[f - 1], reference[f - 1]);
        const FrameStats stats = newton->solve(transforms[f], StartMode::warm, newton_setup.stopping, false, false).stats;
        agreement_rms.push_back(bench::rmsMillimetres(newton->state().position, reference[f]));
        agreement_max.push_back(1e3 * (newton->state().position - reference[f]).colwise().norm().maxCoeff());
        newton_residual.push_back(yardstick.residualOf(newton->state()));
        newton_ms.push_back(stats.solve_ms);
        // Converged: the force residual where the solve ended below the tolerance (SolveStats::converged).
        if (stats.solver.converged) {
          ++converged_frames;
          converged_rms.push_back(agreement_rms.back());
          converged_max.push_back(agreement_max.back());
        }
        records.begin();
        records.add("scene", scene_name);
        records.add("mode", "stream");
        records.add("solver", "agreement_frame");
        records.add("frame", static_cast<double>(f));
        records.add("newton_iterations", stats.solver.iterations);
        records.add("newton_converged", stats.solver.converged ? 1.0 : 0.0);
        records.add("newton_own_residual", stats.solver.residual);
        records.add("newton_residual", newton_residual.back());
        records.add("newton_rms_mm", agreement_rms.back());
        records.add("newton_max_mm", agreement_max.back());
        records.end();
        std::printf("[%6.1f s]   %s frame %zu: Newton-Krylov %d steps, its residual %.2e (%s), %.3f mm RMS (%.3f max) "
                    "from the reference\n", elapsedSeconds(), scene_name.c_str(), f, stats.solver.iterations,
                    stats.solver.residual, stats.solver.converged ? "converged" : "not converged", agreement_rms.back(),
                    agreement_max.back());
      }
      std::printf("[%6.1f s] %s: %d particles, stream reference of %zu frames, %d sweeps each: residual median %.2e, "
                  "max %.2e (its own, with the volume term: %.2e, %.2e); the same frame given twice the sweeps from another start ends up to %.3f mm RMS from it; Newton-Krylov from the same "
                  "start ends %.3f mm RMS (%.3f max) from it, residual %.2e\n",
                  elapsedSeconds(), scene_name.c_str(), particles, frame_count, reference_sweeps,
                  bench::median(reference_residuals),
                  *std::max_element(reference_residuals.begin(), reference_residuals.end()),
                  bench::median(reference_own_residuals),
                  *std::max_element(reference_own_residuals.begin(), reference_own_residuals.end()), reference_moves_mm,
                  *std::max_element(agreement_rms.begin(), agreement_rms.end()),
                  *std::max_element(agreement_max.begin(), agreement_max.end()),
                  *std::max_element(newton_residual.begin(), newton_residual.end()));
      records.begin();
      records.add("scene", scene_name);
      records.add("mode", "stream");
      records.add("solver", "reference");
      records.add("reference_sweeps", reference_sweeps);
      records.add("frames", static_cast<double>(frame_count));
      records.add("reference_residual_median", bench::median(reference_residuals));
      records.add("reference_residual_max", *std::max_element(reference_residuals.begin(), reference_residuals.end()));
      records.add("reference_own_residual_median", bench::median(reference_own_residuals));
      records.add("reference_own_residual_max",
                  *std::max_element(reference_own_residuals.begin(), reference_own_residuals.end()));
      records.add("reference_moves_mm", reference_moves_mm);
      records.add("tissue_relaxation_s", reference_settings.block_descent.tissue_relaxation_s);
      records.add("particles", static_cast<double>(particles));
      records.end();
      records.begin();
      records.add("scene", scene_name);
      records.add("mode", "stream");
      records.add("solver", "agreement");
      records.add("frames", static_cast<double>(agreement_rms.size()));
      records.add("newton_rms_mm_max", *std::max_element(agreement_rms.begin(), agreement_rms.end()));
      records.add("newton_max_mm", *std::max_element(agreement_max.begin(), agreement_max.end()));
      records.add("newton_residual_max", *std::max_element(newton_residual.begin(), newton_residual.end()));
      records.add("newton_ms_median", bench::median(newton_ms));
      records.add("newton_converged_frames", converged_frames);
      if (!converged_rms.empty()) {
        records.add("newton_converged_rms_mm_max", *std::max_element(converged_rms.begin(), converged_rms.end()));
        records.add("newton_converged_max_mm", *std::max_element(converged_max.begin(), converged_max.end()));
      }
      records.add("newton_iterations_cap", static_cast<double>(newton_config.max_iterations));
      records.end();
    }

    // Each configuration plays the gait through the node's stream protocol (StreamSession, the node's stream settings
    // with the configuration's stopping), from the converged reference frame 0.
    for (const Config& config : stream_configs) {
      const Setup setup = setupFor(node, config);
      StreamSessionSettings stream_settings = node.stream;
      stream_settings.stopping = setup.stopping;
      StreamSession session(bundled.scene.muscle_descriptions, bundled.scene.muscles, bundled.scene.bones,
                            setup.pipeline, stream_settings);
      const DeformationPipeline& pipeline = session.pipeline();
      BlockDescentSolver yardstick = yardstickFor(pipeline, reference_settings.block_descent);
      session.continueFrom(bench::streamStamp(0), transforms[0], reference[0]);
      std::vector<Measured> rows;
      for (std::size_t f = 1; f < frame_count; ++f) {
        const FrameResult* frame = bench::frameOf(session.offer(bench::streamStamp(f), transforms[f], FrameWants{}));
        if (!frame) continue;  // no bone moved: the node solves nothing (StreamCounters::unchanged)
        // Judged against the reference frame's problem: the tissue carrying the reference's previous frame.
        rows.push_back(measured(pipeline, frame->stats, reference[f], carried[f], yardstick));
      }
      const StreamCounters& counters = session.counters();
      if (counters.unchanged > 0 || counters.refined > 0 || counters.resets > 0)
        std::printf("[%6.1f s]   %s %s: of %u poses the stream left %u unchanged, refined %u, restarted %u times\n",
                    elapsedSeconds(), scene_name.c_str(), config.label.c_str(), counters.offered, counters.unchanged,
                    counters.refined, counters.resets);
      record(records, scene_name, "stream", config, setup.simulation(), summarise(rows), particles);
    }

    // ----- cold single poses -----
    const std::vector<std::size_t> poses = options.quick ? std::vector<std::size_t>{fiveGaitFrames(bundled)[2]}
                                                         : fiveGaitFrames(bundled);
    std::vector<Eigen::Matrix3Xd> cold_reference;
    std::vector<FrameInputs> cold_carried;
    {
      const Setup setup = setupFor(node, blockDescent(2 * reference_sweeps, 0));
      const std::unique_ptr<DeformationPipeline> simulation = pipelineFor(bundled, setup);
      BlockDescentSolver yardstick = yardstickFor(*simulation, setup.simulation().block_descent);
      std::vector<double> residuals, own_residuals;
      for (const std::size_t f : poses) {
        const FrameResult& frame = simulation->solve(boneTransformsOf(simulation->bones(), gaitPose(bundled, f)),
                                                     StartMode::cold, setup.stopping, false, false);
        cold_reference.push_back(simulation->state().position);
        cold_carried.push_back(FrameInputs::of(simulation->state()));
        residuals.push_back(yardstick.residualOf(simulation->state()));
        own_residuals.push_back(frame.stats.solver.residual);
      }
      records.begin();
      records.add("scene", scene_name);
      records.add("mode", "cold");
      records.add("solver", "reference");
      records.add("reference_sweeps", 2 * reference_sweeps);
      records.add("frames", static_cast<double>(poses.size()));
      records.add("reference_residual_median", bench::median(residuals));
      records.add("reference_residual_max", *std::max_element(residuals.begin(), residuals.end()));
      records.add("reference_own_residual_median", bench::median(own_residuals));
      records.add("reference_own_residual_max", *std::max_element(own_residuals.begin(), own_residuals.end()));
      records.add("tissue_relaxation_s", setup.simulation().block_descent.tissue_relaxation_s);
      records.add("particles", static_cast<double>(particles));
      records.end();
    }
    for (const Config& config : cold_configs) {
      const Setup setup = setupFor(node, config);
      const std::unique_ptr<DeformationPipeline> simulation = pipelineFor(bundled, setup);
      BlockDescentSolver yardstick = yardstickFor(*simulation, reference_settings.block_descent);
      std::vector<Measured> rows;
      for (std::size_t k = 0; k < poses.size(); ++k) {
        const FrameResult& frame = simulation->solve(boneTransformsOf(simulation->bones(), gaitPose(bundled, poses[k])),
                                                     StartMode::cold, setup.stopping, false, false);
        rows.push_back(measured(*simulation, frame.stats, cold_reference[k], cold_carried[k], yardstick));
      }
      record(records, scene_name, "cold", config, setup.simulation(), summarise(rows), particles);
    }
  }

  std::printf("[%6.1f s] done\n", elapsedSeconds());
  return bench::finish(records, options, "realtime.json");
}
