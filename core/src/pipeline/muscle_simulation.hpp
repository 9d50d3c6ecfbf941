// The pipeline's own simulation: muscles and bones in, a pose in, deformed particles and statistics out. Private to
// pipeline/: DeformationPipeline, the stream session and the single-pose session drive it; nothing else does.
#pragma once

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/collision/collision_ready_model.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/simulation_settings.hpp"
#include "muscle_deformation/core/solvers/solver_factory.hpp"
#include "muscle_deformation/core/surfaces/skinned_volume.hpp"

#include <functional>
#include <memory>
#include <vector>

namespace muscle_deformation {

class MuscleSimulation {
 public:
  // Throws ModelError (invalid settings or input) or std::invalid_argument (invalid solver/collision settings).
  // `threads`: the solver's worker threads (BlockDescentSolver). `bone_fields`: the bones' distance fields already
  // built (e.g. by another simulation of the same scene), used with bone_proxy distance_field instead of building them
  // again.
  MuscleSimulation(std::vector<Muscle> muscles, std::vector<Bone> bones, SimulationSettings settings, int threads = 0,
                   const BoneFields& bone_fields = {});

  // Solves the pose given as bone transforms (boneTransformsOf(bones(), pose)). `frame_interval_s`: the time since the
  // pose a warm start continues (a stream's stamps), which weighs the tissue drag; a cold start uses
  // kNominalFrameIntervalS.
  FrameStats solve(const BoneTransforms& transforms, StartMode start, const FrameStopping& stopping,
                   double frame_interval_s = kNominalFrameIntervalS);
  // More of the last frame's solve: the same pose and the same pull of the tissue (carried positions), from where the
  // last solve ended, with `stopping.sweeps` (a time budget as for a warm frame). Throws std::logic_error without a
  // previous frame.
  FrameStats refine(const FrameStopping& stopping);
  void reset();  // forget the previous result: the next solve starts cold
  // Puts each muscle's volume, as `skinning` skins it, into the solver's frame energy with the stiffness the block
  // descent settings' volume_stiffness gives (solvers that minimise a frame energy only; the others ignore it). The
  // skinning must outlive the simulation.
  void keepVolume(const SurfaceSkinning& skinning);
  bool keepsVolume() const { return volume_ != nullptr; }
  const SkinnedVolume* skinnedVolume() const { return volume_.get(); }
  // Continue from a known result instead of the last solve's: the next warm solve starts from `position` (a state of
  // this system) solved at `transforms`. Throws std::invalid_argument on a size mismatch or a non-finite position.
  void continueFrom(const BoneTransforms& transforms, const Eigen::Matrix3Xd& position);

  const MassSpringSystem& system() const { return system_; }
  const ParticleState& state() const { return state_; }
  // The bones' transforms the last solve (or continueFrom) placed them with, indexed like bones().
  const BoneTransforms& boneTransforms() const { return previous_transforms_; }
  bool hasPrevious() const { return has_previous_; }
  const std::vector<Muscle>& muscles() const { return muscles_; }
  const std::vector<Bone>& bones() const { return bones_; }
  const ModelBuildReport& buildReport() const { return build_report_; }
  const SimulationSettings& settings() const { return settings_; }
  const CollisionWorld* collisionWorld() const { return collision_.get(); }
  // The bones' distance fields (bone_proxy distance_field; empty otherwise), per bone index: shared with the metrics.
  const BoneFields& boneFields() const { return bone_fields_; }
  // Sphere radii shrunk at build time so that the rest pose is free of contacts (clearRestOverlaps).
  const RestOverlapSummary& restOverlaps() const { return rest_overlaps_; }
  bool measuresResidual() const { return measuresForceResidual(settings_.solver_kind); }

 private:
  // The solver's rule for the frame's main solve: a cold start under a time budget runs a fixed number instead.
  StoppingSettings mainSolveStopping(bool warm, const FrameStopping& stopping) const;
  // The solver (with the collision stage's contacts or its hook) at `transforms`, then the sweeps past the budget
  // (deep contact; catch-up, not for a `refinement`).
  void runSolver(const BoneTransforms& transforms, const StoppingSettings& main, const FrameStopping& stopping,
                 FrameStats& stats, bool refinement);
  // Up to `cap` single sweeps past the frame's main solve while `needed()` holds and the solve is sound, each from
  // where the last ended, towards the same answer; `count` says how many the frame took.
  void sweepPastBudget(const StoppingSettings& main, int cap, const std::function<bool()>& needed, FrameStats& stats,
                       int& count);
  // FrameStopping::deep_contact_sweeps: while a bone contact is deeper than the median collision radius.
  void sweepDeepContacts(const StoppingSettings& main, const FrameStopping& stopping, FrameStats& stats);
  // Finite check (with the pre-transform as the last resort) and what the next warm start continues; `refinement`: the
  // frame continued the last one (refine()).
  void finishFrame(const BoneTransforms& transforms, bool drag, bool refinement, FrameStats& stats);
  // Threads for the frame's passes over every particle or spring outside the solver (carrying with the bones, the
  // tone), as the skinned volume takes them: each element is computed alone, so results do not depend on it.
  int passThreads() const { return parallelThreads(threads_, SolveLimits{}); }

