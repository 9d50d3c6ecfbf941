#include "muscle_deformation/core/model/model_builder.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include "muscle_deformation/core/model/collision_radii.hpp"
#include "muscle_deformation/core/model/fibre_sampling.hpp"
#include "muscle_deformation/core/base/inside_test.hpp"
#include "muscle_deformation/core/base/point_index.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <limits>
#include <map>
#include <memory>
#include <sstream>

namespace muscle_deformation {

std::string validate(const ModelSettings& s) {
  if (s.particles_per_fibre < 2) return "particles_per_fibre must be at least 2";
  if (s.spring_layout == SpringLayout::nearest_neighbours && s.nearest_neighbours < 1)
    return "nearest_neighbours must be at least 1";
  if (!(s.attachment_distance_m >= 0) || !std::isfinite(s.attachment_distance_m))
    return "attachment_distance_m must be a finite distance >= 0";
  if (!(s.spring_material_n > 0) || !std::isfinite(s.spring_material_n))
    return "spring_material_n must be a finite value > 0";
  if (!(s.density_kg_per_m3 > 0) || !std::isfinite(s.density_kg_per_m3))
    return "density_kg_per_m3 must be a finite value > 0";
  if (!(s.fibre_prestretch >= 0 && s.fibre_prestretch <= 0.5))
    return "fibre_prestretch must be in [0, 0.5]";
  if (!(s.fibre_tone >= 0 && s.fibre_tone <= 2)) return "fibre_tone must be in [0, 2]";
  if (!(s.transverse_stiffness_ratio > 0 && s.transverse_stiffness_ratio <= 1))
    return "transverse_stiffness_ratio must be in (0, 1]";
  if (!(s.tendon_stiffness_ratio > 0) || !std::isfinite(s.tendon_stiffness_ratio))
    return "tendon_stiffness_ratio must be a finite value > 0";
  if (!(s.boundary_fibre_fraction >= 0 && s.boundary_fibre_fraction <= 1))
    return "boundary_fibre_fraction must be in [0, 1]";
  return {};
}

namespace {

struct BoneQueries {
  std::vector<PointIndex> vertices;       // nearest bone vertex: a cheap upper bound of the surface distance
  std::vector<SurfaceDistance> surfaces;  // exact distances where they decide something (attachments)
};

BoneQueries prepareBoneQueries(const std::vector<Bone>& bones) {
  BoneQueries queries;
  for (const Bone& bone : bones) {
    queries.vertices.emplace_back(bone.surface.vertices);
    queries.surfaces.emplace_back(bone.surface.vertices, bone.surface.triangles);
  }
  return queries;
}

int particlesPerFibreOf(const Muscle& muscle, const ModelSettings& settings) {
  return muscle.particles_per_fibre > 0 ? muscle.particles_per_fibre : settings.particles_per_fibre;
}

ParticlePairs layoutPairs(const ModelSettings& settings, const FibreSamples& samples) {
  switch (settings.spring_layout) {
    case SpringLayout::nearest_neighbours: return nearestNeighbourPairs(samples.position, settings.nearest_neighbours);
    case SpringLayout::cubic6: return cubicLatticePairs(samples.position, samples.fibre_of, samples.sample_of, false);
    case SpringLayout::cubic26: return cubicLatticePairs(samples.position, samples.fibre_of, samples.sample_of, true);
    case SpringLayout::delaunay: return delaunayPairs(samples.position);
  }
  return {};
}

// Fibres nearest the surface. Every fibre is probed at the same number of points along its length, whatever the
// particles per fibre; each surface vertex votes for its closest probe, and a fibre whose probes won enough votes is a
// boundary fibre. Interior fibres only win votes near the muscle ends, where all fibres converge. Probing the fibres
// rather than the particles keeps the answer independent of the sampling resolution.
std::vector<std::uint8_t> markBoundary(const Muscle& muscle, const FibreSamples& samples, double fraction) {
  constexpr int kProbesPerFibre = 16;
  std::vector<std::int32_t> fibre_ids(samples.fibre_of.begin(), samples.fibre_of.end());
  std::sort(fibre_ids.begin(), fibre_ids.end());
  fibre_ids.erase(std::unique(fibre_ids.begin(), fibre_ids.end()), fibre_ids.end());

  Eigen::Matrix3Xd probes(3, static_cast<Eigen::Index>(fibre_ids.size()) * kProbesPerFibre);
  for (std::size_t f = 0; f < fibre_ids.size(); ++f) {
    const Polyline& fibre = muscle.fibres[fibre_ids[f]];
    const double length = polylineLength(fibre);
    for (int k = 0; k < kProbesPerFibre; ++k)
      probes.col(static_cast<Eigen::Index>(f) * kProbesPerFibre + k) =
          pointAtArcLength(fibre, length * (k + 0.5) / kProbesPerFibre);
  }
  std::vector<std::uint8_t> probe_won(static_cast<std::size_t>(probes.cols()), 0);
  const PointIndex probe_index(probes);
  for (Eigen::Index v = 0; v < muscle.surface.vertices.cols(); ++v)
    probe_won[probe_index.nearest(muscle.surface.vertices.col(v)).first] = 1;

  std::map<std::int32_t, bool> is_boundary_fibre;
  for (std::size_t f = 0; f < fibre_ids.size(); ++f) {
    int won = 0;
    for (int k = 0; k < kProbesPerFibre; ++k) won += probe_won[f * kProbesPerFibre + k];
    is_boundary_fibre[fibre_ids[f]] = won >= fraction * kProbesPerFibre;
  }
  std::vector<std::uint8_t> boundary(samples.fibre_of.size(), 0);
  for (std::size_t i = 0; i < boundary.size(); ++i) boundary[i] = is_boundary_fibre[samples.fibre_of[i]] ? 1 : 0;
  return boundary;
}

// The bones a muscle may be fixed to (indices into `bones`): its origin and insertion, or every bone when it names
// neither (then origin and insertion are kNoBone, and a fibre end goes to the nearest bone).
struct AttachmentBones {
  std::vector<int> allowed;
  int origin = kNoBone, insertion = kNoBone;
};

AttachmentBones attachmentBones(const Muscle& muscle, const std::vector<Bone>& bones) {
  AttachmentBones out;
  if (muscle.origin_bone.empty() && muscle.insertion_bone.empty()) {
    for (std::size_t b = 0; b < bones.size(); ++b) out.allowed.push_back(static_cast<int>(b));
    return out;
  }
  if (bones.empty()) return out;  // fibre ends fixed in space, as for any muscle without bones
  for (const std::string* name : {&muscle.origin_bone, &muscle.insertion_bone}) {
    if (name->empty()) continue;
    const auto bone = std::find_if(bones.begin(), bones.end(), [&](const Bone& b) { return b.name == *name; });
    if (bone == bones.end()) {
      std::string known;
      for (const Bone& b : bones) known += (known.empty() ? "'" : ", '") + b.name + "'";
      throw ModelError("muscle '" + muscle.name + "': its " + (name == &muscle.origin_bone ? "origin" : "insertion") +
                       " bone '" + *name + "' is not one of the bones (" + known + ")");
    }
    const int index = static_cast<int>(bone - bones.begin());
    (name == &muscle.origin_bone ? out.origin : out.insertion) = index;
    if (std::find(out.allowed.begin(), out.allowed.end(), index) == out.allowed.end()) out.allowed.push_back(index);
  }
  // A muscle naming one bone only is fixed to it at both ends.
  if (out.origin == kNoBone) out.origin = out.insertion;
  if (out.insertion == kNoBone) out.insertion = out.origin;
  return out;
}

// Fibres run from origin to insertion. A fibre whose start is nearer the insertion bone and whose end is nearer the
// origin bone runs the other way (either end alone can be far from both bones: a tendon leaving the skeleton, an
// attachment patch from the principal axis). Returns (reversed, checked) fibres.
std::pair<int, int> countReversedFibres(const Muscle& muscle, const AttachmentBones& attachment,
                                        const BoneQueries& queries) {
  if (attachment.origin == kNoBone || attachment.origin == attachment.insertion) return {0, 0};
  const SurfaceDistance& origin = queries.surfaces[static_cast<std::size_t>(attachment.origin)];
  const SurfaceDistance& insertion = queries.surfaces[static_cast<std::size_t>(attachment.insertion)];
  int reversed = 0, checked = 0;
  for (const Polyline& fibre : muscle.fibres) {
    if (fibre.cols() < 2 || !fibre.allFinite()) continue;
    const Eigen::Vector3d start = fibre.col(0), end = fibre.col(fibre.cols() - 1);
    ++checked;
    if (insertion.distance(start) < origin.distance(start) && origin.distance(end) < insertion.distance(end))
      ++reversed;
  }
  return {reversed, checked};
}

// The closest pair of particles of one muscle (global indices offset .. offset + count) fixed to different bones.
void findClosestAttachments(const MassSpringSystem& system, Eigen::Index offset, Eigen::Index count,
                            const std::vector<Bone>& bones, MuscleBuildSummary& summary) {
  std::map<int, std::vector<Eigen::Index>> fixed_by_bone;
  for (Eigen::Index i = offset; i < offset + count; ++i)
    if (system.is_fixed[static_cast<std::size_t>(i)] && system.fixed_bone[static_cast<std::size_t>(i)] != kNoBone)
      fixed_by_bone[system.fixed_bone[static_cast<std::size_t>(i)]].push_back(i);
  for (auto a = fixed_by_bone.begin(); a != fixed_by_bone.end(); ++a) {
    Eigen::Matrix3Xd points(3, static_cast<Eigen::Index>(a->second.size()));
    for (std::size_t k = 0; k < a->second.size(); ++k)
      points.col(static_cast<Eigen::Index>(k)) = system.rest_position.col(a->second[k]);
    const PointIndex index(points);
    for (auto b = std::next(a); b != fixed_by_bone.end(); ++b) {
      for (Eigen::Index i : b->second) {
        const double d = index.nearest(system.rest_position.col(i)).second;
        if (d < summary.closest_attachments_m) {
          summary.closest_attachments_m = d;
          summary.closest_attachment_bones[0] = bones[static_cast<std::size_t>(a->first)].name;
          summary.closest_attachment_bones[1] = bones[static_cast<std::size_t>(b->first)].name;
        }
      }
    }
  }
}

double diagonalOf(const TriangleMesh& surface) {
  const AlignedBox box = boundsOf(surface.vertices);
  return box.empty() ? 0.0 : (box.max - box.min).norm();
}

// Refuses every bone of an implausible size beside the muscles (kImplausibleBoneSizeRatio), naming each with both
// sizes and what to check for the direction it is off in.
void refuseImplausibleBoneSizes(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones) {
  const BoneScale scale = measureBoneScale(muscles, bones);
  std::string too_large, too_small, large_links;
  int large_count = 0, small_count = 0;
  for (const BoneSize& size : scale.bones) {
    const bool large = size.ratio >= kImplausibleBoneSizeRatio;
    if (!large && !(size.ratio <= 1.0 / kImplausibleBoneSizeRatio)) continue;
    std::ostringstream line;
    line << std::setprecision(3) << "bone '" << size.bone << "' is " << size.diagonal_m << " m across, ";
    if (large)
      line << std::lround(size.ratio) << " times";
    else
      line << "1/" << std::lround(1.0 / size.ratio) << " of";
    line << " the median muscle (" << scale.median_muscle_diagonal_m << " m)";
    std::string& list = large ? too_large : too_small;
    list += (list.empty() ? "" : "; ") + line.str();
    ++(large ? large_count : small_count);
    if (large) large_links += (large_links.empty() ? "'" : ", '") + size.bone + "'";
  }
  if (too_large.empty() && too_small.empty()) return;
  std::string message = "bone meshes of an implausible size beside the muscles (sizes are bounding-box diagonals; " +
                        std::to_string(std::lround(kImplausibleBoneSizeRatio)) +
                        " times larger or smaller is a unit error, not anatomy): ";
  if (!too_large.empty())
    message += too_large +
               (large_count > 1 ? ". Are these meshes in millimetres? Scale them to metres in the <collision> of links "
                                : ". Is the mesh in millimetres? Scale it to metres in the <collision> of link ") +
               large_links + " in the URDF: <mesh filename=\"...\" scale=\"0.001 0.001 0.001\"/>";
  if (!too_large.empty() && !too_small.empty()) message += ". ";
  if (!too_small.empty())
    message += too_small + (small_count > 1 ? ". Are these meshes" : ". Is the mesh") +
               " scaled twice (a URDF scale of 0.001 on a mesh already in metres), or are the muscle surface and fibre "
               "files in millimetres? Bones and muscles must both be in metres";
  throw ModelError(message);
}

// Counts, for each muscle in turn, its particles that start inside each bone. A bone's inside test is made when a
// particle first falls in its bounding box; a bone whose surface is not closed has no inside and is left out.
class BoneInsides {
 public:
  explicit BoneInsides(const std::vector<Bone>& bones) : bones_(bones), tests_(bones.size()), open_(bones.size(), false) {
    for (const Bone& bone : bones) boxes_.push_back(boundsOf(bone.surface.vertices));
  }

