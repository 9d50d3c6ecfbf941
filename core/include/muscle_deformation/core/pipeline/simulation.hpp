// One way through the core: muscles and bones in, a pose in, deformed particles and statistics out.
//
//   MuscleSimulation simulation(muscles, bones, settings);   // builds the MSS, radii, bone spheres
//   FrameStats stats = simulation.solve(pose, StartMode::warm);
//   simulation.state().position  /  fibrePolylines(simulation.system(), simulation.state().position)
#pragma once

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/model/model.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/solver_factory.hpp"

#include <memory>
#include <vector>

namespace muscle_deformation {

// How a frame's solve stops, whichever solver runs: the settings table's stopping_rule, max_iterations,
// displacement_tolerance_m and time_budget_ms, and the node's limits. Each solver keeps its own copy (a solver can be
// used alone, with its own default rule); shareStoppingRule copies these into all of
// them, as the node and the benchmarks that speak for it do.
struct StoppingSettings {
  StoppingRule rule = StoppingRule::iterations;
  int max_iterations = 100;                 // cap for every rule
  double displacement_tolerance_m = 1e-6;   // for StoppingRule::displacement
  double time_budget_ms = 16.0;             // for StoppingRule::time_budget
  SolveLimits limits;                       // for every rule
};

struct SimulationSettings {
  ModelSettings model;
  SolverKind solver_kind = SolverKind::verlet;  // which solver MuscleSimulation runs
  StoppingSettings stopping;                    // shared by the solvers once shareStoppingRule copied it
  VerletSettings verlet;                        // for SolverKind::verlet
  LocalGlobalSettings local_global;             // for SolverKind::local_global
  BlockDescentSettings block_descent;           // for SolverKind::block_descent (and newton_krylov's energy)
  NewtonKrylovSettings newton_krylov;           // for SolverKind::newton_krylov
  CollisionSettings collision;
  bool collisions = true;  // false: the MSS alone (for comparisons)
};

// Copies `simulation.stopping` into the settings of every solver, so that it drives whichever one runs.
void shareStoppingRule(SimulationSettings& simulation);

enum class StartMode {
  cold,  // from the rest shape moved by the rigid pre-transform (the seeds: every pose independent)
  warm,  // from the previous result moved with the bones' motion since the previous pose (cold if there is none)
};

struct FrameStats {
  SolveStats solver;         // the solver's: iterations, per-phase times, spring deviation, strain, divergence
  CollisionStats collision;  // contacts and remaining penetration after the last iteration, when has_collision
  bool has_collision = false;  // collisions are on, so `collision` was measured (off: its figures mean nothing)
  bool warm_started = false;
  bool finite = true;        // every particle position is finite (always, unless the rest shape itself is not)
  // The solve left non-finite positions despite the solver's own recovery; the state is the rigid pre-transform.
  bool fell_back_to_pretransform = false;
};

class MuscleSimulation {
 public:
  // Throws ModelError (invalid settings or input) or std::invalid_argument (invalid solver/collision settings).
  // `bone_fields`: the bones' distance fields already built (e.g. by another simulation of the same scene, boneFields()),
  // used with bone_proxy distance_field instead of building them again.
  MuscleSimulation(std::vector<Muscle> muscles, std::vector<Bone> bones, SimulationSettings settings,
                   const BoneFields& bone_fields = {});

  // `frame_interval_s`: the time since the pose a warm start continues (a stream's stamps), which weighs the tissue
  // drag of block descent; a cold start uses kNominalFrameIntervalS.
  FrameStats solve(const Pose& pose, StartMode start, double frame_interval_s = kNominalFrameIntervalS);
  // The same with the pose already turned into bone transforms (boneTransformsOf(bones(), pose)), for callers that
  // need them anyway: a frame computes them once.
  FrameStats solve(const BoneTransforms& transforms, StartMode start, double frame_interval_s = kNominalFrameIntervalS);
  void reset();  // forget the previous result: the next solve starts cold
  // Continue from a known result instead of the last solve's: the next warm solve starts from `position` (a state of
  // this system) solved at `transforms`. Benchmarks start every compared stream from the same converged frame.
  // Throws std::invalid_argument on a size mismatch or a non-finite position.
  void continueFrom(const BoneTransforms& transforms, const Eigen::Matrix3Xd& position);
  // Changes how later solves stop, for whichever solver runs (no rebuild): rule, iteration cap, tolerances, limits.
  void setStopping(StoppingRule rule, int max_iterations, double displacement_tolerance_m, double time_budget_ms,
                   const SolveLimits& limits);

  const MassSpringSystem& system() const { return system_; }
  const ParticleState& state() const { return state_; }
  // The bones' transforms the last solve (or continueFrom) placed them with, indexed like bones().
  const BoneTransforms& boneTransforms() const { return previous_transforms_; }
  const std::vector<Muscle>& muscles() const { return muscles_; }
  const std::vector<Bone>& bones() const { return bones_; }
  const ModelBuildReport& buildReport() const { return build_report_; }
  const SimulationSettings& settings() const { return settings_; }
  const CollisionWorld* collisionWorld() const { return collision_.get(); }
  // The bones' distance fields (bone_proxy distance_field; empty otherwise), per bone index: shared with the metrics.
  const std::vector<std::shared_ptr<const BoneDistanceField>>& boneFields() const { return bone_fields_; }
  // Sphere radii shrunk at build time so that the rest pose is free of contacts (clearRestOverlaps).
  const RestOverlapSummary& restOverlaps() const { return rest_overlaps_; }

 private:
  StoppingSettings runningStopping() const;  // the stopping settings of the solver that runs

  std::vector<Muscle> muscles_;
  std::vector<Bone> bones_;
  SimulationSettings settings_;
  ModelBuildReport build_report_;
  RestOverlapSummary rest_overlaps_;
  MassSpringSystem system_;
  std::unique_ptr<SoftBodySolver> solver_;  // the one settings_.solver_kind names (solver_factory.hpp)
  std::unique_ptr<CollisionWorld> collision_;
  std::vector<std::shared_ptr<const BoneDistanceField>> bone_fields_;
  // MassSpringSystem::medianCollisionRadius of the final model, once (BlockDescentSettings::deep_contact_sweeps).
  double median_collision_radius_m_ = 0;
  bool tissueDrag() const;  // block descent with tissue_relaxation_s > 0

  ParticleState state_;
  // The last frame's correction (its answer minus where the tissue carried it; zero after a cold start), which the next
  // warm start carries on (BlockDescentSettings::predict_start).
  Eigen::Matrix3Xd correction_;
  // The correction of the frame before (for BlockDescentSettings::predict_extrapolation), empty when that frame did
  // not continue a warm one.
  Eigen::Matrix3Xd previous_correction_;
  BoneTransforms previous_transforms_;
  bool has_previous_ = false;
};

}  // namespace muscle_deformation
