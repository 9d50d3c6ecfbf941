// The collision sphere radius of each muscle particle (the seeds' heuristic, thesis 4.3): a property of the model,
// which the collision stage reads.
#pragma once

#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"

#include <string>
#include <vector>

namespace muscle_deformation {

struct MuscleRadiiSummary {
  std::string name;
  int boundary_particles = 0;
  int particles_without_vertex = 0;  // no surface vertex had them as closest: half the nearest spacing used
  int reduced_pairs = 0;             // overlapping same-muscle pairs shrunk to touching
  double mean_radius_before_m = 0;   // mean over boundary particles, before the overlap reduction
  double mean_radius_m = 0;          // after
};

// The seeds' heuristic (thesis 4.3). For each muscle, every surface vertex is associated with its closest boundary
// particle (rest positions); a particle's radius is the mean distance to its associated vertices. A boundary particle
// no vertex chose gets half the distance to its nearest other boundary particle of the muscle: it lies behind
// particles nearer the surface, so it should fill the gap between its neighbours without poking out.
// Then radii are reduced until no two spheres of the same muscle overlap: overlapping pairs are visited from the
// deepest relative overlap, and both radii of a pair still overlapping are scaled by d / (r_i + r_j) so the two just
// touch. Radii only shrink, so a pair once fixed stays fixed and one pass suffices.
// Interior particles get radius 0 and never collide. `muscles` are in the order of system.muscle_name.
std::vector<MuscleRadiiSummary> assignCollisionRadii(MassSpringSystem& system, const std::vector<Muscle>& muscles);

}  // namespace muscle_deformation
