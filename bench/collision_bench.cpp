// Collision time per solver iteration on the synthetic thigh, sized like the GRAPP paper's Table 1 scene:
// 13 muscles x 64 fibres x {20, 40, 60, 80} particles per fibre (boundary particles only take part), bones as sphere
// sets of 8527 (pelvis), 1568 (femur) and 1709 (tibia) spheres. For each broad phase: median per-iteration time of
// muscle-muscle CD, muscle-bone CD and the full iteration (MSS step + collision), one thread.
#include "bench_util.hpp"
#include "iteration_split.hpp"
#include "paper_figures.hpp"

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/model/collision_radii.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <new>

using namespace muscle_deformation;

// Counts heap allocations while `g_count_allocations` is set, to check the steady-state iteration allocates nothing.
namespace {
std::atomic<bool> g_count_allocations{false};
std::atomic<long> g_allocations{0};
}  // namespace

void* operator new(std::size_t size) {
  if (g_count_allocations.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

namespace {

struct Fit {
  double slope = 0, intercept = 0, r2 = 0;
};
Fit leastSquares(const std::vector<double>& x, const std::vector<double>& y) {
  const double n = static_cast<double>(x.size());
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    sx += x[i];
    sy += y[i];
    sxx += x[i] * x[i];
    sxy += x[i] * y[i];
  }
  Fit fit;
  fit.slope = (n * sxy - sx * sy) / (n * sxx - sx * sx);
  fit.intercept = (sy - fit.slope * sx) / n;
  double ss_res = 0, ss_tot = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    ss_res += std::pow(y[i] - (fit.intercept + fit.slope * x[i]), 2);
    ss_tot += std::pow(y[i] - sy / n, 2);
  }
  fit.r2 = ss_tot > 0 ? 1 - ss_res / ss_tot : 1;
  return fit;
}

struct Row {
  int per_fibre = 0;
  BroadPhaseKind kind = BroadPhaseKind::hash_grid;
  int boundary = 0;
  double muscle_ms = 0, bone_ms = 0, response_ms = 0, mss_ms = 0, total_ms = 0;
  double contacts = 0;
  long allocations = 0;
};

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  std::filesystem::create_directories(options.out_dir);
  const SyntheticScene scene = makeSyntheticThigh(13, 8);
  const Pose pose = syntheticThighPose(0.5, 0.8);  // a bent leg, as in the MSS benchmark
  const BoneTransforms transforms = boneTransformsOf(scene.bones, pose);

  const std::vector<SphereSet> bone_spheres = bench::paperCountBoneSpheres(scene.bones);
  std::vector<std::string> bone_names;
  for (const Bone& bone : scene.bones) bone_names.push_back(bone.name);
  const std::array<int, 3> paper_sphere_count = bench::paperBoneSphereCounts();
  const std::array<bench::PaperTableColumn, 4> paper = bench::paperTable1();

  const BroadPhaseKind kinds[] = {BroadPhaseKind::octree, BroadPhaseKind::hash_grid};
  const int warmup_iterations = options.quick ? 5 : 30;
  const int repetitions = options.quick ? 3 : 15;
  const int iterations_per_run = options.quick ? 5 : 20;

  std::vector<Row> rows;
  std::printf("bone spheres: pelvis %d, femur %d, tibia %d; one thread\n", paper_sphere_count[0], paper_sphere_count[1],
              paper_sphere_count[2]);
  std::printf("%-7s %-9s %8s %9s %9s %9s %9s %9s %9s | %8s %8s %8s\n", "per_fib", "broad", "boundary", "contacts",
              "muscle_ms", "bone_ms", "resp_ms", "mss_ms", "total_ms", "paper_mm", "paper_mb", "paper_tot");
  for (int k = 0; k < 4; ++k) {
    ModelSettings model;
    model.particles_per_fibre = paper[k].particles_per_fibre;
    model.nearest_neighbours = 18;
    MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, model);
    assignCollisionRadii(system, scene.muscles);
    VerletSettings solver_settings;
    solver_settings.dt_rule = TimeStepRule::fixed;
    VerletSolver solver(system, solver_settings);

    // A common starting state: rigid pre-transform, then a few iterations with collision so contacts are settled
    // the way they are in the middle of a solve.
    ParticleState start;
    {
      CollisionWorld world(system, bone_spheres, CollisionSettings{}, bone_names);
      start = bench::loadedState(system, solver, world, transforms, warmup_iterations);
    }

    for (const BroadPhaseKind kind : kinds) {
      CollisionSettings settings;
      settings.broad_phase = kind;
      CollisionWorld world(system, bone_spheres, settings, bone_names);
      world.setBoneTransforms(transforms);
      const bench::IterationSplit split =
          bench::measureIterationSplit(solver, world, start, repetitions, iterations_per_run);
      long allocations = 0;
      // Steady state: after the runs above every buffer has grown; count heap allocations in further collision passes.
      {
        ParticleState state = start;
        for (int i = 0; i < 10; ++i) {
          solver.step(state);
          world.resolve(state);
        }
        g_allocations = 0;
        for (int i = 0; i < 10; ++i) {
          solver.step(state);
          g_count_allocations = true;
          world.resolve(state);
          g_count_allocations = false;
        }
        allocations = g_allocations.load();
      }
      Row row;
      row.per_fibre = paper[k].particles_per_fibre;
      row.kind = kind;
      row.boundary = world.muscleSphereCount();
      row.muscle_ms = split.muscle_cd_ms;
      row.bone_ms = split.bone_cd_ms;
      row.response_ms = split.response_ms;
      row.mss_ms = split.mss_ms;
      row.total_ms = split.total_ms;
      row.contacts = split.contacts;
      row.allocations = allocations;
      rows.push_back(row);
      std::printf("%-7d %-9s %8d %9.0f %9.3f %9.3f %9.3f %9.3f %9.3f | %8.1f %8.1f %8.1f  allocs/10 passes %ld\n",
                  row.per_fibre, toString(kind), row.boundary, row.contacts, row.muscle_ms, row.bone_ms,
                  row.response_ms, row.mss_ms, row.total_ms, paper[k].muscle_cd_ms, paper[k].bone_cd_ms, paper[k].total_ms,
                  row.allocations);
    }
  }

  // Collision time (muscle + bone CD) against the number of boundary particles, per broad phase: a linear fit and
  // the exponent of a power-law fit (log-log slope; 1 = linear).
  bench::JsonRecords records;
  for (const BroadPhaseKind kind : kinds) {
    std::vector<double> x, y, lx, ly;
    for (const Row& row : rows)
      if (row.kind == kind) {
        x.push_back(row.boundary);
        y.push_back(row.muscle_ms + row.bone_ms);
        lx.push_back(std::log(static_cast<double>(row.boundary)));
        ly.push_back(std::log(row.muscle_ms + row.bone_ms));
      }
    const Fit linear = leastSquares(x, y);
    const Fit power = leastSquares(lx, ly);
    std::printf("%-9s collision ms = %.4f + %.5f ms per 1000 boundary particles (R^2 %.4f); log-log exponent %.3f\n",
                toString(kind), linear.intercept, linear.slope * 1000, linear.r2, power.slope);
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const Row& row = rows[i];
      if (row.kind != kind) continue;
      const int k = static_cast<int>(i / 2);
      records.begin();
      records.add("particles_per_fibre", row.per_fibre);
      records.add("broad_phase", std::string(toString(kind)));
      records.add("muscle_cd_ms", row.muscle_ms);
      records.add("bone_cd_ms", row.bone_ms);
      records.add("total_ms_per_iteration", row.total_ms);
      records.add("mss_ms", row.mss_ms);
      records.add("collision_response_ms", row.response_ms);
      records.add("boundary_particles", row.boundary);
      records.add("contacts_per_iteration", row.contacts);
      records.add("allocations_in_10_steady_passes", static_cast<double>(row.allocations));
      records.add("paper_muscle_cd_ms", paper[static_cast<std::size_t>(k)].muscle_cd_ms);
      records.add("paper_bone_cd_ms", paper[static_cast<std::size_t>(k)].bone_cd_ms);
      records.add("paper_total_ms_per_iteration", paper[static_cast<std::size_t>(k)].total_ms);
      records.add("fit_collision_ms_intercept", linear.intercept);
      records.add("fit_collision_ms_per_1000_boundary", linear.slope * 1000);
      records.add("fit_collision_r2", linear.r2);
      records.add("fit_collision_loglog_exponent", power.slope);
      records.add("repetitions", repetitions);
      records.add("iterations_per_repetition", iterations_per_run);
      records.end();
    }
  }
  return bench::finish(records, options, "iteration.json");
}
