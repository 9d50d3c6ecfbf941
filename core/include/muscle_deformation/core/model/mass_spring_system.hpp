// The mass-spring system (MSS) of all simulated muscles, stored as structure of arrays.
//
// Particles of every muscle live in one set of arrays; muscle m owns the contiguous index range
// [muscle_begin[m], muscle_begin[m+1]). Springs never join two muscles.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace muscle_deformation {

constexpr int kNoBone = -1;
// fibre_of of a tendon's bone end: a particle fixed to a bone that belongs to no fibre (see ModelSettings::tendons).
constexpr int kTendonAnchor = -1;

struct SpringSet {
  std::vector<std::int32_t> first;   // particle index
  std::vector<std::int32_t> second;  // particle index, != first
  Eigen::VectorXd rest_length;       // metres
  Eigen::VectorXd stiffness;         // N/m  (material constant / rest length)
  // Per spring, its rest length over its length in the segmented shape (1 - fibre_prestretch a^2 for the belly's
  // springs under passive tension, ModelSettings::fibre_prestretch); empty: 1 for every spring. Strain is measured
  // against the shape, so that a belly's pre-tension is not counted as deformation.
  Eigen::VectorXd prestretch_factor;

  std::size_t size() const { return first.size(); }
};

// A tendon whose path runs on past its anchor over points on bones (via points, the attachment site). The length of
// that fixed part changes with the pose when the points lie on different bones (the psoas over the pelvic brim to the
// femur), and the tendon's whole length is what it keeps: its spring's rest length is the whole rest length minus the
// fixed part's length in the pose (updateTendonRestLengths).
struct TendonPath {
  std::int32_t spring = -1;            // the spring from the fibre end to the anchor
  std::int32_t anchor = -1;            // the anchor particle (fixed to its bone at the path's first point)
  std::vector<std::int32_t> bones;     // the bone of each path point beyond the anchor, in order to the site
  Eigen::Matrix3Xd points = Eigen::Matrix3Xd(3, 0);  // those points at rest, scene frame
  double length_m = 0;                 // the tendon's whole rest length: fibre end to site along the path
};

// The line a muscle's belly follows between its tendons where it bends round a bone (Muscle::belly_path), from
// origin to insertion: points carried rigidly by their bones, at rest in the scene frame.
struct BellyPath {
  std::vector<std::int32_t> bones;
  Eigen::Matrix3Xd points = Eigen::Matrix3Xd(3, 0);
};

// One fibre's attachments, for the belly's tone (BellyTone): the particles fixed to its bones at its two ends (the
// fibre's own end when it is fixed there, else its tendon's anchor) and the tendon paths that run on past them.
struct FibreSpan {
  std::int32_t first_anchor = -1, last_anchor = -1;  // fixed particles
  std::int32_t first_path = -1, last_path = -1;      // index into tendon_paths; -1: none
  std::int32_t muscle = -1;   // its muscle: the belly path between the anchors (BellyTone::belly_paths)
  double rest_span_m = 0;     // anchor to anchor (along the belly path), plus the paths beyond them, at rest
  double belly_length_m = 0;  // the fibre's arc length at rest
};

// The belly's tone (ModelSettings::fibre_tone): each fibre's rest length follows the change of the span between its
// attachments as the bones carry them (a stiff tendon passes the joint's motion to the belly), along the fibres only.
// Empty (gain 0): the rest lengths are the model's.
struct BellyTone {
  double gain = 0;  // share of the span's change the belly's rest length takes (1: all of it)
  std::vector<FibreSpan> fibres;  // every fibre of every muscle, in particle order
  // Per muscle (or empty): the belly path a fibre's span runs along from its first anchor to its last; no points:
  // the straight line.
  std::vector<BellyPath> belly_paths;
  // Per spring: the fibres of its two particles (indices into `fibres`; -1: not the belly's), the square of its
  // alignment with the fibres, and its rest length without the tone.
  std::vector<std::int32_t> first_fibre, second_fibre;
  Eigen::VectorXd alignment_squared;
  Eigen::VectorXd untoned_rest_length;
  // Per fibre: the factor the last updateBellyTone gave its rest length (empty before the first; 1 at rest).
  std::vector<double> factor;
  bool empty() const { return gain == 0 || fibres.empty(); }
};

struct MassSpringSystem {
  // Rest configuration (scene frame, metres) and per-particle properties.
  Eigen::Matrix3Xd rest_position = Eigen::Matrix3Xd(3, 0);
  Eigen::VectorXd mass;                  // kg
  Eigen::VectorXd radius;                // m, collision sphere radius (0 for particles that never collide)
  std::vector<std::uint8_t> is_fixed;    // 1: moves rigidly with fixed_bone (attachment), never integrated
  std::vector<std::uint8_t> is_boundary; // 1: on a fibre nearest the surface; takes part in collision
  std::vector<std::int32_t> fixed_bone;  // bone index for fixed particles, kNoBone otherwise
  std::vector<std::int32_t> muscle_of;   // muscle index of each particle
  std::vector<std::int32_t> fibre_of;    // fibre index within its muscle; kTendonAnchor for a tendon's bone end
  std::vector<std::int32_t> sample_of;   // position along the fibre, 0 = fibre start

  // Rigid pre-transform weights: each particle follows a blend of up to kBlendBones bones.
  static constexpr int kBlendBones = 2;
  Eigen::Matrix<std::int32_t, kBlendBones, Eigen::Dynamic> blend_bone;  // kNoBone for unused slots
  Eigen::Matrix<double, kBlendBones, Eigen::Dynamic> blend_weight;      // sums to 1 per particle