  std::vector<Muscle> muscles_;
  std::vector<Bone> bones_;
  SimulationSettings settings_;
  int threads_ = 0;  // as constructed (PipelineSettings::threads)
  ModelBuildReport build_report_;
  RestOverlapSummary rest_overlaps_;
  MassSpringSystem system_;
  std::unique_ptr<SoftBodySolver> solver_;  // the one settings_.solver_kind names (solver_factory.hpp)
  // The force that holds the rest shape in balance, rest frame (restBalanceForces), when the solver's tie carries it.
  Eigen::Matrix3Xd rest_balance_ = Eigen::Matrix3Xd(3, 0);
  // Per particle, its springs' summed stiffness, for the tissue's stretch with the tone (SimulationSettings::
  // drag_follows_tone; empty without it).
  Eigen::VectorXd spring_stiffness_sum_;
  std::unique_ptr<CollisionWorld> collision_;
  BoneFields bone_fields_;
  // MassSpringSystem::medianCollisionRadius of the final model, once (FrameStopping::deep_contact_sweeps).
  double median_collision_radius_m_ = 0;
  // The running mean of log(residual) after the budgeted sweeps of the warm frames so far (FrameStopping::
  // catch_up_sweeps); unset until the first.
  double typical_log_residual_ = 0;
  bool has_typical_residual_ = false;
  static constexpr double kTypicalResidualWeight = 0.05;  // of each new frame: about the last 20 frames (1/3 s at 60 Hz)

  std::unique_ptr<SkinnedVolume> volume_;  // keepVolume(); null without a volume term
  // Per muscle, the volume term's target (VolumeTerm::target_volume_m3): the rest volume until a warm frame's error
  // moves it (updateVolumePressure); back to the rest volume at a cold start.
  std::vector<double> volume_target_m3_;
  static constexpr double kMaxVolumeTargetShift = 0.3;  // of the rest volume
  static constexpr int kColdPressureSweeps = 5;          // a cold start's sweeps between its pressure updates
  // After a solved frame: each muscle's pressure takes on volume_pressure_gain of its remaining volume error.
  void updateVolumePressure();
  // Each muscle's volume target moved by `shift` (m^3), within kMaxVolumeTargetShift of its rest volume.
  void moveVolumeTargets(const std::vector<double>& shift);
  bool pressureBuilds() const { return volume_ && settings_.block_descent.volume_pressure_gain > 0; }
  // After a cold start: the pressure built within it held the volume against the tissue drag's pull towards the rigid
  // pre-transform (which squeezes a muscle by up to 8 % on the bundled gait). The next frame's drag pulls towards this
  // frame's answer instead, and that share of the pressure would inflate the muscle (the biceps femoris short head 4.5 %
  // at the gait's first warm frame, docs/lengths.md), so the first warm frame after it starts from the pressure the
  // answer needs without the drag (SoftBodySolver::dragShareOfVolumeTargets). The cold frame's own answer, and its
  // refinements (the same anchor), are unchanged: the share is measured after each and taken out when a warm frame
  // begins.
  void measureColdDragShare(bool warm);
  void takeColdDragOutOfPressure();
  std::vector<double> cold_drag_share_;  // per muscle (m^3); empty unless the last frame was a cold start
  void resetVolumePressure();
  BoneTransforms frame_transforms_;        // the bones of the frame being solved (the volume term's skin reads them)

  ParticleState state_;
  // The last frame's correction (its answer minus where the tissue carried it; zero after a cold start), which the next
  // warm start carries on (StartPrediction).
  Eigen::Matrix3Xd correction_;
  // The last frame's change of the correction (for StartPrediction::predict_extrapolation) and the change before it
  // (what the extrapolated trend must be confirmed by); empty where there is none to carry on (after a cold start, a
  // refinement or continueFrom).
  Eigen::Matrix3Xd correction_change_;
  Eigen::Matrix3Xd previous_correction_change_;
  BoneTransforms previous_transforms_;
  bool has_previous_ = false;
  bool last_frame_warm_ = false;  // the last frame continued a warm one (its correction is carried on)
};

}  // namespace muscle_deformation