  // Particles of `positions` inside each bone (per bone) and inside any bone.
  std::pair<std::vector<int>, int> count(const Eigen::Matrix3Xd& positions) {
    std::vector<int> per_bone(bones_.size(), 0);
    int inside_any = 0;
    for (Eigen::Index i = 0; i < positions.cols(); ++i) {
      const Eigen::Vector3d p = positions.col(i);
      bool inside = false;
      for (std::size_t b = 0; b < bones_.size(); ++b) {
        if ((p.array() < boxes_[b].min.array()).any() || (p.array() > boxes_[b].max.array()).any()) continue;
        const ClosedSurfaceInsideTest* test = testOf(b);
        if (test == nullptr || !test->contains(p)) continue;
        ++per_bone[b];
        inside = true;
      }
      inside_any += inside ? 1 : 0;
    }
    return {per_bone, inside_any};
  }

 private:
  const ClosedSurfaceInsideTest* testOf(std::size_t b) {
    if (!tests_[b] && !open_[b]) {
      try {
        tests_[b] = std::make_unique<ClosedSurfaceInsideTest>(bones_[b].surface, bones_[b].name);
      } catch (const OpenSurfaceError&) {
        open_[b] = true;
      }
    }
    return tests_[b].get();
  }

  const std::vector<Bone>& bones_;
  std::vector<AlignedBox> boxes_;
  std::vector<std::unique_ptr<ClosedSurfaceInsideTest>> tests_;
  std::vector<bool> open_;
};

// "muscle 'm': 3840 of 4224 particles (91 %) start inside bone 'femur' ..." when more than
// kMostlyInsideBoneWarningFraction of them do; "" otherwise.
std::string mostlyInsideBoneWarning(const Muscle& muscle, const std::vector<Bone>& bones, BoneInsides& insides,
                                    const Eigen::Matrix3Xd& positions) {
  const auto [per_bone, inside_any] = insides.count(positions);
  const auto particles = positions.cols();
  if (particles == 0 || inside_any <= kMostlyInsideBoneWarningFraction * static_cast<double>(particles)) return "";
  std::vector<std::pair<int, std::size_t>> holding;  // (particles inside, bone), most first
  for (std::size_t b = 0; b < bones.size(); ++b)
    if (per_bone[b] > 0) holding.emplace_back(per_bone[b], b);
  std::sort(holding.begin(), holding.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  const auto percent = [&](int count) { return std::lround(100.0 * count / static_cast<double>(particles)); };
  std::ostringstream warning;
  warning << "muscle '" << muscle.name << "': " << inside_any << " of " << particles << " particles ("
          << percent(inside_any) << " %) start inside bone" << (holding.size() > 1 ? "s " : " ");
  for (std::size_t k = 0; k < holding.size(); ++k) {
    warning << (k > 0 ? ", '" : "'") << bones[holding[k].second].name << "'";
    if (holding.size() > 1) warning << " (" << holding[k].first << ", " << percent(holding[k].first) << " %)";
  }
  warning << ", and no collision can keep the muscle out of " << (holding.size() > 1 ? "them" : "it")
          << ". Are the bone meshes in the units (metres) and the frame of the muscle's surface and fibre files? Check "
             "the <mesh scale> and <origin> of the link's <collision> in the URDF";
  return warning.str();
}

// A fibre end to be joined to its bone through a tendon (global particle index before the anchors are inserted).
struct PendingTendon {
  std::int32_t particle;
  int bone;
  bool origin_end;  // the fibre's first particle (its next one inward is particle + 1), else its last
  // The tendon's path beyond the fibre end when the muscle gives one (Muscle::origin_path / insertion_path), from the
  // point nearest the belly to the site; empty: the bone's nearest vertex.
  std::vector<std::pair<int, Eigen::Vector3d>> path;
};

// Each muscle's belly path (Muscle::belly_path) with its points' bone indices.
std::vector<BellyPath> bellyPaths(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones) {
  std::vector<BellyPath> paths(muscles.size());
  for (std::size_t m = 0; m < muscles.size(); ++m) {
    const std::vector<AttachmentSite>& sites = muscles[m].belly_path;
    paths[m].points.resize(3, static_cast<Eigen::Index>(sites.size()));
    for (std::size_t k = 0; k < sites.size(); ++k) {
      const auto bone = std::find_if(bones.begin(), bones.end(), [&](const Bone& b) { return b.name == sites[k].bone; });
      if (bone == bones.end())
        throw ModelError("muscle '" + muscles[m].name + "': its belly path names bone '" + sites[k].bone +
                         "', which is not among the bones");
      paths[m].bones.push_back(static_cast<std::int32_t>(bone - bones.begin()));
      paths[m].points.col(static_cast<Eigen::Index>(k)) = sites[k].point;
    }
  }
  return paths;
}

// Per spring, the cosine of its angle with the fibres' local direction at its two particles at rest; NaN for a spring
// that is not the belly's (a tendon or a tendon anchor's) or has no direction.
std::vector<double> fibreAlignments(const MassSpringSystem& system) {
  const auto on_fibre = [&](Eigen::Index i) { return system.fibre_of[static_cast<std::size_t>(i)] != kTendonAnchor; };
  const Eigen::Matrix3Xd direction = fibreDirections(system, system.rest_position);
  std::vector<double> alignment(system.springs.size(), std::numeric_limits<double>::quiet_NaN());
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const std::int32_t a = system.springs.first[s], b = system.springs.second[s];
    if (!on_fibre(a) || !on_fibre(b)) continue;
    Eigen::Vector3d fibre = direction.col(a) + (direction.col(a).dot(direction.col(b)) < 0 ? -1.0 : 1.0) * direction.col(b);
    const Eigen::Vector3d spring = system.rest_position.col(b) - system.rest_position.col(a);
    if (!(fibre.norm() > 0) || !(spring.norm() > 0)) continue;
    alignment[s] = fibre.normalized().dot(spring.normalized());
  }
  return alignment;
}

// The belly's springs get a rest length shorter by `prestretch` x the square of their alignment with the fibres (the
// local direction of the fibres at their two particles): at its segmented length the belly is under passive tension
// along its fibres, as muscle in the body is, so that when a joint lets its tendon go it shortens instead of going
// slack. Stiffness stays that of the segmented length. Tendons and springs of tendon anchors are left as they are.
void prestretchAlongFibres(MassSpringSystem& system, const std::vector<double>& alignment, double prestretch) {
  system.springs.prestretch_factor.setOnes(static_cast<Eigen::Index>(system.springs.size()));
  for (std::size_t s = 0; s < system.springs.size(); ++s)
    if (!std::isnan(alignment[s])) {
      const double factor = 1.0 - prestretch * alignment[s] * alignment[s];
      system.springs.rest_length[static_cast<Eigen::Index>(s)] *= factor;
      system.springs.prestretch_factor[static_cast<Eigen::Index>(s)] = factor;
    }
}

// The belly's springs across its fibres get `ratio` of their stiffness, those along them keep it, in between by the
// square of their alignment: the transverse isotropy of passive muscle.
void softenAcrossFibres(MassSpringSystem& system, const std::vector<double>& alignment, double ratio) {
  for (std::size_t s = 0; s < system.springs.size(); ++s)
    if (!std::isnan(alignment[s]))
      system.springs.stiffness[static_cast<Eigen::Index>(s)] *= alignment[s] * alignment[s] + ratio * (1.0 - alignment[s] * alignment[s]);
}

// Inserts each tendon's anchor, a particle fixed to the bone at the bone vertex nearest the fibre end, after its
// muscle's particles (muscle ranges stay contiguous), renumbers `spring_pairs` and adds one spring per tendon.
// Tendon springs have their own stiffness (`tendon_stiffness`: spring index -> N/m), stiffness_ratio x material_n over
// the tendon's whole length.
void insertTendonAnchors(MassSpringSystem& system, const std::vector<PendingTendon>& tendons,
                         const std::vector<Bone>& bones, const BoneQueries& queries,
                         std::vector<std::pair<std::int32_t, std::int32_t>>& spring_pairs,
                         std::vector<double>& spring_rest, double material_n, double stiffness_ratio, bool keep_line,
                         std::vector<std::pair<std::int32_t, double>>& tendon_stiffness, ModelBuildReport& report) {
  if (tendons.empty()) return;
  const int muscle_count = system.muscleCount();
  std::vector<std::vector<PendingTendon>> by_muscle(static_cast<std::size_t>(muscle_count));
  for (const PendingTendon& t : tendons)
    by_muscle[static_cast<std::size_t>(system.muscle_of[static_cast<std::size_t>(t.particle)])].push_back(t);
  // A particle of muscle m moves up by the anchors of the muscles before it.
  std::vector<std::int32_t> shift(static_cast<std::size_t>(muscle_count) + 1, 0);
  for (std::size_t m = 0; m < by_muscle.size(); ++m)
    shift[m + 1] = shift[m] + static_cast<std::int32_t>(by_muscle[m].size());
  const auto newIndex = [&](std::int32_t old) {
    return old + shift[static_cast<std::size_t>(system.muscle_of[static_cast<std::size_t>(old)])];
  };

  for (auto& [first, second] : spring_pairs) {
    first = newIndex(first);
    second = newIndex(second);
  }
  const Eigen::Index count = system.particleCount() + static_cast<Eigen::Index>(tendons.size());
  const auto size = static_cast<std::size_t>(count);
  MassSpringSystem grown;
  grown.rest_position.resize(3, count);
  grown.mass.resize(count);
  grown.radius.setZero(count);
  grown.is_fixed.assign(size, 0);
  grown.is_boundary.assign(size, 0);
  grown.fixed_bone.assign(size, kNoBone);
  grown.muscle_of.assign(size, 0);
  grown.fibre_of.assign(size, 0);
  grown.sample_of.assign(size, 0);
  grown.blend_bone.setConstant(MassSpringSystem::kBlendBones, count, kNoBone);
  grown.blend_weight.setZero(MassSpringSystem::kBlendBones, count);
  grown.muscle_name = system.muscle_name;
  grown.muscle_begin.assign(static_cast<std::size_t>(muscle_count) + 1, 0);
  const auto copyParticle = [&](Eigen::Index from, Eigen::Index to) {
    const auto f = static_cast<std::size_t>(from), t = static_cast<std::size_t>(to);
    grown.rest_position.col(to) = system.rest_position.col(from);
    grown.mass[to] = system.mass[from];
    grown.radius[to] = system.radius[from];
    grown.is_fixed[t] = system.is_fixed[f];
    grown.is_boundary[t] = system.is_boundary[f];
    grown.fixed_bone[t] = system.fixed_bone[f];
    grown.muscle_of[t] = system.muscle_of[f];
    grown.fibre_of[t] = system.fibre_of[f];
    grown.sample_of[t] = system.sample_of[f];
    grown.blend_bone.col(to) = system.blend_bone.col(from);
    grown.blend_weight.col(to) = system.blend_weight.col(from);
  };
  for (int m = 0; m < muscle_count; ++m) {
    const auto mi = static_cast<std::size_t>(m);
    const std::int32_t begin = system.muscle_begin[mi], end = system.muscle_begin[mi + 1];
    grown.muscle_begin[mi] = begin + shift[mi];
    for (std::int32_t i = begin; i < end; ++i) copyParticle(i, i + shift[mi]);
    std::int32_t anchor = end + shift[mi];
    MuscleBuildSummary* summary = mi < report.muscles.size() ? &report.muscles[mi] : nullptr;
    for (const PendingTendon& t : by_muscle[mi]) {
      const Eigen::Vector3d fibre_end = system.rest_position.col(t.particle);
      // The anchor: the path's first point (nearest the belly) on its bone, or the attachment bone's nearest vertex.
      const int anchor_bone = t.path.empty() ? t.bone : t.path.front().first;
      const auto b = static_cast<std::size_t>(anchor_bone);
      const Eigen::Vector3d on_bone = t.path.empty()
                                          ? Eigen::Vector3d(bones[b].surface.vertices.col(queries.vertices[b].nearest(fibre_end).first))
                                          : t.path.front().second;
      const auto a = static_cast<std::size_t>(anchor);
      grown.rest_position.col(anchor) = on_bone;
      grown.mass[anchor] = system.mass[t.particle];  // never integrated: fixed
      grown.is_fixed[a] = 1;
      grown.fixed_bone[a] = anchor_bone;
      grown.muscle_of[a] = m;
      grown.fibre_of[a] = kTendonAnchor;
      grown.sample_of[a] = system.fibre_of[static_cast<std::size_t>(t.particle)];  // the fibre it ends
      grown.blend_bone(0, anchor) = anchor_bone;
      grown.blend_weight(0, anchor) = 1.0;
      const double to_anchor = (fibre_end - on_bone).norm();
      double length = to_anchor;  // the whole tendon: to the anchor, then along the path to the site
      TendonPath tendon_path;
      tendon_path.anchor = anchor;
      tendon_path.points.resize(3, static_cast<Eigen::Index>(t.path.size() > 0 ? t.path.size() - 1 : 0));
      for (std::size_t k = 1; k < t.path.size(); ++k) {
        length += (t.path[k].second - t.path[k - 1].second).norm();
        tendon_path.bones.push_back(t.path[k].first);
        tendon_path.points.col(static_cast<Eigen::Index>(k - 1)) = t.path[k].second;
      }
      if (to_anchor > 1e-9) {
        tendon_path.spring = static_cast<std::int32_t>(spring_pairs.size());
        tendon_path.length_m = length;
        spring_pairs.emplace_back(newIndex(t.particle), anchor);
        spring_rest.push_back(to_anchor);
        tendon_stiffness.emplace_back(tendon_path.spring, stiffness_ratio * material_n / length);
        if (!tendon_path.bones.empty()) grown.tendon_paths.push_back(tendon_path);
        if (summary) ++summary->springs;
        // The tendon keeps its line with the fibre's end: a second spring from the anchor to the fibre's next particle,
        // so that a tendon pulled shorter (the joint closing) pushes the belly's end along the fibre instead of letting
        // it swing round the anchor at the tendon's length.
        const std::int32_t inward = t.particle + (t.origin_end ? 1 : -1);
        if (keep_line && inward >= 0 && inward < static_cast<std::int32_t>(system.particleCount()) &&
            system.fibre_of[static_cast<std::size_t>(inward)] == system.fibre_of[static_cast<std::size_t>(t.particle)] &&
            system.muscle_of[static_cast<std::size_t>(inward)] == m) {
          const double to_inward = (system.rest_position.col(inward) - on_bone).norm();
          TendonPath line = tendon_path;
          line.spring = static_cast<std::int32_t>(spring_pairs.size());
          line.length_m = length - to_anchor + to_inward;
          spring_pairs.emplace_back(newIndex(inward), anchor);
          spring_rest.push_back(to_inward);
          tendon_stiffness.emplace_back(line.spring, stiffness_ratio * material_n / line.length_m);
          if (!line.bones.empty()) grown.tendon_paths.push_back(line);
          if (summary) ++summary->springs;
        }
      }
      if (summary) {
        ++summary->tendons;
        ++summary->particles;
        ++summary->fixed_particles;
        ++summary->fixed_by_bone[bones[b].name];
        summary->longest_tendon_m = std::max(summary->longest_tendon_m, length);
        if (!t.path.empty()) ++summary->tendons_to_sites;
      }
      ++anchor;
    }
  }
  grown.muscle_begin.back() = static_cast<std::int32_t>(count);
  system = std::move(grown);
}

}  // namespace

BoneScale measureBoneScale(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones) {
  BoneScale scale;
  std::vector<double> muscle_diagonals;
  for (const Muscle& muscle : muscles) muscle_diagonals.push_back(diagonalOf(muscle.surface));
  if (!muscle_diagonals.empty()) {
    const auto middle = muscle_diagonals.begin() + static_cast<std::ptrdiff_t>(muscle_diagonals.size() / 2);
    std::nth_element(muscle_diagonals.begin(), middle, muscle_diagonals.end());
    scale.median_muscle_diagonal_m = *middle;
  }
  for (const Bone& bone : bones) {
    BoneSize size;
    size.bone = bone.name;
    size.diagonal_m = diagonalOf(bone.surface);
    size.ratio = scale.median_muscle_diagonal_m > 0 ? size.diagonal_m / scale.median_muscle_diagonal_m
                                                    : std::numeric_limits<double>::quiet_NaN();
    scale.bones.push_back(size);
  }
  return scale;
}

MassSpringSystem buildMassSpringSystem(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones,
                                       const ModelSettings& settings, ModelBuildReport* report) {
  const auto start = std::chrono::steady_clock::now();
  if (const std::string problem = validate(settings); !problem.empty()) throw ModelError("model settings: " + problem);
  if (muscles.empty()) throw ModelError("no muscles to simulate");
  for (std::size_t b = 0; b < bones.size(); ++b)
    if (bones[b].surface.triangleCount() == 0)
      throw ModelError("bone '" + bones[b].name + "' has an empty surface mesh");

  ModelBuildReport local_report;
  ModelBuildReport& out = report ? *report : local_report;
  out = ModelBuildReport{};
  const BoneQueries bone_queries = prepareBoneQueries(bones);
  const int bone_count = static_cast<int>(bones.size());

  MassSpringSystem system;
  std::vector<Eigen::Matrix3Xd> positions;
  std::size_t total = 0;
  std::vector<FibreSamples> all_samples;
  for (std::size_t m = 0; m < muscles.size(); ++m) {
    const Muscle& muscle = muscles[m];
    FibreSamples samples;
    try {
      if (muscle.particles_per_fibre != 0 && muscle.particles_per_fibre < 2)
        throw ModelError("particles_per_fibre " + std::to_string(muscle.particles_per_fibre) +
                         " must be at least 2 (or 0: the model's)");
      samples = sampleFibres(muscle.fibres, particlesPerFibreOf(muscle, settings),
                             settings.sampling_seed + static_cast<std::uint32_t>(m));
    } catch (const std::exception& error) {
      throw ModelError("muscle '" + muscle.name + "': " + error.what());
    }
    if (samples.position.cols() == 0)
      throw ModelError("muscle '" + muscle.name + "' has no usable fibre (" + std::to_string(muscle.fibres.size()) +
                       " given, all shorter than 1 micrometre or non-finite)");
    if (muscle.surface.triangleCount() == 0 || !muscle.surface.vertices.allFinite())
      throw ModelError("muscle '" + muscle.name + "' has an empty or non-finite surface mesh");
    total += static_cast<std::size_t>(samples.position.cols());
    all_samples.push_back(std::move(samples));
  }
  // Every muscle surface is there and finite: the bones can be measured against them.
  refuseImplausibleBoneSizes(muscles, bones);
  BoneInsides bone_insides(bones);

  const auto n = static_cast<Eigen::Index>(total);
  system.rest_position.resize(3, n);
  system.mass.resize(n);
  system.radius.setZero(n);
  system.is_fixed.assign(total, 0);
  system.is_boundary.assign(total, 0);
  system.fixed_bone.assign(total, kNoBone);
  system.muscle_of.resize(total);
  system.fibre_of.resize(total);
  system.sample_of.resize(total);
  system.blend_bone.setConstant(MassSpringSystem::kBlendBones, n, kNoBone);
  system.blend_weight.setZero(MassSpringSystem::kBlendBones, n);
  system.muscle_begin.push_back(0);

  std::vector<std::pair<std::int32_t, std::int32_t>> spring_pairs;
  std::vector<double> spring_rest;
  std::vector<PendingTendon> tendons;
  Eigen::Index offset = 0;
  for (std::size_t m = 0; m < muscles.size(); ++m) {
    const Muscle& muscle = muscles[m];
    const FibreSamples& samples = all_samples[m];
    const Eigen::Index count = samples.position.cols();
    const int particles_per_fibre = particlesPerFibreOf(muscle, settings);
    MuscleBuildSummary summary;
    summary.name = muscle.name;
    summary.fibres = static_cast<int>(muscle.fibres.size()) - static_cast<int>(samples.skipped_fibres.size());
    summary.skipped_fibres = static_cast<int>(samples.skipped_fibres.size());
    summary.particles = static_cast<int>(count);
    for (int f : samples.skipped_fibres)
      out.warnings.push_back("muscle '" + muscle.name + "': fibre " + std::to_string(f) +
                             " skipped (fewer than 2 points, non-finite, or shorter than 1 micrometre)");

    double volume = enclosedVolume(muscle.surface);
    if (volume < 0) {
      out.warnings.push_back("muscle '" + muscle.name + "': surface triangles wind inwards; volume taken as positive");
      volume = -volume;
    }
    if (!(volume > 0)) throw ModelError("muscle '" + muscle.name + "': surface encloses no volume");
    summary.volume_m3 = volume;

    system.rest_position.middleCols(offset, count) = samples.position;
    system.mass.segment(offset, count).setConstant(settings.density_kg_per_m3 * volume / static_cast<double>(count));
    const std::vector<std::uint8_t> boundary = markBoundary(muscle, samples, settings.boundary_fibre_fraction);

    // The bones this muscle may be fixed to: its origin and insertion (every bone when it names neither).
    const AttachmentBones attachment = attachmentBones(muscle, bones);
    const auto [reversed_fibres, checked_fibres] = countReversedFibres(muscle, attachment, bone_queries);

    // Per particle: fibre bookkeeping, attachments, and the bones it follows in the rigid pre-transform.
    for (Eigen::Index local = 0; local < count; ++local) {
      const Eigen::Index i = offset + local;
      const Eigen::Vector3d p = samples.position.col(local);
      system.muscle_of[i] = static_cast<std::int32_t>(m);
      system.fibre_of[i] = samples.fibre_of[local];
      system.sample_of[i] = samples.sample_of[local];
      system.is_boundary[i] = boundary[local];
      summary.boundary_particles += boundary[local];
      if (bone_count == 0) {
        const bool fibre_end = samples.sample_of[local] == 0 || samples.sample_of[local] == particles_per_fibre - 1;
        system.is_fixed[i] = settings.fix_fibre_ends && fibre_end ? 1 : 0;
        summary.fixed_particles += system.is_fixed[i];
        continue;
      }
      // Two nearest bones by vertex distance, inverse-square weights: the GRAPP paper's blended rigid transform.
      std::vector<std::pair<double, int>> by_distance;
      for (int b = 0; b < bone_count; ++b) by_distance.emplace_back(bone_queries.vertices[b].nearest(p).second, b);
      std::sort(by_distance.begin(), by_distance.end());

      int attached = kNoBone;
      double attached_distance = settings.attachment_distance_m;
      for (int b : attachment.allowed) {
        const double d = bone_queries.surfaces[b].distanceWithin(p, attached_distance);
        if (d <= attached_distance) {
          attached = b;
          attached_distance = d;
        }
      }
      const bool fibre_start = samples.sample_of[local] == 0;
      const bool fibre_end = fibre_start || samples.sample_of[local] == particles_per_fibre - 1;
      if (attached == kNoBone && settings.fix_fibre_ends && fibre_end) {
        if (attachment.origin != kNoBone) {
          // The fibre's first particle belongs to the origin, its last to the insertion.
          attached = fibre_start ? attachment.origin : attachment.insertion;
        } else {
          double best = std::numeric_limits<double>::infinity();
          for (int b : attachment.allowed) {
            const double d = bone_queries.surfaces[b].distance(p);
            if (d < best) {
              best = d;
              attached = b;
            }
          }
        }
        // Not within attachment_distance_m of that bone (the loop above would have found it): joined by a tendon, along
        // the muscle's tendon path when it has one (nearest the belly first, the site last).
        if (settings.tendons && attached != kNoBone) {
          PendingTendon tendon{static_cast<std::int32_t>(i), attached, fibre_start, {}};
          const std::vector<AttachmentSite>& sites = fibre_start ? muscle.origin_path : muscle.insertion_path;
          for (std::size_t k = 0; k < sites.size(); ++k) {
            const AttachmentSite& site = fibre_start ? sites[sites.size() - 1 - k] : sites[k];
            const auto bone = std::find_if(bones.begin(), bones.end(), [&](const Bone& b) { return b.name == site.bone; });
            if (bone == bones.end())
              throw ModelError("muscle '" + muscle.name + "': its tendon path names bone '" + site.bone +
                               "', which is not among the bones");
            tendon.path.emplace_back(static_cast<int>(bone - bones.begin()), site.point);
          }
          tendons.push_back(std::move(tendon));
          attached = kNoBone;
        }
      }
      if (attached != kNoBone) {
        system.is_fixed[i] = 1;
        system.fixed_bone[i] = attached;
        system.blend_bone(0, i) = attached;
        system.blend_weight(0, i) = 1.0;
        ++summary.fixed_particles;
        ++summary.fixed_by_bone[bones[static_cast<std::size_t>(attached)].name];
        continue;
      }
      const int blended = std::min(bone_count, MassSpringSystem::kBlendBones);
      double weight_sum = 0;
      for (int k = 0; k < blended; ++k) {
        const double d = std::max(by_distance[k].first, 1e-4);
        system.blend_bone(k, i) = by_distance[k].second;
        system.blend_weight(k, i) = 1.0 / (d * d);
        weight_sum += system.blend_weight(k, i);
      }
      system.blend_weight.col(i) /= weight_sum;
    }

    if (const std::string warning = mostlyInsideBoneWarning(muscle, bones, bone_insides, samples.position);
        !warning.empty())
      out.warnings.push_back(warning);
    if (checked_fibres > 0 && 2 * reversed_fibres > checked_fibres)
      out.warnings.push_back("muscle '" + muscle.name + "': " + std::to_string(reversed_fibres) + " of " +
                             std::to_string(checked_fibres) + " fibres start nearer its insertion bone '" +
                             muscle.insertion_bone + "' and end nearer its origin bone '" + muscle.origin_bone +
                             "'; fibres must run from origin to insertion (are origin_bone and insertion_bone "
                             "swapped, or the fibre file reversed?)");
    if (bone_count > 0) {
      findClosestAttachments(system, offset, count, bones, summary);
      if (summary.closest_attachments_m < kCloseAttachmentsWarningM) {
        std::ostringstream warning;
        warning << "muscle '" << muscle.name << "': particles fixed to '" << summary.closest_attachment_bones[0]
                << "' and to '" << summary.closest_attachment_bones[1] << "' are "
                << 1000.0 * summary.closest_attachments_m << " mm apart at rest (less than "
                << 1000.0 * kCloseAttachmentsWarningM
                << " mm): moving the joint between these bones stretches the springs between them, which no solver "
                   "can undo. Check the muscle's origin_bone and insertion_bone, or lower attachment_distance_m";
        out.warnings.push_back(warning.str());
      }
    }

    // Springs of this muscle, in global indices.
    ParticlePairs pairs;
    try {
      pairs = layoutPairs(settings, samples);
    } catch (const std::exception& error) {
      throw ModelError("muscle '" + muscle.name + "': " + toString(settings.spring_layout) + " layout: " + error.what());
    }
    for (const auto& [a, b] : pairs) {
      const double rest = (samples.position.col(a) - samples.position.col(b)).norm();
      if (!(rest > 1e-9)) {
        ++summary.dropped_springs;
        continue;
      }
      spring_pairs.emplace_back(static_cast<std::int32_t>(offset + a), static_cast<std::int32_t>(offset + b));
      spring_rest.push_back(rest);
      ++summary.springs;
    }
    if (summary.dropped_springs > 0)
      out.warnings.push_back("muscle '" + muscle.name + "': " + std::to_string(summary.dropped_springs) +
                             " springs between coincident particles dropped");

    system.muscle_name.push_back(muscle.name);
    offset += count;
    system.muscle_begin.push_back(static_cast<std::int32_t>(offset));
    out.muscles.push_back(summary);
  }

  std::vector<std::pair<std::int32_t, double>> tendon_stiffness;
  insertTendonAnchors(system, tendons, bones, bone_queries, spring_pairs, spring_rest, settings.spring_material_n,
                      settings.tendon_stiffness_ratio, settings.tendon_keeps_line, tendon_stiffness, out);
  const std::size_t spring_count = spring_pairs.size();
  system.springs.first.resize(spring_count);
  system.springs.second.resize(spring_count);
  system.springs.rest_length.resize(static_cast<Eigen::Index>(spring_count));
  system.springs.stiffness.resize(static_cast<Eigen::Index>(spring_count));
  for (std::size_t s = 0; s < spring_count; ++s) {
    system.springs.first[s] = spring_pairs[s].first;
    system.springs.second[s] = spring_pairs[s].second;
    system.springs.rest_length[static_cast<Eigen::Index>(s)] = spring_rest[s];
    system.springs.stiffness[static_cast<Eigen::Index>(s)] = settings.spring_material_n / spring_rest[s];
  }
  for (const auto& [spring, stiffness] : tendon_stiffness) system.springs.stiffness[spring] = stiffness;
  if (settings.transverse_stiffness_ratio < 1 || settings.fibre_prestretch > 0 || settings.fibre_tone > 0) {
    const std::vector<double> alignment = fibreAlignments(system);
    if (settings.transverse_stiffness_ratio < 1) softenAcrossFibres(system, alignment, settings.transverse_stiffness_ratio);
    if (settings.fibre_prestretch > 0) prestretchAlongFibres(system, alignment, settings.fibre_prestretch);
    if (settings.fibre_tone > 0) system.belly_tone = buildBellyTone(system, alignment, settings.fibre_tone, bellyPaths(muscles, bones));
  }
  // Collision spheres of the boundary particles (the seeds' radius heuristic); the adaptive time step uses them too.
  const std::vector<MuscleRadiiSummary> radii = assignCollisionRadii(system, muscles);
  for (std::size_t m = 0; m < radii.size() && m < out.muscles.size(); ++m) out.muscles[m].mean_radius_m = radii[m].mean_radius_m;
  out.build_ms = millisecondsSince(start);
  return system;
}

MassSpringSystem systemFromParticles(const Eigen::Matrix3Xd& positions, const ParticlePairs& springs,
                                     double particle_mass_kg, double spring_material_n) {
  MassSpringSystem system;
  const Eigen::Index n = positions.cols();
  const auto count = static_cast<std::size_t>(n);
  system.rest_position = positions;
  system.mass.setConstant(n, particle_mass_kg);
  system.radius.setZero(n);
  system.is_fixed.assign(count, 0);
  system.is_boundary.assign(count, 0);
  system.fixed_bone.assign(count, kNoBone);
  system.muscle_of.assign(count, 0);
  system.fibre_of.assign(count, 0);
  system.sample_of.resize(count);
  for (std::size_t i = 0; i < count; ++i) system.sample_of[i] = static_cast<std::int32_t>(i);
  system.blend_bone.setConstant(MassSpringSystem::kBlendBones, n, kNoBone);
  system.blend_weight.setZero(MassSpringSystem::kBlendBones, n);
  system.muscle_begin = {0, static_cast<std::int32_t>(n)};
  system.muscle_name = {"particles"};
  system.springs.rest_length.resize(static_cast<Eigen::Index>(springs.size()));
  system.springs.stiffness.resize(static_cast<Eigen::Index>(springs.size()));
  for (std::size_t s = 0; s < springs.size(); ++s) {
    const double rest = (positions.col(springs[s].first) - positions.col(springs[s].second)).norm();
    system.springs.first.push_back(springs[s].first);
    system.springs.second.push_back(springs[s].second);
    system.springs.rest_length[static_cast<Eigen::Index>(s)] = rest;
    system.springs.stiffness[static_cast<Eigen::Index>(s)] = spring_material_n / rest;
  }
  return system;
}

}  // namespace muscle_deformation