  std::vector<std::int32_t> muscle_begin;  // size muscles + 1
  std::vector<std::string> muscle_name;

  SpringSet springs;
  std::vector<TendonPath> tendon_paths;  // tendons whose path goes on past their anchor (ModelSettings::tendons)
  BellyTone belly_tone;  // ModelSettings::fibre_tone

  Eigen::Index particleCount() const { return rest_position.cols(); }
  int muscleCount() const { return static_cast<int>(muscle_name.size()); }
  std::size_t modelBytes() const;  // heap bytes of the arrays above
  // Median radius of the particles that collide (radius > 0), 0 when none does: the scale contacts and penetrations
  // are judged by (a contact deeper than it puts a particle of median size with its centre inside).
  double medianCollisionRadius() const;
};

// Dynamic state the solver advances. Kept apart from the model so one model serves many solves.
struct ParticleState {
  Eigen::Matrix3Xd position = Eigen::Matrix3Xd(3, 0);
  Eigen::Matrix3Xd previous_position = Eigen::Matrix3Xd(3, 0);  // Verlet: velocity = (x - x_prev) / dt
  // Where the tissue around the muscles carries each particle this frame: the previous result moved with the bones
  // (warm start) or the rigid pre-transform (cold). The tissue drag of block descent pulls towards it; empty: the
  // position on entry to the solve. Solvers without drag ignore it.
  Eigen::Matrix3Xd carried_position = Eigen::Matrix3Xd(3, 0);
  // Where the bones carry the rest shape this frame (the rigid pre-transform of the rest positions): the anchor of
  // block descent's across-fibre tie (BlockDescentSettings::across_fibre_tie); empty without one.
  Eigen::Matrix3Xd rest_carried_position = Eigen::Matrix3Xd(3, 0);
  // The force that holds the rest shape in balance (restBalanceForces), turned with the bones this frame (N): the
  // tie's constant part (BlockDescentSettings::balance_rest_shape); empty without one.
  Eigen::Matrix3Xd rest_balance_force = Eigen::Matrix3Xd(3, 0);
};

// The force on each free particle that balances its springs (tendons included) at the rest positions: the springs'
// net force there, reversed (N; zero on fixed particles). Zero for springs at their rest length; a pre-tensioned belly
// (SpringSet::prestretch_factor) has it where its fibres curve and where they meet their tendons.
Eigen::Matrix3Xd restBalanceForces(const MassSpringSystem& system);

// The belly's tone at `gain` (BellyTone), from the springs' `alignment` with the fibres (NaN: not the belly's) and the
// muscles' belly paths (per muscle, or empty: straight spans). Call after the tendons and the rest lengths are final.
BellyTone buildBellyTone(const MassSpringSystem& system, const std::vector<double>& alignment, double gain,
                         std::vector<BellyPath> belly_paths = {});

// Per particle, the summed stiffness of its springs (N/m).
Eigen::VectorXd springStiffnessSums(const MassSpringSystem& system);

// Calls visit(begin, count) for each fibre's particles in order (particles of one fibre are stored consecutively, from
// the fibre start), tendon anchors left out; the order of BellyTone::fibres.
template <class Visit>
void forEachFibre(const MassSpringSystem& system, Visit&& visit) {
  Eigen::Index begin = 0;
  for (Eigen::Index i = 1; i <= system.particleCount(); ++i) {
    const bool fibre_ends = i == system.particleCount() || system.fibre_of[i] != system.fibre_of[i - 1] ||
                            system.muscle_of[i] != system.muscle_of[i - 1];
    if (!fibre_ends) continue;
    if (system.fibre_of[begin] != kTendonAnchor) visit(begin, i - begin);
    begin = i;
  }
}

// The deformed fibres: each fibre's particles in order from its start (all muscles, in particle order), tendon
// anchors left out.
std::vector<Eigen::Matrix3Xd> fibrePolylines(const MassSpringSystem& system, const Eigen::Matrix3Xd& position);

// Whether the fibres keep their line: a fibre pushed shorter than its belly can follow buckles instead (a chain of
// springs has no bending stiffness), and its arc length then no longer measures the muscle's length.
struct FibreFolding {
  int fibres = 0;  // of two particles or more
  // Fibres that turn back on themselves somewhere (two consecutive segments more than 90 degrees apart) where they did
  // not at rest.
  int folded_fibres = 0;
  // The largest, over fibres, of the fibre's tortuosity (arc length over end-to-end distance) divided by its rest
  // tortuosity: 1 = as straight as at rest. NaN without fibres.
  double worst_tortuosity_ratio = std::numeric_limits<double>::quiet_NaN();
  int worst_muscle = -1;         // the muscle of that fibre
  int most_folded_muscle = -1;   // the muscle with the most folded fibres, -1 when none folded
};
FibreFolding measureFibreFolding(const MassSpringSystem& system, const Eigen::Matrix3Xd& position);

// The unit direction of each particle's fibre at `position`: from the particle before it on its fibre to the one after
// it (one-sided at a fibre's ends); zero for tendon anchors, for a fibre of one particle, and everywhere when the
// system has no fibre labels or `position` is not one column per particle.
Eigen::Matrix3Xd fibreDirections(const MassSpringSystem& system, const Eigen::Matrix3Xd& position);

}  // namespace muscle_deformation
