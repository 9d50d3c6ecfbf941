// Per-muscle resolution for an error target: models at each candidate resolution against the finest one.
#include "muscle_deformation/preprocessing/resolution_choice.hpp"

#include "muscle_deformation/core/base/bone_transforms.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <set>
#include <sstream>
#include <stdexcept>

namespace muscle_deformation {

namespace {

// The joints from `link` up to the root, nearest first.
std::vector<std::string> jointsToRoot(const Skeleton& skeleton, std::string link) {
  std::vector<std::string> joints;
  for (const SkeletonLink* l = skeleton.link(link); l && !l->parent_joint.empty(); l = skeleton.link(link)) {
    joints.push_back(l->parent_joint);
    link = l->parent_link;
  }
  return joints;
}

// The rotating joints between a muscle's origin and insertion links: the joints on one link's way to the root and not
// on the other's. Coupled joints (<mimic>) move with the joint they follow.
std::set<std::string> jointsCrossed(const Skeleton& skeleton, const std::string& origin, const std::string& insertion) {
  const std::vector<std::string> a = jointsToRoot(skeleton, origin), b = jointsToRoot(skeleton, insertion);
  std::set<std::string> crossed;
  for (const auto* chain : {&a, &b})
    for (const std::string& name : *chain) {
      const std::vector<std::string>& other = chain == &a ? b : a;
      if (std::find(other.begin(), other.end(), name) != other.end()) continue;
      const SkeletonJoint* joint = skeleton.joint(name);
      if (joint && (joint->type == "revolute" || joint->type == "continuous") && joint->mimic_joint.empty())
        crossed.insert(name);
    }
  return crossed;
}

std::string poseLabel(const std::string& joint, double value) {
  std::ostringstream out;
  out << joint << " " << std::showpos << std::fixed << std::setprecision(2) << value << " rad";
  return out.str();
}

}  // namespace

ResolutionChoice chooseResolutions(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones,
                                   const Skeleton& skeleton, const std::string& frame, const CoreSettings& settings,
                                   const ResolutionChoiceRequest& request,
                                   const std::function<void(const std::string&)>& progress) {
  const auto started = std::chrono::steady_clock::now();
  if (!(request.surface_error_m > 0) || !std::isfinite(request.surface_error_m))
    throw std::invalid_argument("the surface error target must be a positive number of millimetres");
  if (request.candidates.empty() || request.candidates.front() < 2 ||
      !std::is_sorted(request.candidates.begin(), request.candidates.end(), std::less_equal<int>()) ||
      request.candidates.back() >= request.finest)
    throw std::invalid_argument("the candidate resolutions must increase from 2 particles per fibre and stay below the "
                                "finest");

  // The checked poses: each joint some muscle crosses, bent both ways within its limits, one at a time.
  std::set<std::string> crossed;
  for (const Muscle& muscle : muscles) {
    const std::set<std::string> joints = jointsCrossed(skeleton, muscle.origin_bone, muscle.insertion_bone);
    crossed.insert(joints.begin(), joints.end());
  }
  std::vector<JointValues> poses;
  ResolutionChoice choice;
  for (const std::string& name : skeleton.movableJointNames()) {
    if (!crossed.count(name)) continue;
    const SkeletonJoint* joint = skeleton.joint(name);
    for (const double sign : {1.0, -1.0}) {
      double value = sign * request.bend_rad;
      if (joint->lower < joint->upper) value = std::clamp(value, joint->lower, joint->upper);
      if (std::abs(value) < 0.1 * request.bend_rad) continue;  // the joint cannot bend that way
      poses.push_back({{name, value}});
      choice.poses.push_back(poseLabel(name, value));
    }
  }
  if (poses.empty())
    throw std::invalid_argument("no muscle crosses a joint that bends: there is no pose to compare the resolutions at");

  // Bone transforms of each pose in the scene frame (the frame link's frame), from the rest poses.
  const std::map<std::string, Eigen::Isometry3d> rest = linkPosesInFrame(skeleton, frame);
  std::vector<BoneTransforms> transforms;
  for (const JointValues& values : poses)
    transforms.push_back(
        boneTransformsOf(bones, poseFromLinkPoses(bones, rest, linkPosesInFrame(skeleton, frame, values))));

  // Each resolution's skinned surfaces at each pose: [resolution][pose][muscle].
  std::vector<int> resolutions = request.candidates;
  resolutions.push_back(request.finest);
  choice.resolutions = resolutions;
  std::vector<std::vector<std::vector<Vertices>>> surfaces;
  for (const int particles_per_fibre : resolutions) {
    PipelineSettings pipeline_settings = settings.pipeline;
    pipeline_settings.simulation.model.particles_per_fibre = particles_per_fibre;
    pipeline_settings.skin_surfaces = true;
    pipeline_settings.measure_fidelity = false;
    pipeline_settings.keep_surfaces_out_of_bones = false;  // the skin as the particles carry it
    pipeline_settings.surface_volume.keep_volume = false;
    std::vector<Muscle> at_resolution = muscles;
    for (Muscle& muscle : at_resolution) muscle.particles_per_fibre = 0;
    DeformationPipeline pipeline(describedByName(at_resolution), at_resolution, bones, pipeline_settings);
    choice.model_particles.push_back(static_cast<double>(pipeline.system().particleCount()));
    std::vector<std::vector<Vertices>> per_pose;
    for (const BoneTransforms& t : transforms) {
      const FrameResult& frame_result = pipeline.solve(
          t, StartMode::cold,
          FrameStopping::of(StoppingSettings::atResidual(request.residual_tolerance, request.max_sweeps)), true, false);
      if (!frame_result.has_surfaces || !frame_result.stats.finite)
        throw std::runtime_error("the model at " + std::to_string(particles_per_fibre) +
                                 " particles per fibre gave no finite surfaces");
      per_pose.push_back(frame_result.surfaces);
    }
    surfaces.push_back(std::move(per_pose));
    if (progress)
      progress("resolution " + std::to_string(particles_per_fibre) + " particles per fibre: " +
               std::to_string(poses.size()) + " poses solved");
  }

  const std::vector<std::vector<Vertices>>& finest = surfaces.back();
  for (std::size_t m = 0; m < muscles.size(); ++m) {
    MuscleResolution result;
    result.muscle = muscles[m].name;
    for (std::size_t c = 0; c < request.candidates.size(); ++c) {
      double worst_rms = 0, worst_max = 0;
      for (std::size_t p = 0; p < poses.size(); ++p) {
        const Eigen::VectorXd distance = (surfaces[c][p][m] - finest[p][m]).colwise().norm();
        worst_rms = std::max(worst_rms, std::sqrt(distance.squaredNorm() / static_cast<double>(distance.size())));
        worst_max = std::max(worst_max, distance.maxCoeff());
      }
      result.worst_rms_m.push_back(worst_rms);
      result.worst_max_m.push_back(worst_max);
      if (!result.met && worst_rms <= request.surface_error_m) {
        result.met = true;
        result.chosen = request.candidates[c];
      }
    }
    if (!result.met) result.chosen = request.candidates.back();
    choice.muscles.push_back(std::move(result));
  }
  choice.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  return choice;
}

}  // namespace muscle_deformation
