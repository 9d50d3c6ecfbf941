// One frame of the product: solve the mass-spring system for a pose, then (when someone needs
// them) skin the muscle surfaces and measure their fidelity. Plain C++ on top of the core (no ROS types), so the
// node's streaming and service solves share it and tests drive it directly.
#pragma once

#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/pipeline/simulation_settings.hpp"
#include "muscle_deformation/core/surfaces/surface_bone_contact.hpp"
#include "muscle_deformation/core/surfaces/surface_skinning.hpp"
#include "muscle_deformation/core/surfaces/surface_volume.hpp"

#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace muscle_deformation {

struct PipelineSettings {
  SimulationSettings simulation;
  // Worker threads of the frame: the solver's sweeps, then the surface stages and metrics, which run after the solve and
  // so have the cores the sweeps had. 0 = every core; -1 = the solver measures one or every core as it runs
  // (BlockDescentSolver::kThreadsMeasured), the surface stages then take every core.
  int threads = 0;
  SkinningSettings skinning;
  // Skinned surface vertices inside a bone are moved out to its surface (SurfaceBoneContact), before the volume
  // constraint, which never moves one in.
  bool keep_surfaces_out_of_bones = true;
  SurfaceVolumeSettings surface_volume;  // the skinned surfaces keep their rest volume (applied with the skinning)
  bool skin_surfaces = true;     // precompute surface skinning (needed for ~surfaces and the surface metrics)
  bool measure_fidelity = true;  // precompute the volume / surface-in-bone metrics
};

// What one solved pose gives the layers above (the node's messages, the benchmarks): the particles, the fibres they
// lie on, the skinned surfaces when computed, and the frame's figures. The big arrays stay where the pipeline keeps
// them and the frame reads them in place, so nothing is copied per frame: the views show the pipeline's newest solve
// and stay valid while it lives. A default-constructed frame has no views (a test of the figures alone).
struct FrameResult {
  FrameStats stats;                 // stats.solver (iterations, times, strain, divergence), stats.collision, ...
  BoneTransforms bone_transforms;   // indexed by Bone::id
  bool has_surfaces = false;
  std::vector<Vertices> surfaces;   // per muscle, when has_surfaces; triangles in surfaceTriangles(muscle)
  double skinning_ms = 0;           // skinning, the contact with the bones and the volume projection
  // Per muscle, what the contact with the bones did to the skinned surface (empty when it is off or there are none).
  std::vector<SurfaceBoneCorrection> bone_corrections;
  // Per muscle, what the volume projection did to the skinned surface (empty when it is off or there are no surfaces).
  std::vector<SurfaceVolumeCorrection> volume_corrections;
  double volume_ms = 0;             // of skinning_ms, the volume projection's share
  bool has_metrics = false;
  SceneMetrics metrics;             // when has_metrics
  double metrics_ms = 0;
  // Why a figure of this frame is absent (empty when it is there): the force residual (stats.solver.residual < 0),
  // the contacts and penetrations (stats.has_collision false), the surface metrics (has_metrics false).
  std::string residual_absent_reason, collision_absent_reason, metrics_absent_reason;

  // Particle positions, m, one column per particle.
  const Eigen::Matrix3Xd& positions() const { return *positions_; }
  // What each particle is: its muscle (muscle_of, muscle_begin), fibre (fibre_of: a fibre is a run of consecutive
  // particles), collision radius, the bone it is fixed to; the springs and rest positions.
  const MassSpringSystem& particles() const { return *particles_; }
  // Names and colours of the muscles, in the order of particles().muscle_of and `surfaces`.
  const std::vector<MuscleDescription>& muscles() const { return *muscles_; }
  const std::vector<Bone>& bones() const { return *bones_; }  // in the order of bone_transforms
  // The triangles over surfaces[muscle] (its vertices); only when has_surfaces.
  const Triangles& surfaceTriangles(std::size_t muscle) const { return skinning_->muscles()[muscle].triangles(); }

  // Points the views at what they show: the pipeline does it once when built, a converter test with a model of its
  // own. `skinning` may be null (no surfaces).
  void view(const MassSpringSystem& particles, const Eigen::Matrix3Xd& positions,
            const std::vector<MuscleDescription>& muscles, const std::vector<Bone>& bones,
            const SurfaceSkinning* skinning) {
    particles_ = &particles;
    positions_ = &positions;
    muscles_ = &muscles;
    bones_ = &bones;
    skinning_ = skinning;
  }

 private:
  const MassSpringSystem* particles_ = nullptr;
  const Eigen::Matrix3Xd* positions_ = nullptr;
  const std::vector<MuscleDescription>* muscles_ = nullptr;
  const std::vector<Bone>* bones_ = nullptr;
  const SurfaceSkinning* skinning_ = nullptr;
};

// What a frame's consumers want computed beside the particles.
struct FrameWants {
  bool surfaces = false;
  bool metrics = false;
  // The caller dropped poses while the frame before was solved: the stream is behind, and this frame takes no
  // catch-up sweeps past its budget (FrameStopping::catch_up_sweeps), which would drop more. Its residual is high
  // because it covers the motion of the poses dropped, not because the motion is fast. Deep-contact sweeps still run.
  bool late = false;
};

// The fidelity figures (the surface metrics and the particles' depth in bone) by their ~stats names, as an absence
// names them.
inline constexpr const char* kFidelityFigures =
    "volume_error_*, surface_vertices_inside_bone, max_surface_inside_bone_m, particles_inside_bone, "
    "max_particle_inside_bone_m, muscle_*";

// A figure the pipeline cannot give, with the reason and what would turn it on (setting names as in the settings
// table and config/muscle_deformation.yaml).
struct AbsentMetric {
  std::string figures;  // e.g. "force_residual"
  std::string reason;
  std::string remedy;
  bool turned_off = false;  // a setting chose it (true), or something is broken (false)

