// How the collision stage runs: broad phase, bone sphere rule, reach margin.
#pragma once

#include "muscle_deformation/core/collision/bone_distance_field.hpp"

#include <string>

namespace muscle_deformation {

enum class BroadPhaseKind {
  octree,     // the seeds' method: per-object AABB octree split at the box midpoint, built lazily, refitted
  hash_grid,  // uniform spatial hash grid (Teschner et al. 2003), rebuilt whenever the object moved
};

const char* toString(BroadPhaseKind kind);

// Which vertices may become roots of the one-ring heuristic.
enum class OneRingRule {
  // Thesis 4.3 as written: any vertex not yet marked becomes a root, and it and its ring are marked. Two roots are
  // never neighbours, so their triangle fans are disjoint; every vertex is a root or in a root's ring, so a convex
  // surface is covered completely (at the price of overlapping spheres).
  disjoint_triangle_fans,
  // Stricter: a root's whole ring must be unmarked, so the vertex rings are disjoint. About half the spheres, but a
  // vertex can be two edges from the nearest root and left up to ~0.8 edge lengths outside every sphere.
  disjoint_vertex_rings,
};

// What stands in for a bone in muscle-bone contacts.
enum class BoneProxyKind {
  // The seeds' spheres (thesis 4.3) against the boundary particles' spheres: a bone sphere sticks out of the bone, and
  // a muscle sphere it overlaps at rest is shrunk or dropped (clearRestOverlaps).
  one_ring_spheres,
  // The bone itself: every free particle (interior ones too) is kept `radius` outside the bone's signed distance field
  // (BoneDistanceField), or no deeper than it lay at rest when the data put it closer; nothing is dropped.
  distance_field,
};

const char* toString(BoneProxyKind kind);

struct CollisionSettings {
  // Default chosen by measurement (bench/collision_bench.cpp, 13 muscles x 64 fibres, 2-core shared machine, one
  // thread): the octree's muscle-muscle pass took 0.23-0.36 ms per iteration against the hash grid's 1.7-3.4 ms,
  // and its muscle-bone pass 0.38-0.55 ms against 0.45-0.72 ms, at every size from 20 to 80 particles per fibre.
  BroadPhaseKind broad_phase = BroadPhaseKind::octree;
  int octree_max_depth = 8;        // GRAPP 2014: empirically 8
  int octree_min_primitives = 10;  // a node with at most this many spheres is a leaf (GRAPP 2014: 10)
  double hash_cell_scale = 1.0;    // hash cell edge = this x the mean sphere diameter of the hashed object
  double bone_reach_margin_m = 0.0;  // a bone is tested only if its sphere bounds grown by this reach some muscle's
  // Skip muscle-bone tests whose sphere bounds do not overlap (a whole bone when it reaches no muscle): exact, since
  // spheres lie inside their bounds. false sends every muscle-bone pair to the broad phase, to measure what the
  // skip saves (bench/economy_bench.cpp); results are the same either way.
  bool skip_bones_out_of_reach = true;
  OneRingRule bone_sphere_rule = OneRingRule::disjoint_triangle_fans;  // for bones given as meshes
  BoneProxyKind bone_proxy = BoneProxyKind::one_ring_spheres;
  BoneFieldSettings bone_field;  // for bone_proxy distance_field
};

// Returns an empty string when the settings are usable, otherwise what is wrong.
std::string validate(const CollisionSettings& settings);

}  // namespace muscle_deformation
