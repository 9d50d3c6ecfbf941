// Collision time per solver iteration on the synthetic thigh, sized like the GRAPP paper's Table 1 scene:
// 13 muscles x 64 fibres x {20, 40, 60, 80} particles per fibre (boundary particles only take part), bones as sphere
// sets of 8527 (pelvis), 1568 (femur) and 1709 (tibia) spheres. For each broad phase: median per-iteration time of
// muscle-muscle CD, muscle-bone CD and the full iteration (MSS step + collision), one thread.
#include "bench_util.hpp"

#include "muscle_deformation/core/collision.hpp"
#include "muscle_deformation/core/model_builder.hpp"
#include "muscle_deformation/core/rigid_pretransform.hpp"
#include "muscle_deformation/core/solver.hpp"
#include "muscle_deformation/core/synthetic_scene.hpp"

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <new>
#include <random>

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

// `count` spheres on the bone surface placed like the one-ring heuristic: surface points drawn uniformly by area
// (seeded), centre moved inward by L along the face normal, radius L sqrt(2). L is chosen so the spheres' surface
// caps (radius L) cover the area about twice: N pi L^2 = 2 A.
SphereSet boneSpheresOfCount(const TriangleMesh& mesh, int count, std::uint32_t seed) {
  std::vector<double> cumulative_area;
  double area = 0;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    const Eigen::Vector3d a = mesh.vertices.col(mesh.triangles(0, t)), b = mesh.vertices.col(mesh.triangles(1, t)),
                          c = mesh.vertices.col(mesh.triangles(2, t));
    area += 0.5 * (b - a).cross(c - a).norm();
    cumulative_area.push_back(area);
  }
  const double depth = std::sqrt(2.0 * area / (M_PI * count));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  SphereSet spheres;
  spheres.resize(count);
  for (int k = 0; k < count; ++k) {
    const auto t = static_cast<Eigen::Index>(
        std::lower_bound(cumulative_area.begin(), cumulative_area.end(), unit(rng) * area) - cumulative_area.begin());
    const Eigen::Vector3d a = mesh.vertices.col(mesh.triangles(0, t)), b = mesh.vertices.col(mesh.triangles(1, t)),
                          c = mesh.vertices.col(mesh.triangles(2, t));
    double u = unit(rng), v = unit(rng);
    if (u + v > 1) u = 1 - u, v = 1 - v;
    const Eigen::Vector3d point = a + u * (b - a) + v * (c - a);
    const Eigen::Vector3d normal = (b - a).cross(c - a).normalized();
    spheres.centre.col(k) = point - depth * normal;
    spheres.radius[k] = depth * std::sqrt(2.0);
  }
  return spheres;
}

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

  // The paper's bone sphere counts (GRAPP 2014 section 4), on the synthetic bones in the scene's bone order.
  const int paper_sphere_count[] = {8527, 1568, 1709};  // pelvis, femur, tibia
  std::vector<SphereSet> bone_spheres;
  std::vector<std::string> bone_names;
  for (std::size_t b = 0; b < scene.bones.size(); ++b) {
    bone_spheres.push_back(boneSpheresOfCount(scene.bones[b].surface, paper_sphere_count[b % 3], 17u + static_cast<std::uint32_t>(b)));
    bone_names.push_back(scene.bones[b].name);
  }

  // GRAPP Table 1, seconds per 500 iterations -> ms per iteration.
  const double paper_muscle_ms[] = {8.15 * 2, 13.50 * 2, 24.00 * 2, 29.53 * 2};
  const double paper_bone_ms[] = {30.03 * 2, 37.43 * 2, 56.03 * 2, 67.10 * 2};
  const double paper_total_ms[] = {56.84 * 2, 90.9 * 2, 140.56 * 2, 177.33 * 2};

  const int per_fibre[] = {20, 40, 60, 80};
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
    model.particles_per_fibre = per_fibre[k];
    model.nearest_neighbours = 18;
    MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, model);
    assignCollisionRadii(system, scene.muscles);
    SolverSettings solver_settings;
    solver_settings.dt_rule = TimeStepRule::fixed;
    VerletSolver solver(system, solver_settings);

    // A common starting state: rigid pre-transform, then a few iterations with collision so contacts are settled
    // the way they are in the middle of a solve.
    ParticleState start;
    rigidPretransform(system, transforms, start);
    {
      CollisionWorld world(system, bone_spheres, CollisionSettings{}, bone_names);
      world.setBoneTransforms(transforms);
      for (int i = 0; i < warmup_iterations; ++i) {
        solver.step(start);
        world.resolve(start);
      }
    }

    for (const BroadPhaseKind kind : kinds) {
      CollisionSettings settings;
      settings.broad_phase = kind;
      CollisionWorld world(system, bone_spheres, settings, bone_names);
      world.setBoneTransforms(transforms);
      std::vector<double> muscle_runs, bone_runs, response_runs, mss_runs, total_runs, contact_runs;
      long allocations = 0;
      for (int r = 0; r < repetitions; ++r) {
        ParticleState state = start;
        // The first pass after a reset builds lazy structures; it belongs to the run's warm-up, not its timing.
        world.resolve(state);
        state = start;
        world.resetTiming();
        double mss_ms = 0, total_ms = 0, contacts = 0;
        for (int i = 0; i < iterations_per_run; ++i) {
          total_ms += bench::millisecondsOf([&] {
            mss_ms += bench::millisecondsOf([&] { solver.step(state); });
            contacts += world.resolve(state);
          });
        }
        const CollisionStats& stats = world.accumulatedStats();
        muscle_runs.push_back(stats.muscle_cd_ms / iterations_per_run);
        bone_runs.push_back(stats.bone_cd_ms / iterations_per_run);
        response_runs.push_back(stats.response_ms / iterations_per_run);
        mss_runs.push_back(mss_ms / iterations_per_run);
        total_runs.push_back(total_ms / iterations_per_run);
        contact_runs.push_back(contacts / iterations_per_run);
      }
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
      row.per_fibre = per_fibre[k];
      row.kind = kind;
      row.boundary = world.muscleSphereCount();
      row.muscle_ms = bench::median(muscle_runs);
      row.bone_ms = bench::median(bone_runs);
      row.response_ms = bench::median(response_runs);
      row.mss_ms = bench::median(mss_runs);
      row.total_ms = bench::median(total_runs);
      row.contacts = bench::median(contact_runs);
      row.allocations = allocations;
      rows.push_back(row);
      std::printf("%-7d %-9s %8d %9.0f %9.3f %9.3f %9.3f %9.3f %9.3f | %8.1f %8.1f %8.1f  allocs/10 passes %ld\n",
                  row.per_fibre, toString(kind), row.boundary, row.contacts, row.muscle_ms, row.bone_ms,
                  row.response_ms, row.mss_ms, row.total_ms, paper_muscle_ms[k], paper_bone_ms[k], paper_total_ms[k],
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
      records.add("paper_muscle_cd_ms", paper_muscle_ms[k]);
      records.add("paper_bone_cd_ms", paper_bone_ms[k]);
      records.add("paper_total_ms_per_iteration", paper_total_ms[k]);
      records.add("fit_collision_ms_intercept", linear.intercept);
      records.add("fit_collision_ms_per_1000_boundary", linear.slope * 1000);
      records.add("fit_collision_r2", linear.r2);
      records.add("fit_collision_loglog_exponent", power.slope);
      records.add("repetitions", repetitions);
      records.add("iterations_per_repetition", iterations_per_run);
      records.end();
    }
  }
  const std::string path = options.out_dir + "/iteration.json";
  if (!records.write(path)) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    return 1;
  }
  std::printf("wrote %s\n", path.c_str());
  return 0;
}
