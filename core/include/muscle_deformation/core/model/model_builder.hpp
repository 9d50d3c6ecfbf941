// Building the mass-spring system of a set of muscles around a set of bones (pre-processing of thesis 4.4.2).
#pragma once

#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/model/spring_layout.hpp"

#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

struct ModelSettings {
  int particles_per_fibre = 20;
  std::uint32_t sampling_seed = 1;
  SpringLayout spring_layout = SpringLayout::nearest_neighbours;
  int nearest_neighbours = 18;             // thesis: 15-20
  double attachment_distance_m = 0.002;    // particles closer than this to their muscle's origin or insertion bone
                                           // surface are fixed to it (near any other bone they collide)
  bool fix_fibre_ends = true;              // first particle of every fibre fixed to the muscle's origin bone, last
                                           // to its insertion bone (fibres run origin to insertion)
  // A fibre end further than attachment_distance_m from its bone is joined to the bone's nearest surface point by a
  // tendon (a spring to a particle fixed there) instead of being fixed where it lies: the segmented bellies of long
  // muscles end centimetres from their bones (hamstrings ~10 cm above the tibia, tensor fasciae latae 34 cm), and a
  // point fixed that far from a bone swings with the bone's rotation like the end of a rigid lever.
  bool tendons = true;
  // A tendon's stiffness: this x spring_material_n / its whole rest length (the belly's springs have
  // spring_material_n / rest length). Real tendon is orders of magnitude stiffer than passive muscle, so that a joint's
  // motion stretches the belly, not the tendon; 1 = the belly's material (the seeds' one spring).
  double tendon_stiffness_ratio = 1.0;
  // A tendon also joins its anchor to the fibre's next particle inward, so that it keeps its line with the fibre's end:
  // pulled shorter (a joint closing) it pushes the belly along the fibre rather than letting the end swing round the
  // anchor. A passive belly hanging from a string would take no shortening at all.
  bool tendon_keeps_line = false;
  // The belly's passive tension at its segmented length: its springs rest shorter by this share along the fibres
  // (0 = the segmented length is the rest length, the seeds' model). A belly at rest length goes slack when a joint
  // shortens its path; one under tension shortens with it.
  double fibre_prestretch = 0.0;
  // The belly's tone: each fibre's rest length along the fibres follows this share of the change of the span between
  // its two attachments as the bones carry them (plus its tendons' paths beyond their anchors), relative to its belly's
  // length (0 = none, the passive belly; 1 = all of it, as a tendon far stiffer than the belly passes the joint's
  // motion to it). A muscle in gait is active: its fibres take the length its path leaves them, while its tendon,
  // ~10^3 x stiffer than passive muscle, hardly stretches (in a Hill model with a rigid tendon the fibre length is the
  // path length less the tendon's). Clamped to +-25 % of the belly's length (kMaxToneChange).
  double fibre_tone = 0.0;
  // The belly's stiffness across its fibres relative to along them: a spring's stiffness is material / rest length x
  // (a^2 + ratio (1 - a^2)), a its alignment with the fibres. Passive muscle is transversely isotropic, its tensile
  // modulus across the fibres about 1/20 of that along them (22 against 447 kPa, Morrow et al. 2010, J Mech Behav
  // Biomed Mater 3:124); 1 = the seeds' isotropic springs. A belly soft across its fibres thickens cheaply, so that it
  // can shorten at constant volume.
  double transverse_stiffness_ratio = 1.0;
  double spring_material_n = 10.0;         // stiffness = material constant / rest length (N / m)
  double density_kg_per_m3 = 1060.0;       // skeletal muscle; particle mass = density * volume / particles
  double boundary_fibre_fraction = 0.3;    // share of a fibre's 16 probe points (spread along it) that must be the
                                           // closest probe of some surface vertex for a boundary fibre
                                           // (0: every fibre, so every particle collides; to measure
                                           // what the seeds' boundary-only collision saves)
};

// Invalid settings or input (e.g. a muscle with no usable fibre); the message names the muscle and the problem.
class ModelError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct MuscleBuildSummary {
  std::string name;
  int fibres = 0;
  int skipped_fibres = 0;   // too short or non-finite, left out
  int particles = 0;
  int boundary_particles = 0;
  int fixed_particles = 0;  // tendon anchors included, fibre ends joined through a tendon not
  int tendons = 0;          // fibre ends joined to their bone through a tendon (ModelSettings::tendons)
  double longest_tendon_m = 0;
  int tendons_to_sites = 0;  // of `tendons`, those running along the muscle's tendon path to its attachment site
  int springs = 0;          // tendons included
  int dropped_springs = 0;  // joined coincident particles (zero rest length)
  double mean_radius_m = 0; // mean collision sphere radius of the boundary particles
  double volume_m3 = 0;
  std::map<std::string, int> fixed_by_bone;  // fixed particles per bone name
  // The closest two particles fixed to different bones, at rest (infinity when at most one bone holds particles):
  // two bones that move apart stretch the springs between such particles, which no solver can undo.
  double closest_attachments_m = std::numeric_limits<double>::infinity();
  std::string closest_attachment_bones[2];
};