  // "<figures>: <reason>; to measure, <remedy>"
  std::string describe() const { return figures + ": " + reason + "; to measure, " + remedy; }
};

class MuscleSimulation;  // the pipeline's own (core/src/pipeline/muscle_simulation.hpp)

class DeformationPipeline {
 public:
  // Builds the simulation (throws ModelError / std::invalid_argument on bad settings or input). Skinning and metrics
  // that cannot be set up (e.g. an open surface) are disabled with a reason (skinningProblem(), metricsProblem())
  // rather than failing: the particles and fibres are still useful.
  // `bone_fields`: see MuscleSimulation (shared by the node's stream and service pipelines).
  DeformationPipeline(std::vector<MuscleDescription> descriptions, std::vector<Muscle> muscles,
                      std::vector<Bone> bones, const PipelineSettings& settings, const BoneFields& bone_fields = {});
  // The frame result views the pipeline's own arrays: a copy or a move would leave it looking at the old ones.
  DeformationPipeline(const DeformationPipeline&) = delete;
  DeformationPipeline& operator=(const DeformationPipeline&) = delete;
  ~DeformationPipeline();

  // Solves one pose given as bone transforms (boneTransformsOf(bones(), pose)), stopping as `stopping` says. Surfaces
  // are skinned if `want_surfaces` or `want_metrics`; metrics measured if `want_metrics`. `frame_interval_s`: time
  // since the pose a warm start continues (weighs the tissue drag). The result is the pipeline's own (see
  // FrameResult): the next solve overwrites it.
  const FrameResult& solve(const BoneTransforms& transforms, StartMode start, const FrameStopping& stopping,
                           bool want_surfaces, bool want_metrics, double frame_interval_s = kNominalFrameIntervalS);
  // More sweeps of the last frame's solve at the same pose and tissue (the answer it was solving for), within
  // `stopping`: a frame a budget left unfinished, continued while the skeleton holds still. Throws std::logic_error
  // when there is no previous frame to continue.
  const FrameResult& refine(const FrameStopping& stopping, bool want_surfaces, bool want_metrics);
  void reset();  // forget the previous result: the next solve starts cold
  // Continue from a known result instead of the last solve's (benchmarks start compared streams from one converged
  // frame): the next warm solve starts from `position` solved at `transforms`. Throws std::invalid_argument on a size
  // mismatch or a non-finite position.
  void continueFrom(const BoneTransforms& transforms, const Eigen::Matrix3Xd& position);

  // The model and its state as the last solve left them.
  const MassSpringSystem& system() const;
  const ParticleState& state() const;
  const BoneTransforms& boneTransforms() const;  // of the last solve (or continueFrom)
  const std::vector<Muscle>& muscles() const;
  const ModelBuildReport& buildReport() const;
  const CollisionWorld* collisionWorld() const;
  // The bones' distance fields (bone_proxy distance_field; empty otherwise), shared with another pipeline of the scene.
  const BoneFields& boneFields() const;
  const RestOverlapSummary& restOverlaps() const;
  // How deep the deepest free particle's centre lies inside a bone at rest, with its muscle and the bone (bone
  // distance fields; absent with sphere proxies or without collision, which do not measure it).
  struct RestPenetration {
    double depth_m = 0;  // 0: none inside
    std::string muscle, bone;
  };
  std::optional<RestPenetration> restPenetration() const;
  const std::vector<Bone>& bones() const;  // what a pose's bone transforms are of
  const std::vector<MuscleDescription>& descriptions() const { return descriptions_; }
  const PipelineSettings& settings() const { return settings_; }
  const FrameResult& lastFrame() const { return frame_; }
  const SurfaceSkinning* skinning() const { return skinning_.get(); }
  const SurfaceVolumeConstraint* surfaceVolume() const { return surface_volume_.get(); }
  const SurfaceBoneContact* surfaceBoneContact() const { return surface_contact_.get(); }
  const DeformationMetrics* metrics() const { return metrics_.get(); }
  const std::string& skinningProblem() const { return skinning_problem_; }
  const std::string& metricsProblem() const { return metrics_problem_; }
  // Every figure this pipeline never measures, as set up (empty when it measures all): the force residual, the
  // collision figures, the surface metrics.
  std::vector<AbsentMetric> absentMetrics() const;
  double skinningSetupMs() const { return skinning_setup_ms_; }
  double metricsSetupMs() const { return metrics_setup_ms_; }

  // Heap bytes of the model (mass-spring arrays, surface weights); an estimate for the startup log.
  std::size_t modelBytes() const;
  // One line per quantity for the startup log: muscles, particles, springs, spheres, memory, build time.
  std::string describe() const;

 private:
  // The surfaces and metrics of the frame the simulation just solved.
  const FrameResult& finishFrame(const FrameStopping& stopping, bool want_surfaces, bool want_metrics);
  AbsentMetric residualAbsence() const;

  AbsentMetric collisionAbsence() const;
  AbsentMetric metricsAbsence() const;

  std::vector<MuscleDescription> descriptions_;
  PipelineSettings settings_;
  std::unique_ptr<MuscleSimulation> simulation_;
  std::unique_ptr<SurfaceSkinning> skinning_;
  std::unique_ptr<DeformationMetrics> metrics_;
  std::unique_ptr<SurfaceVolumeConstraint> surface_volume_;
  std::unique_ptr<SurfaceBoneContact> surface_contact_;
  std::string skinning_problem_, metrics_problem_;
  double skinning_setup_ms_ = 0, metrics_setup_ms_ = 0;
  FrameResult frame_;
};

}  // namespace muscle_deformation
