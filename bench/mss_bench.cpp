// MSS update time per iteration on the synthetic thigh, sized like the GRAPP paper's Table 1 scene:
// 13 muscles x 64 fibres x {20, 40, 60, 80} particles per fibre, 18 nearest-neighbour springs, one thread.
#include "bench_util.hpp"
#include "paper_figures.hpp"

#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <cstdio>
#include <filesystem>

using namespace muscle_deformation;

namespace {
// Sustained memory bandwidth of this machine, one thread: a triad over arrays much larger than the caches.
double measureTriadBandwidthGBs(int repetitions) {
  const std::size_t n = 16u << 20;  // 16 Mi doubles per array, 384 MiB in all
  std::vector<double> a(n, 1.0), b(n, 2.0), c(n, 0.0);
  std::vector<double> runs;
  for (int r = 0; r < repetitions; ++r) {
    const double ms = bench::millisecondsOf([&] {
      for (std::size_t i = 0; i < n; ++i) c[i] = a[i] + 0.5 * b[i];
    });
    runs.push_back(3.0 * sizeof(double) * n / (ms * 1e-3) / 1e9);
    std::swap(a, c);
  }
  return bench::median(runs);
}

// Bytes one MSS iteration moves at least once through memory: the packed springs (16 B each) and their runs (8 B
// per particle), and per particle: zeroing and accumulating forces (24 + 48), reading positions for the springs
// (24), then integration reading x, x_prev, force, 1/m (80) and writing x, x_prev (48).
double bytesPerIteration(const MassSpringSystem& system) {
  return 16.0 * static_cast<double>(system.springs.size()) + (8.0 + 24 + 48 + 24 + 80 + 48) * system.particleCount();
}
}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  std::filesystem::create_directories(options.out_dir);
  const SyntheticScene scene = makeSyntheticThigh(13, 8);
  const Pose pose = syntheticThighPose(0.5, 0.8);  // a bent leg: the springs are far from rest
  const BoneTransforms transforms = boneTransformsOf(scene.bones, pose);
  const std::array<bench::PaperTableColumn, 4> paper = bench::paperTable1();

  const double bandwidth_gbs = measureTriadBandwidthGBs(options.quick ? 3 : 9);
  std::printf("triad memory bandwidth (one thread): %.1f GB/s\n", bandwidth_gbs);
  bench::JsonRecords records;
  const int repetitions = options.quick ? 3 : 15;
  const int iterations_per_run = options.quick ? 5 : 40;
  std::printf("%-8s %9s %9s %11s %14s %14s %14s %10s %8s\n", "per_fib", "particles", "springs", "bytes/part",
              "fixed dt ms/it", "(cpu ms/it)", "adapt dt ms/it", "paper ms/it", "speedup");
  for (int k = 0; k < 4; ++k) {
    ModelSettings model;
    model.particles_per_fibre = paper[k].particles_per_fibre;
    model.nearest_neighbours = 18;
    ModelBuildReport report;
    const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, model, &report);

    // Median wall and thread-CPU time per iteration over repeated runs from the same start.
    auto timePerIteration = [&](TimeStepRule rule) {
      VerletSettings settings;
      settings.dt_rule = rule;
      VerletSolver solver(system, settings);
      std::vector<double> wall, cpu;
      for (int r = 0; r < repetitions; ++r) {
        ParticleState state;
        rigidPretransform(system, transforms, state);
        const double cpu_start = bench::threadCpuMilliseconds();
        wall.push_back(bench::millisecondsOf([&] {
                         for (int i = 0; i < iterations_per_run; ++i) solver.step(state);
                       }) /
                       iterations_per_run);
        cpu.push_back((bench::threadCpuMilliseconds() - cpu_start) / iterations_per_run);
      }
      return std::make_pair(bench::median(wall), bench::median(cpu));
    };
    const auto [fixed_ms, fixed_cpu_ms] = timePerIteration(TimeStepRule::fixed);
    const auto [adaptive_ms, adaptive_cpu_ms] = timePerIteration(TimeStepRule::adaptive);
    // Everything one solve keeps in memory: model arrays, the solver's packed copy, and the state (x, x_prev).
    const std::size_t state_bytes = 2 * 3 * sizeof(double) * static_cast<std::size_t>(system.particleCount());
    const std::size_t bytes_per_particle =
        (system.modelBytes() + VerletSolver(system, VerletSettings{}).solverBytes() + state_bytes) /
        static_cast<std::size_t>(system.particleCount());

    std::printf("%-8d %9ld %9zu %11zu %14.3f %14.3f %14.3f %10.1f %7.0fx\n", paper[k].particles_per_fibre,
                static_cast<long>(system.particleCount()), system.springs.size(), bytes_per_particle, fixed_ms,
                fixed_cpu_ms, adaptive_ms, paper[k].mss_ms, paper[k].mss_ms / fixed_ms);
    records.begin();
    records.add("particles_per_fibre", paper[k].particles_per_fibre);
    records.add("particles", static_cast<double>(system.particleCount()));
    records.add("springs", static_cast<double>(system.springs.size()));
    records.add("mss_ms_per_iteration", fixed_ms);
    records.add("mss_cpu_ms_per_iteration", fixed_cpu_ms);
    records.add("mss_adaptive_dt_ms_per_iteration", adaptive_ms);
    records.add("mss_adaptive_dt_cpu_ms_per_iteration", adaptive_cpu_ms);
    records.add("bytes_per_particle", static_cast<double>(bytes_per_particle));
    records.add("paper_mss_ms_per_iteration", paper[k].mss_ms);
    records.add("build_ms", report.build_ms);
    records.add("bytes_moved_per_iteration", bytesPerIteration(system));
    records.add("triad_bandwidth_gbs", bandwidth_gbs);
    records.add("bandwidth_floor_ms", bytesPerIteration(system) / (bandwidth_gbs * 1e9) * 1e3);
    records.add("repetitions", repetitions);
    records.add("iterations_per_repetition", iterations_per_run);
    records.end();
  }
  return bench::finish(records, options, "mss.json");
}
