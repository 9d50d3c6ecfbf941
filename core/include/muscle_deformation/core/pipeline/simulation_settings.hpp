// What a frame's solve is made of, as the pipeline's callers choose it: the model and solver settings, how a warm
// frame starts, how a frame's solve stops, and what it reports. The simulation that runs them is the pipeline's own
// (core/src/pipeline/muscle_simulation.hpp); callers reach it through DeformationPipeline and the sessions.
#pragma once

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/collision/collision_settings.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/solvers/solver_factory.hpp"

#include <string>

namespace muscle_deformation {

// The largest predict_extrapolation accepted (StartPrediction).
inline constexpr double kMaxPredictExtrapolation = 0.75;

// How a warm frame of a solver with tissue drag starts. The answer does not change (the drag still pulls towards where
// the tissue carries each particle); only where the sweeps begin.
struct StartPrediction {
  // Start from the previous frame's own correction (its answer minus where the tissue carried it) carried on with the
  // bones, rather than from where the tissue carries it: over a smooth motion one frame's correction is close to the
  // next one's, so the sweeps start near the answer.
  bool predict_start = true;
  // How much of the correction's change over the last frame the predicted start carries on besides the correction
  // itself: y + c_n + e d, where d is, per particle, the part of c_n - c_(n-1) that the change before it confirms (its
  // projection on it, within 0 and 1 of it), so that the sweeps' own alternation is not fed back (held still it grew
  // without that). 0.5, measured on the bundled gait with one sweep a frame: 1.93 instead of 2.47 mm RMS from the
  // converged stream over three cycles of thigh13 (docs/realtime.md); 1 (straight linear extrapolation) fed its own
  // error back and diverged.
  double predict_extrapolation = 0.5;
};

struct SimulationSettings {
  ModelSettings model;
  SolverKind solver_kind = SolverKind::verlet;  // which solver runs
  VerletSettings verlet;                        // for SolverKind::verlet
  LocalGlobalSettings local_global;             // for SolverKind::local_global
  BlockDescentSettings block_descent;           // for SolverKind::block_descent (and newton_krylov's energy)
  NewtonKrylovSettings newton_krylov;           // for SolverKind::newton_krylov
  StartPrediction prediction;                   // warm frames of block_descent / newton_krylov with tissue drag
  // With the belly's tone (ModelSettings::fibre_tone) and a tissue drag: on a warm frame, where the tissue carries the
  // belly (the drag's anchor and the frame's start) also stretches each fibre along itself by its tone's change since
  // the previous frame (stretchWithTone), as the tissue around a lengthening muscle lengthens with it. Without it the drag holds each
  // fibre at the previous answer's length carried rigidly, and a streamed belly took about three fifths of its span's
  // change (the biceps femoris short head a third; docs/lengths.md). false: the drag carries the answer rigidly.
  bool drag_follows_tone = false;
  CollisionSettings collision;
  bool collisions = true;  // false: the MSS alone (for comparisons)
};

// Empty when the settings are usable, otherwise what is wrong (the parts no solver checks itself).
std::string validate(const StartPrediction& prediction);

enum class StartMode {
  cold,  // from the rest shape moved by the rigid pre-transform (the seeds: every pose independent)
  warm,  // from the previous result moved with the bones' motion since the previous pose (cold if there is none)
};

// How one frame's solve stops: the solver's rule for its iterations, and what a frame may take beyond it. Passed with
// every solve; the simulation derives each solver call's rule from it and keeps none.
struct FrameStopping {
  StoppingSettings sweeps;
  // A cold start under a time budget (the first frame, a discontinuity) continues nothing: from the rigid
  // pre-transform one budget's sweep leaves particles up to 2 mm inside bone (gait bag rostest), so it runs this many
  // iterations instead (at most sweeps.max_iterations), once. 10: block descent cold on all 26 bundled muscles then
  // ends 0.08 mm deep at most in 118 ms (real-time bench), and a frame that long still fits between the poses of a
  // stream played slower than real time. The node runs 15 (`cold_start_sweeps`, nodeDefaultSettings): with the belly's
  // tone 10 left the iliacus' model volume 3.22 % off at the gait's first pose.
  int cold_start_iterations = 10;
  // time_budget, frames of a solver with contacts in its solve (warm, and a cold start after its
  // cold_start_iterations): sweeps a frame may take past its budget while the
  // collision stage measures a bone contact deeper than the median collision radius (a particle of median size with
  // its centre in the bone). A smooth stream never needs them (the bundled gait: 0.03 mm at most); a warm frame after a
  // jump does (thigh13, rest to 90 deg hip flexion in one frame: 1.71 mm after the one sweep its budget fits, 0.19 mm
  // after a second).
  int deep_contact_sweeps = 0;
  // time_budget, warm frames of a solver that measures a force residual: sweeps a frame may take past its budget, one
  // at a time, while its residual stays above catch_up_residual_ratio x the stream's typical residual after the
  // budgeted sweeps (a running geometric mean over the warm frames before it), so that the frames of a fast motion get
  // sweeps where their residual is and a smooth stream none. 0 = none.
  int catch_up_sweeps = 0;
  double catch_up_residual_ratio = 3.0;

  static FrameStopping of(const StoppingSettings& sweeps) {
    FrameStopping stopping;
    stopping.sweeps = sweeps;
    return stopping;
  }
};

// Empty when usable, otherwise what is wrong.
std::string validate(const FrameStopping& stopping);

struct FrameStats {
  SolveStats solver;         // the solver's: iterations, per-phase times, spring deviation, strain, divergence
  CollisionStats collision;  // contacts and remaining penetration after the last iteration, when has_collision
  bool has_collision = false;  // collisions are on, so `collision` was measured (off: its figures mean nothing)
  bool warm_started = false;
  bool finite = true;        // every particle position is finite (always, unless the rest shape itself is not)
  // The solve left non-finite positions despite the solver's own recovery; the state is the rigid pre-transform.
  bool fell_back_to_pretransform = false;
  int deep_contact_sweeps = 0;  // sweeps taken past the budget for a deep bone contact (FrameStopping)
  int catch_up_sweeps = 0;      // sweeps taken past the budget for a residual far above the stream's (FrameStopping)
  // Wall times of the frame's solve, milliseconds. solve_ms is all of it: the pose's preparation (tendons' and the
  // belly tone's rest lengths, carrying the particles to the pose, the tissue drag's anchors), the solver
  // (solver.total_ms: sweeps, contact search, closing contact pass) and what follows it (spring and contact figures,
  // the volume pressure). A time budget counts from the solve's start, preparation included.
  double solve_ms = 0;
  double preparation_ms = 0;  // of solve_ms, before the solver's first sweep
};

}  // namespace muscle_deformation
