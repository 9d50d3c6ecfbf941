// Moving particles with the bones before the soft-body solve (thesis 4.2, GRAPP 3.1).
#pragma once

#include "muscle_deformation/core/base/bone_transforms.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"

#include <Eigen/Geometry>

#include <vector>

namespace muscle_deformation {

// Cold start: every particle moved by the distance-weighted blend of its nearest bones' transforms (fixed particles
// exactly with their bone); previous = current, i.e. the solve starts at rest.
// `threads` (here and below): the particles (fibres, springs) are split over that many threads; each is computed alone,
// so the result does not depend on it.
void rigidPretransform(const MassSpringSystem& system, const BoneTransforms& transforms, ParticleState& state,
                       int threads = 1);

// Vectors given per particle in the rest frame (a force, a direction) turned as the rigid pre-transform turns each
// particle's neighbourhood: by the blend of its bones' rotations (a plain weighted sum, as the positions are blended).
Eigen::Matrix3Xd carryRestVectors(const MassSpringSystem& system, const BoneTransforms& transforms,
                                  const Eigen::Matrix3Xd& rest_vectors, int threads = 1);

// Warm start from the previous result: the fixed (attached) particles go exactly to their bones; each free particle
// keeps its previous shape but moves with the blend of its bones' motion since the previous pose
// (new * previous^-1), so that only the change of shape is left to the solver, not the bones' travel. Velocities are
// zeroed (previous = current): the old velocities belong to the old pose.
void warmStart(const MassSpringSystem& system, const BoneTransforms& previous_transforms,
               const BoneTransforms& transforms, ParticleState& state, int threads = 1);

// Only the fixed (attached) particles follow their bones; free particles keep the previous result and velocity.
void moveAttachments(const MassSpringSystem& system, const BoneTransforms& transforms, ParticleState& state);

// Tendons whose path runs on past their anchor (system.tendon_paths): the length of that fixed part in the pose, and
// the rest length their spring then has (the tendon's whole rest length minus it, at least kMinTendonRestLengthM),
// written into system.springs.rest_length. True if any changed: the solvers must read them again
// (SoftBodySolver::restLengthsChanged).
constexpr double kMinTendonRestLengthM = 1e-4;
double tendonPathBeyondAnchor(const MassSpringSystem& system, const TendonPath& tendon, const BoneTransforms& transforms);
bool updateTendonRestLengths(MassSpringSystem& system, const BoneTransforms& transforms);

// The belly's tone (system.belly_tone): each fibre's span between its attachments in the pose against its rest span;
// the belly's springs' rest lengths become their untoned ones x (1 + a^2 (f - 1)), with f = 1 + gain x (span change)
// / belly length, the mean over the spring's two fibres, clamped to [1 - kMaxToneChange, 1 + kMaxToneChange]. True if
// any changed (SoftBodySolver::restLengthsChanged).
// 0.25: the gait's lengths against gait2392 are the same as at 0.4, and the iliacus in hip flexion to 1.5 rad, whose
// span shrinks by more, loses 3.5 % of its volume instead of 4.7 % (fidelity bench, 2026-11-28); muscle fibres work
// within about +-25-40 % of their optimal length.
constexpr double kMaxToneChange = 0.25;
// A fibre's span in the pose: from its first anchor through its muscle's belly path (tone.belly_paths; none: straight)
// to its last anchor, plus its tendons' paths beyond them (empty transforms: at rest).
double fibreSpanLength(const MassSpringSystem& system, const BellyTone& tone, const FibreSpan& span,
                       const BoneTransforms& transforms);
// The factor the tone gives one fibre's belly for its span's change (m, pose against rest): 1 + gain x change / belly
// length, held to [1 - kMaxToneChange, 1 + kMaxToneChange]; `limited` (optional) says whether the limit held it. 1 for
// a fibre without a belly length.
double fibreToneFactor(const BellyTone& tone, const FibreSpan& span, double span_change_m, bool* limited = nullptr);
bool updateBellyTone(MassSpringSystem& system, const BoneTransforms& transforms, int threads = 1);
// Each fibre's arc length at `positions` (tendon anchors left out), in the order of BellyTone::fibres.
std::vector<double> fibreArcLengths(const MassSpringSystem& system, const Eigen::Matrix3Xd& positions);
// The most a fibre stretches with its tone in one frame (stretchWithTone), as a share of its length. 0.01, measured with
// the stability bench (thigh13, 2026-11-28): unlimited, the gait played 4x faster (the tone changing 4x as much a frame)
// reached a strain 99th percentile of 0.66 median and a fibre 2.0x as tortuous as at rest, against 0.36 and 1.27 with
// the previous answer carried rigidly; held to 1 % a frame, 0.33 and 1.22. The 1-cycle gait's lengths against gait2392
// keep most of the gain (docs/lengths.md).
constexpr double kMaxToneStretchPerFrame = 0.01;
// The tissue carries the belly along its fibres as its tone changes (SimulationSettings::drag_follows_tone): each fibre
// of `carried` (the previous answer moved with the bones, or the rest shape so moved) is stretched along itself by the
// ratio that brings its arc length to `previous_arcs` (before the carrying) x the change of its tone factor since
// `previous_factor` (empty: from rest, 1), held between 1 and that change and to +-kMaxToneStretchPerFrame: about its fixed particles (those and the
// particles between them stay), or without one about its particles' mean position along it weighted by `stiffness_sum`
// (springStiffnessSums); a particle stiffer than the fibre's median moves less by that ratio. Nothing without the tone
// or before its first update.
void stretchWithTone(const MassSpringSystem& system, const Eigen::VectorXd& stiffness_sum,
                     const std::vector<double>& previous_factor, const std::vector<double>& previous_arcs,
                     Eigen::Matrix3Xd& carried);

// State at rest: positions = rest positions, zero velocity.
ParticleState restState(const MassSpringSystem& system);

}  // namespace muscle_deformation
