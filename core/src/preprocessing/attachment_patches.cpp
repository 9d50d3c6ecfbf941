// Fibre generation, the patch step: origin and insertion patches from the surface regions nearest the bones.
#include "muscle_deformation/preprocessing/fibre_generator.hpp"

#include "fibre_steps.hpp"

#include "muscle_deformation/core/base/point_index.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <string>
#include <utility>
#include <vector>

namespace muscle_deformation {

using fibre_steps::kInf;
using fibre_steps::mm;
using fibre_steps::validateOptions;

AttachmentPatches findAttachmentPatches(const TriangleMesh& surface, const TriangleMesh* origin_bone,
                                        const TriangleMesh* insertion_bone, const FibreGeneratorOptions& options) {
  validateOptions(options);
  const Eigen::Index n = surface.vertexCount();
  if (n == 0 || !surface.vertices.allFinite()) throw FibreGenerationError("the muscle surface has no (finite) vertices");
  if (origin_bone && origin_bone->triangleCount() == 0) origin_bone = nullptr;
  if (insertion_bone && insertion_bone->triangleCount() == 0) insertion_bone = nullptr;
  AttachmentPatches patches;

  // Principal axis of the vertices: the muscle's long direction; tn = position along it, 0..1.
  const Eigen::Vector3d centroid = surface.vertices.rowwise().mean();
  const Eigen::Matrix3Xd centred = surface.vertices.colwise() - centroid;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> pca(centred * centred.transpose());
  const Eigen::Vector3d axis = pca.eigenvectors().col(2);
  const Eigen::VectorXd t = (axis.transpose() * centred).transpose();
  const double t_min = t.minCoeff(), length = t.maxCoeff() - t_min;
  if (!(length > 0)) throw FibreGenerationError("the muscle surface is degenerate (no extent)");
  const Eigen::VectorXd tn = (t.array() - t_min) / length;
  const auto min_count = static_cast<std::size_t>(std::max(1, options.min_patch_vertices));

  // The two tips: vertices within end_fraction of the length from an end (at least min_count of them).
  auto tip = [&](bool low) {
    std::vector<int> order(static_cast<std::size_t>(n));
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return low ? tn[a] < tn[b] : tn[a] > tn[b]; });
    std::vector<int> out;
    for (int v : order) {
      if ((low ? tn[v] : 1 - tn[v]) > options.end_fraction && out.size() >= min_count) break;
      out.push_back(v);
    }
    return out;
  };
  const std::vector<int> low_tip = tip(true), high_tip = tip(false);

  // Which tip is the origin: the assignment that puts each named bone nearer its own end.
  auto tipDistance = [&](const TriangleMesh& bone, const std::vector<int>& vertices) {
    const SurfaceDistance to_bone(bone.vertices, bone.triangles);
    double best = kInf;
    for (int v : vertices) best = std::min(best, to_bone.distance(surface.vertices.col(v)));
    return best;
  };
  bool origin_low;
  if (!origin_bone && !insertion_bone) {
    origin_low = axis.z() < 0;  // origin = the end with greater Z: proximal in a Z-up anatomical frame
    patches.notes.push_back("no bones: origin = the end of the principal axis with greater Z");
  } else {
    double score = 0;  // > 0: origin at the low end
    if (origin_bone) score += tipDistance(*origin_bone, high_tip) - tipDistance(*origin_bone, low_tip);
    if (insertion_bone) score += tipDistance(*insertion_bone, low_tip) - tipDistance(*insertion_bone, high_tip);
    origin_low = score >= 0;
  }
  // s: position from the origin end (0) to the insertion end (1).
  const Eigen::VectorXd s = origin_low ? tn : Eigen::VectorXd(1.0 - tn.array());

  // Region of the surface nearest a bone: vertices within attachment_distance of the closest approach, which itself
  // must be within max_attachment_gap (registered bones rarely touch a segmented muscle exactly). Vertices inside the
  // bone count as touching it.
  const double cap = options.max_attachment_gap + options.attachment_distance;
  auto distances = [&](const TriangleMesh* bone) {
    std::vector<double> d(static_cast<std::size_t>(n), kInf);
    if (!bone) return d;
    const SurfaceDistance to_bone(bone->vertices, bone->triangles);
    for (Eigen::Index v = 0; v < n; ++v) {
      const Eigen::Vector3d p = surface.vertices.col(v);
      double& dv = d[static_cast<std::size_t>(v)];
      dv = to_bone.distanceWithin(p, cap);
      if (dv <= cap && dv > 0 && windingNumber(*bone, p) > 0.5) dv = 0;
    }
    return d;
  };
  const std::vector<double> d_origin = distances(origin_bone), d_insertion = distances(insertion_bone);
  const double closest_origin = *std::min_element(d_origin.begin(), d_origin.end());
  const double closest_insertion = *std::min_element(d_insertion.begin(), d_insertion.end());
  std::vector<int> origin, insertion;
  for (Eigen::Index v = 0; v < n; ++v) {
    const double a = d_origin[static_cast<std::size_t>(v)], b = d_insertion[static_cast<std::size_t>(v)];
    const bool near_a = closest_origin <= options.max_attachment_gap && a <= closest_origin + options.attachment_distance;
    const bool near_b =
        closest_insertion <= options.max_attachment_gap && b <= closest_insertion + options.attachment_distance;
    if (near_a && (!near_b || a <= b)) {
      origin.push_back(static_cast<int>(v));
    } else if (near_b) {
      insertion.push_back(static_cast<int>(v));
    }
  }
  auto describeBone = [&](const char* role, const TriangleMesh* bone, double closest) {
    if (!bone) return std::string(role) + " bone: none given";
    if (!std::isfinite(closest)) return std::string(role) + " bone: too far (farther than " + mm(cap, 1) + ")";
    if (closest > options.max_attachment_gap) {
      return std::string(role) + " bone: too far (closest approach " + mm(closest, 1) + " > " +
             mm(options.max_attachment_gap, 1) + ")";
    }
    return std::string(role) + " bone: closest approach " + mm(closest, 1);
  };
  patches.notes.push_back(describeBone("origin", origin_bone, closest_origin));
  patches.notes.push_back(describeBone("insertion", insertion_bone, closest_insertion));

  // Keep each bone region on its own side of the muscle: a muscle lying along its origin bone all the way to the
  // insertion touches it there too. Cut at the midpoint of the two regions' mean positions (or mid-length), with a gap.
  auto meanS = [&](const std::vector<int>& vs) {
    double sum = 0;
    for (int v : vs) sum += s[v];
    return sum / static_cast<double>(std::max<std::size_t>(1, vs.size()));
  };
  double split = 0.5;
  if (!origin.empty() && !insertion.empty() && meanS(origin) < meanS(insertion)) {
    split = 0.5 * (meanS(origin) + meanS(insertion));
  }
  const double gap = options.patch_gap_fraction;
  origin.erase(std::remove_if(origin.begin(), origin.end(), [&](int v) { return s[v] >= split - gap; }), origin.end());
  insertion.erase(std::remove_if(insertion.begin(), insertion.end(), [&](int v) { return s[v] <= split + gap; }),
                  insertion.end());

  // A bone region is used if it is big enough and reaches its end of the muscle; otherwise the tip stands in.
  double origin_reach = kInf, insertion_reach = -kInf;
  for (int v : origin) origin_reach = std::min(origin_reach, s[v]);
  for (int v : insertion) insertion_reach = std::max(insertion_reach, s[v]);
  patches.origin_from_bone = origin.size() >= min_count && origin_reach <= options.bone_patch_reach;
  patches.insertion_from_bone = insertion.size() >= min_count && insertion_reach >= 1 - options.bone_patch_reach;
  if (!patches.origin_from_bone) {
    if (!origin.empty()) patches.notes.push_back("origin bone region unusable (too small or away from its end)");
    origin = origin_low ? low_tip : high_tip;
  }
  if (!patches.insertion_from_bone) {
    if (!insertion.empty()) patches.notes.push_back("insertion bone region unusable (too small or away from its end)");
    insertion = origin_low ? high_tip : low_tip;
  }
  // Never share a vertex (tips and bone regions are cut apart above; this is a last guard): the origin keeps it.
  std::vector<char> in_origin(static_cast<std::size_t>(n), 0);
  for (int v : origin) in_origin[static_cast<std::size_t>(v)] = 1;
  insertion.erase(std::remove_if(insertion.begin(), insertion.end(),
                                 [&](int v) { return in_origin[static_cast<std::size_t>(v)] != 0; }),
                  insertion.end());
  if (origin.empty() || insertion.empty()) throw FibreGenerationError("could not find two separate attachment patches");
  std::sort(origin.begin(), origin.end());
  std::sort(insertion.begin(), insertion.end());
  patches.origin_vertices = origin;
  patches.insertion_vertices = insertion;
  return patches;
}

}  // namespace muscle_deformation
