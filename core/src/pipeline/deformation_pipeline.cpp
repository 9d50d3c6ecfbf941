#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include "muscle_simulation.hpp"

#include <chrono>
#include <sstream>

namespace muscle_deformation {

DeformationPipeline::DeformationPipeline(std::vector<MuscleDescription> descriptions, std::vector<Muscle> muscles,
                                         std::vector<Bone> bones, const PipelineSettings& settings,
                                         const BoneFields& bone_fields)
    : descriptions_(std::move(descriptions)), settings_(settings) {
  simulation_ = std::make_unique<MuscleSimulation>(std::move(muscles), std::move(bones), settings_.simulation,
                                                   settings_.threads, bone_fields);
  const MuscleSimulation& sim = *simulation_;
  // The volume term of the frame energy reads each muscle's skin, so it needs the skinning whatever else is asked.
  const bool keep_volume = settings_.simulation.block_descent.volume_stiffness > 0;
  if (settings_.skin_surfaces || settings_.measure_fidelity || keep_volume) {
    const auto start = std::chrono::steady_clock::now();
    try {
      skinning_ = std::make_unique<SurfaceSkinning>(sim.system(), sim.muscles(), settings_.skinning);
    } catch (const std::exception& e) {
      skinning_problem_ = e.what();
    }
    skinning_setup_ms_ = millisecondsSince(start);
    if (skinning_ && keep_volume) simulation_->keepVolume(*skinning_);
  } else {
    skinning_problem_ = "turned off (surfaces and surface_metrics are false)";
  }
  if (settings_.measure_fidelity && skinning_) {
    const auto start = std::chrono::steady_clock::now();
    try {
      metrics_ = std::make_unique<DeformationMetrics>(sim.bones(), sim.muscles(), sim.system(), sim.boneFields());
    } catch (const std::exception& e) {
      metrics_problem_ = e.what();
    }
    metrics_setup_ms_ = millisecondsSince(start);
  } else {
    metrics_problem_ = settings_.measure_fidelity ? "needs the surface skinning (" + skinning_problem_ + ")"
                                                  : "turned off (surface_metrics is false)";
  }
  // The bones the surfaces are kept out of: the fields the collision or the metrics built (one set per scene), none
  // when neither did.
  const BoneFields& fields = !sim.boneFields().empty() ? sim.boneFields()
                             : metrics_                ? metrics_->boneFields()
                                                       : BoneFields{};
  if (skinning_ && settings_.keep_surfaces_out_of_bones && !fields.empty()) {
    std::vector<Eigen::Index> vertex_counts;
    for (const Muscle& muscle : sim.muscles()) vertex_counts.push_back(muscle.surface.vertexCount());
    surface_contact_ = std::make_unique<SurfaceBoneContact>(vertex_counts, fields);
  }
  if (skinning_ && settings_.surface_volume.keep_volume) {
    std::vector<Triangles> triangles;
    std::vector<Vertices> rest;
    for (std::size_t m = 0; m < skinning_->muscles().size(); ++m) {
      triangles.push_back(skinning_->muscles()[m].triangles());
      rest.push_back(sim.muscles()[m].surface.vertices);
    }
    surface_volume_ = std::make_unique<SurfaceVolumeConstraint>(triangles, rest, fields, settings_.surface_volume);
  }
  frame_.view(sim.system(), sim.state().position, descriptions_, sim.bones(), skinning_.get());
}

DeformationPipeline::~DeformationPipeline() = default;

void DeformationPipeline::reset() { simulation_->reset(); }
void DeformationPipeline::continueFrom(const BoneTransforms& transforms, const Eigen::Matrix3Xd& position) {
  simulation_->continueFrom(transforms, position);
}
const MassSpringSystem& DeformationPipeline::system() const { return simulation_->system(); }
const ParticleState& DeformationPipeline::state() const { return simulation_->state(); }
const BoneTransforms& DeformationPipeline::boneTransforms() const { return simulation_->boneTransforms(); }
const std::vector<Muscle>& DeformationPipeline::muscles() const { return simulation_->muscles(); }
const std::vector<Bone>& DeformationPipeline::bones() const { return simulation_->bones(); }
const ModelBuildReport& DeformationPipeline::buildReport() const { return simulation_->buildReport(); }
const CollisionWorld* DeformationPipeline::collisionWorld() const { return simulation_->collisionWorld(); }
const BoneFields& DeformationPipeline::boneFields() const { return simulation_->boneFields(); }
const RestOverlapSummary& DeformationPipeline::restOverlaps() const { return simulation_->restOverlaps(); }

std::optional<DeformationPipeline::RestPenetration> DeformationPipeline::restPenetration() const {
  const CollisionWorld* world = simulation_->collisionWorld();
  if (!world || !world->everyParticleCollides()) return std::nullopt;
  const CollisionWorld::RestPenetration deepest = world->deepestParticleInsideBoneAtRest();
  RestPenetration out;
  out.depth_m = deepest.depth_m;
  if (deepest.particle >= 0) {
    const MassSpringSystem& model = system();
    out.muscle = muscles().at(static_cast<std::size_t>(model.muscle_of[static_cast<std::size_t>(deepest.particle)])).name;
    out.bone = bones().at(static_cast<std::size_t>(deepest.bone)).name;
  }
  return out;
}

const FrameResult& DeformationPipeline::solve(const BoneTransforms& transforms, StartMode start,
                                              const FrameStopping& stopping, bool want_surfaces, bool want_metrics,
                                              double frame_interval_s) {
  frame_.stats = simulation_->solve(transforms, start, stopping, frame_interval_s);
  frame_.bone_transforms = transforms;
  return finishFrame(stopping, want_surfaces, want_metrics);
}

const FrameResult& DeformationPipeline::refine(const FrameStopping& stopping, bool want_surfaces, bool want_metrics) {
  frame_.stats = simulation_->refine(stopping);
  frame_.bone_transforms = simulation_->boneTransforms();
  return finishFrame(stopping, want_surfaces, want_metrics);
}

const FrameResult& DeformationPipeline::finishFrame(const FrameStopping& stopping, bool want_surfaces,
                                                    bool want_metrics) {
  frame_.has_surfaces = false;
  frame_.has_metrics = false;
  frame_.skinning_ms = 0;
  frame_.volume_ms = 0;
  frame_.volume_corrections.clear();
  frame_.bone_corrections.clear();
  frame_.metrics_ms = 0;
  frame_.residual_absent_reason.clear();
  frame_.collision_absent_reason.clear();
  frame_.metrics_absent_reason.clear();
  if (frame_.stats.solver.residual < 0)
    frame_.residual_absent_reason = measuresForceResidual(simulation_->settings().solver_kind)
                                        ? "not measured in this solve"
                                        : residualAbsence().reason;
  if (!frame_.stats.has_collision) frame_.collision_absent_reason = collisionAbsence().reason;
  const Eigen::Matrix3Xd& positions = simulation_->state().position;
  if (!metrics_)
    frame_.metrics_absent_reason = metricsAbsence().reason;
  else if (!want_metrics)
    frame_.metrics_absent_reason = "not asked for in this solve";
  if (!frame_.stats.finite) {
    if (frame_.metrics_absent_reason.empty())
      frame_.metrics_absent_reason = "the solve gave non-finite particle positions";
    return frame_;
  }
  if (skinning_ && (want_surfaces || (want_metrics && metrics_))) {
    const auto skin_start = std::chrono::steady_clock::now();
    const int threads = parallelThreads(settings_.threads, stopping.sweeps.limits);
    skinning_->update(positions, frame_.bone_transforms, frame_.surfaces, threads);
    if (surface_contact_)
      frame_.bone_corrections = surface_contact_->apply(frame_.surfaces, frame_.bone_transforms, threads);
    if (surface_volume_) {
      const auto volume_start = std::chrono::steady_clock::now();
      frame_.volume_corrections = surface_volume_->apply(frame_.surfaces, frame_.bone_transforms, threads);
      frame_.volume_ms = millisecondsSince(volume_start);
    }
    frame_.skinning_ms = millisecondsSince(skin_start);
    frame_.has_surfaces = true;
  }
  if (metrics_ && want_metrics && frame_.has_surfaces) {
    const auto metrics_start = std::chrono::steady_clock::now();
    frame_.metrics = metrics_->measure(frame_.surfaces, positions, frame_.bone_transforms,
                                       parallelThreads(settings_.threads, stopping.sweeps.limits));
    frame_.metrics_ms = millisecondsSince(metrics_start);
    frame_.has_metrics = true;
  }
  return frame_;
}

AbsentMetric DeformationPipeline::residualAbsence() const {
  const SolverKind kind = simulation_->settings().solver_kind;
  return {"force_residual", "the " + toString(kind) + " solver does not measure it (only block_descent and newton_krylov do)",
          "set solver: block_descent", true};
}

AbsentMetric DeformationPipeline::collisionAbsence() const {
  return {"contacts, max_penetration_sphere_bone_m, max_penetration_sphere_muscle_m", "collisions are off",
          "set collisions: true", true};
}

AbsentMetric DeformationPipeline::metricsAbsence() const {
  AbsentMetric absent{kFidelityFigures, metrics_problem_, ""};
  absent.turned_off = !settings_.measure_fidelity;
  if (!settings_.measure_fidelity)
    absent.remedy = "set surface_metrics: true";
  else if (!skinning_)
    absent.remedy = "the muscle surfaces must be skinned: fix what the reason names";
  else
    absent.remedy = "every bone and muscle needs a closed surface: repair the one the reason names (a muscle with "
                    "repair_surfaces: true in the scene, a bone in the URDF's collision mesh)";
  return absent;
}

std::vector<AbsentMetric> DeformationPipeline::absentMetrics() const {
  std::vector<AbsentMetric> absent;
  if (!measuresForceResidual(simulation_->settings().solver_kind)) absent.push_back(residualAbsence());
  if (!simulation_->collisionWorld()) absent.push_back(collisionAbsence());
  if (!metrics_) absent.push_back(metricsAbsence());
  return absent;
}

std::size_t DeformationPipeline::modelBytes() const {
  std::size_t bytes = simulation_->system().modelBytes();
  if (skinning_) {
    for (const MuscleSkin& skin : skinning_->muscles()) {
      bytes += static_cast<std::size_t>(skin.weights().nonZeros()) * (sizeof(double) + sizeof(std::int32_t));
      bytes += static_cast<std::size_t>(skin.triangles().size()) * sizeof(int);
    }
  }
  return bytes;
}

std::string DeformationPipeline::describe() const {
  const MuscleSimulation& sim = *simulation_;
  const MassSpringSystem& system = sim.system();
  const ModelBuildReport& report = sim.buildReport();
  long fixed = 0, boundary = 0;
  for (const MuscleBuildSummary& m : report.muscles) {
    fixed += m.fixed_particles;
    boundary += m.boundary_particles;
  }
  long bone_spheres = 0, muscle_spheres = 0;
  std::string bone_proxy;
  if (const CollisionWorld* world = sim.collisionWorld()) {
    for (int count : world->boneSphereCounts()) bone_spheres += count;
    muscle_spheres = world->muscleSphereCount();
    if (world->everyParticleCollides()) {
      double field_ms = 0, field_mib = 0;
      for (const auto& field : sim.boneFields()) {
        field_ms += field->buildMilliseconds();
        field_mib += static_cast<double>(field->memoryBytes()) / (1024.0 * 1024.0);
      }
      std::ostringstream fields;
      fields << "bones as distance fields (" << sim.settings().collision.bone_field.voxel_m * 1000 << " mm voxels, "
             << field_mib << " MiB, built in " << field_ms << " ms; " << world->particlesCloserThanRadiusAtRest()
             << " particles closer to a bone at rest than their radius, held at that depth; ";
      if (const std::optional<RestPenetration> rest = restPenetration(); rest && rest->depth_m > 0)
        fields << "the deepest particle centre " << rest->depth_m * 1000 << " mm inside bone '" << rest->bone
               << "' at rest (muscle '" << rest->muscle << "')";
      else
        fields << "no particle centre inside a bone at rest";
      fields << ")";
      bone_proxy = fields.str();
    } else {
      bone_proxy = std::to_string(bone_spheres) + " bone spheres";
    }
  }
  std::ostringstream out;
  out << system.muscleCount() << " muscles, " << sim.bones().size() << " bones; " << system.particleCount()
      << " particles (" << fixed << " fixed, " << boundary << " on the boundary), " << system.springs.size()
      << " springs; solver " << toString(sim.settings().solver_kind) << "; collision " << (sim.collisionWorld() ? "on" : "off") << ": " << muscle_spheres
      << " muscle spheres, " << bone_proxy << "; model memory "
      << static_cast<double>(modelBytes()) / (1024.0 * 1024.0) << " MiB; build " << report.build_ms << " ms";
  if (skinning_)
    out << ", surface skinning (" << toString(skinning_->settings().method) << ") " << skinning_setup_ms_ << " ms";
  else
    out << "; no surfaces: " << skinning_problem_;
  if (metrics_)
    out << ", fidelity metrics " << metrics_setup_ms_ << " ms";
  else
    out << "; no fidelity metrics: " << metrics_problem_;
  return out.str();
}

}  // namespace muscle_deformation
