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
// than kCloseAttachmentsWarningM at rest, and when most fibres run from the insertion to the origin bone. Boundary
// particles get their collision radii (assignCollisionRadii, the seeds' heuristic); others radius 0.
MassSpringSystem buildMassSpringSystem(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones,
                                       const ModelSettings& settings, ModelBuildReport* report = nullptr);

// A bare system from given particles and springs (no fibres, no bones), for tests and small analytic set-ups:
// uniform mass, stiffness = material / rest length, no particle fixed or boundary, zero radius.
MassSpringSystem systemFromParticles(const Eigen::Matrix3Xd& positions, const ParticlePairs& springs,
                                     double particle_mass_kg, double spring_material_n);

// Checks settings; returns an empty string when valid, otherwise what is wrong.
std::string validate(const ModelSettings& settings);

}  // namespace muscle_deformation