// Particles fixed to two different bones closer than this at rest (m) make buildMassSpringSystem warn, naming the
// muscle and the bones: a joint between those bones moving pulls them apart by centimetres.
constexpr double kCloseAttachmentsWarningM = 0.005;

// How big each bone is beside the muscles it is built with: the diagonal of its rest bounding box over the median of
// the muscles' (the scene's typical muscle). Bones and muscles must both be in metres; a mesh in other units is off by
// orders of magnitude, and nothing downstream says so: a URDF mesh in millimetres without scale="0.001 0.001 0.001"
// makes a bone 1000 times too large, and most particles start inside it.
struct BoneSize {
  std::string bone;
  double diagonal_m = 0;
  double ratio = 0;  // diagonal_m / BoneScale::median_muscle_diagonal_m
};
struct BoneScale {
  double median_muscle_diagonal_m = 0;
  std::vector<BoneSize> bones;  // in the order of `bones`
};
BoneScale measureBoneScale(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones);

// buildMassSpringSystem refuses a bone this many times larger or smaller than the median muscle (BoneSize::ratio at
// least this, or at most its inverse), naming the bone and both sizes. Anatomy stays far inside: human bones span
// about 1 cm (a phalanx) to under 1 m (a torso link holding spine and ribs) across, muscles about 3 cm to 0.5 m, so a
// bone lies within about 35 times a scene's median muscle either way, even in a scene that selects only its smallest
// or only its largest muscle. The bundled scene: bones 0.27 (patella, 67 mm) to 1.8 times (femur, 0.44 m) its median
// muscle (0.247 m), and 0.14 to 9.1 times any one of its muscles alone. A unit error is 1000 times (millimetres read as
// metres, or a scale of 0.001 applied twice), which the smallest bundled bone reaches at 270 times (143 beside the
// largest muscle alone).
constexpr double kImplausibleBoneSizeRatio = 100.0;

// buildMassSpringSystem warns, naming the muscle, the bones and the fraction, when more than this fraction of a
// muscle's particles start inside bones (closed bone surfaces only: an open one has no inside). Segmented muscles
// touch their bones, and a few particles may start in them (none of the bundled scene's 33,280 does); most of a muscle
// inside a bone is a bone in the wrong place or units, and no collision can keep the muscle out of it.
constexpr double kMostlyInsideBoneWarningFraction = 0.5;

struct ModelBuildReport {
  std::vector<MuscleBuildSummary> muscles;
  std::vector<std::string> warnings;
  double build_ms = 0;
};

// Throws ModelError on invalid settings or unusable input (among others a muscle naming an origin or insertion bone
// that is not in `bones`). Bones may be empty (fibre ends are then fixed in space). Attachments follow the anatomy: a
// particle is fixed only to its muscle's origin or insertion bone (Muscle::origin_bone, insertion_bone; any bone when
// the muscle names neither) and collides with the others; a fibre's first particle goes to the origin and its last to
// the insertion (fix_fibre_ends), through a tendon when it lies further than attachment_distance_m from its bone
// (ModelSettings::tendons): the tendon's bone end is a particle fixed to the bone (fibre_of kTendonAnchor, stored
// after its muscle's fibre particles), joined to the fibre end by one spring of the muscle's material whose rest
// length is their rest distance. The report warns, naming the muscle, when particles fixed to two bones lie closer
// than kCloseAttachmentsWarningM at rest, when most fibres run from the insertion to the origin bone, and when more
// than kMostlyInsideBoneWarningFraction of a muscle's particles start inside bones; it refuses (ModelError) bones of an
// implausible size beside the muscles (kImplausibleBoneSizeRatio). Boundary particles get their collision radii
// (assignCollisionRadii, the seeds' heuristic); others radius 0.
MassSpringSystem buildMassSpringSystem(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones,
                                       const ModelSettings& settings, ModelBuildReport* report = nullptr);

// A bare system from given particles and springs (no fibres, no bones), for tests and small analytic set-ups:
// uniform mass, stiffness = material / rest length, no particle fixed or boundary, zero radius.
MassSpringSystem systemFromParticles(const Eigen::Matrix3Xd& positions, const ParticlePairs& springs,
                                     double particle_mass_kg, double spring_material_n);

// Checks settings; returns an empty string when valid, otherwise what is wrong.
std::string validate(const ModelSettings& settings);

}  // namespace muscle_deformation
