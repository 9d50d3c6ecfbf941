// Quasi-static block descent on the mass-spring energy, in the manner of Vertex Block Descent (Chen, Ibrahim, Yuksel,
// SIGGRAPH 2024), with contacts as energy in the same solve.
//
// The answer of a solve is the equilibrium of the springs, contacts and tissue drag for the fixed particles of the
// pose: the minimiser of
//   E(x) = sum_springs k/2 (|x_a - x_b| - l0)^2 + sum_contacts kc/2 max(0, d - |x_p - c|)^2
//          + sum_free w_p/2 |x_p - y_p|^2
// over the free particles, where y is where the tissue around the muscles carries each particle this frame (the
// previous result moved with the bones, or the rigid pre-transform) and w_p = (tissue_relaxation_s / frame interval)
// x the particle's summed spring stiffness: one implicit step of overdamped motion. Without the drag term the spring
// energy of the bundled muscles is nearly flat along some shape changes (a slender muscle bending, a muscle swinging
// on its tendon: 3e-6 of a particle's own stiffness), so its minimiser is neither unique nor reachable in a frame;
// with it every frame has one answer, which the sweeps reach in a few steps. A sweep visits every free particle once and moves it by one Newton step of its own 3 x 3
// problem (the other particles held), with each spring's Hessian projected to be positive semi-definite. Particles
// are visited colour by colour (a greedy colouring of the spring graph), so the particles of one colour share no
// spring and are updated in parallel; the result does not depend on the thread count. Contacts are found once per
// sweep by the collision stage and enter each particle's step as stiff one-sided springs, so a contact is part of the
// equilibrium rather than a correction the next update undoes.
//
// Convergence is a force residual: the root mean square, over free particles, of the net force on each particle when
// its step is taken, relative to the springs' material constant (k l0, the force of a spring at 100 % strain).
#pragma once

#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/collision/contact_set.hpp"
#include "muscle_deformation/core/solvers/soft_body_solver.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

namespace muscle_deformation {

struct BlockDescentSettings {
  // Contact stiffness relative to the springs: kc = contact_stiffness_scale x (material constant / median collision
  // radius), so a contact resists penetration about this many times harder than a spring of one radius' length
  // resists stretch, and for each particle at least this many times its own summed spring stiffness, so that none of
  // its springs holds it inside a sphere by more than about 1 / scale of the overlap.
  double contact_stiffness_scale = 100.0;
  // The same for contacts between two muscles' particles alone (0 = contact_stiffness_scale). All of block descent's
  // residual that is left after many sweeps sits on particles pressed together by such pairs (docs/realtime.md, "Where
  // block descent levels off"): contacts that much stiffer than the springs pass corrections back and forth from
  // colour to colour. A softer pair scale lets those clusters settle while bones keep the stiff contacts that hold
  // particles out of them.
  double muscle_contact_stiffness_scale = 0.0;
  double pairStiffnessScale() const {
    return muscle_contact_stiffness_scale > 0 ? muscle_contact_stiffness_scale : contact_stiffness_scale;
  }
  // Contacts are looked for once per sweep among pairs closer than this many median collision radii to touching, so
  // that a particle that reaches a sphere during the sweep meets it in its own step.
  // 1: measured on the bundled 26 muscles, one warm sweep then ends 0.06 mm deep in bone at most (0.5: up to 0.9 mm,
  // a particle stepping past the margin in its first step) for 0.3-0.6 ms more detection; 2 costs 2 ms more.
  double contact_margin_scale = 1.0;
  // Newton steps a particle with contacts takes per visit (the contact switches on or off within the step; the
  // others take one: their energy is smooth).
  int contact_newton_steps = 3;
  // Chebyshev semi-iterative acceleration (Wang 2015) of the sweeps: the estimated spectral radius of the plain
  // iteration, in [0, 1); 0 = off. Starts after chebyshev_delay sweeps of a solve.
  double chebyshev_rho = 0.0;
  int chebyshev_delay = 4;
  // Tissue drag (s): the time constant with which a free particle pulled off the balance of its own springs returns to
  // it through the tissue that holds it (see the formula above). 0 = none: the quasi-static equilibrium of springs and
  // contacts alone (the analytic cases of the tests); the node's default is in nodeDefaultSettings().
  double tissue_relaxation_s = 0.0;
  // The share of the tissue drag that acts along the fibre, in [0, 1]: the drag's tensor is
  // w_p ((I - t t^T) + drag_along_fibre t t^T) with t the fibre's direction at the particle where the tissue carries it.
  // 1 = the same drag in every direction (the seeds' isotropic damping); below 1 the belly slides along its own fibres
  // more freely than it moves across them, so a joint that shortens or lengthens a muscle's path reaches its belly
  // within the frame (the slow whole-length mode is along the fibres).
  double drag_along_fibre = 1.0;
  // Across-fibre tie to the anatomy: each free particle is pulled, across its fibre only, towards where the bones carry
  // its rest position (state.rest_carried_position, the rigid pre-transform), with stiffness across_fibre_tie x its
  // summed spring stiffness; its energy is 1/2 across_fibre_tie k_p |(I - t t^T)(x - h)|^2 with t the fibre's direction
  // in that carried rest shape (so that a held pose has one fixed tie; the drag then takes the same direction). A pre-tensioned fibre pulls its curved belly towards its chord, and the drag
  // alone only slows that (the muscles crept by centimetres from their segmented shape over seconds at rest); the tie
  // holds the belly's cross-section where the anatomy has it and leaves the fibre free to lengthen and shorten. Rides
  // on the tissue drag (needs tissue_relaxation_s > 0, whose frame anchor it shares). 0 = none.
  double across_fibre_tie = 0.0;
  // With the tie: the tie also carries the force that holds the rest shape in balance (state.rest_balance_force, the
  // springs' net force at rest reversed, turned with the bones). A pre-tensioned belly is not at rest in its segmented
  // shape: its curved fibres pull towards their chords and its fibre ends pull their tendons, so after a cold start it
  // settled for a hundred frames and more (thigh13: 2.7 mm RMS, 18 mm at most, at rest). In the body the surrounding
  // tissue bears that load; a constant force has no stiffness, so the model's response to a joint's motion is the same
  // with it and the segmented shape is the rest pose's equilibrium. Merged into the drag's anchor like the tie (which
  // needs drag_along_fibre > 0 for the part along the fibre). Ignored without the tie.
  bool balance_rest_shape = false;
  // Incompressibility: each muscle's volume term (volume_term.hpp) has stiffness k_m = volume_stiffness x material
  // constant x (skin particles) / (rest volume x rest skin area), so that a relative volume change e pulls each particle
  // the skin follows with about volume_stiffness x e of the springs' material constant. 0 = none (the seeds' model);
  // the pipeline supplies the volume (the skinned surface's) when this is above 0.
  double volume_stiffness = 0.0;
  // The share of a frame's remaining volume error that each muscle's pressure takes on after the frame (the
  // augmented Lagrangian's multiplier update, once per solved frame, by the simulation: VolumeTerm::target_volume_m3),
  // in [0, 1]. 0 = a plain penalty, whose answer keeps an error that falls only as 1 / volume_stiffness; above 0 a
  // steady or slow motion drives the error towards none over the frames, at a stiffness the sweeps still settle with.
  double volume_pressure_gain = 0.0;
  // A coarse step along the fibres before every sweep: each muscle's free particles move along their fibres by a
  // profile of this many hat functions of the position along the fibre (0 at its start, 1 at its end), chosen by a
  // Newton step on the frame energy within that subspace (its Hessian assembled from the springs, contacts, drag and
  // the volume term) and kept only if the energy falls. A belly's length is the slowest mode of the particle sweeps
  // (each particle sees its neighbours held); this moves the whole belly along its fibres at once. 0 = none; at most 16.
  int fibre_modes = 0;
};

// Returns an empty string when the settings are usable, otherwise what is wrong.
std::string validate(const BlockDescentSettings& settings);

// The threads a parallel part runs on: `threads` when positive, otherwise every core (0, and -1 before a measurement
// chooses), at most what limits.max_threads allows now.
int parallelThreads(int threads, const SolveLimits& limits);
// `threads` within the cap SolveLimits::max_threads holds now (none or <= 0: no cap).
int cappedThreads(int threads, const SolveLimits& limits);

// Net force on every free particle at `position` (springs only), as the RMS over free particles relative to the
// springs' material constant: the convergence measure of an equilibrium, for any solver's result. Contacts are not
// included; benchmarks compare solvers on it at contact-free states or state it beside the penetration.
double relativeSpringResidual(const MassSpringSystem& system, const Eigen::Matrix3Xd& position);

class BlockDescentSolver final : public SoftBodySolver {
 public:
  SolverKind kind() const override { return SolverKind::block_descent; }
  // Worker threads of the sweeps. Positions do not depend on them. 0 = every core. kThreadsMeasured (-1) = one thread
  // or every core, whichever is faster as measured while the solver runs (both are tried first, and the slower again
  // every kThreadProbeInterval sweeps): every core stops paying once another process holds one all the time, as a
  // colour's threads then wait at its barrier for the descheduled one. Measured on 2 cores, all 26 bundled muscles,
  // one sweep a frame: quiet, both 11.3-11.7 ms; beside rviz rendering in software (make demo) every core 16.2 ms
  // against 18.8 ms measured (the estimate, one probe per 32 sweeps, follows rviz's bursts); beside a busy loop on one
  // core 19.3 against 17.7 ms. Viewing in rviz on the same machine is the product's common case, hence every core by
  // default.
  static constexpr int kThreadsMeasured = -1;
  // Colours the spring graph and packs each particle's springs (once). Throws std::invalid_argument on invalid
  // settings or threads below kThreadsMeasured.
  BlockDescentSolver(const MassSpringSystem& system, BlockDescentSettings settings, int threads = 0);

  // Sweeps until `stopping` is met (any rule). Fixed particles keep the positions `state` holds on entry. Contacts come
  // from the query set with setContactQuery (none without one); `after_update` runs after every sweep like the other
  // solvers' collision hook (normally empty: contacts are in the solve). A non-finite result puts the entry state back
  // and reports `diverged`.
  // The solve has `converged` when its last full sweep's force residual lies below stopping.residual_tolerance,
  // whatever rule ended it.
  SolveStats solve(ParticleState& state, const StoppingSettings& stopping,
                   const AfterUpdateHook& after_update = {}) override;
  bool solvesContacts() const override { return true; }
  bool dragsTissue() const override { return settings_.tissue_relaxation_s > 0; }
  bool tiesToRestShape() const override { return tiesAcrossFibres(); }
  bool balancesRestShape() const override { return balancesRest(); }
  // The muscles' volume term (volume_term.hpp) joins the frame energy: evaluated before every sweep, each particle's
  // step takes its muscle's volume as it stands after the colours before it.
  bool keepsVolume() const override { return true; }
  void restLengthsChanged() override;
  void setVolumeTerm(VolumeTerm term) override;
  void setVolumeTargets(const std::vector<double>& target_volume_m3) override;
  std::vector<double> dragShareOfVolumeTargets(const ParticleState& state) override;
  const VolumeTerm& volumeTerm() const { return volume_; }
  // Clamped to [kMinFrameIntervalS, kMaxFrameIntervalS] (a pose stream's gaps, whatever their cause, give the tissue
  // no more than a tenth of a second to relax in); kNominalFrameIntervalS until set.
  void setFrameInterval(double seconds) override;
  static constexpr double kMinFrameIntervalS = 1e-3, kMaxFrameIntervalS = 0.1;
  double frameInterval() const { return frame_interval_s_; }
  void setContactQuery(ContactQuery query, bool every_particle_collides) override;

  // The relative RMS net force (springs, contacts, tissue drag towards state.carried_position when it is set and the
  // across-fibre tie when it is on, as
  // this solver models them) on the free particles at `state`,
  // whichever solver produced it: the common measure of how far a state is from the equilibrium. Does not change the
  // state (uses the contact query).
  double residualOf(const ParticleState& state);
  // What one full sweep at `state` must at least move through memory and compute, counted from the data structures
  // (the counting is in the .cpp): the floor a sweep's time is judged against (bytes over the machine's bandwidth,
  // flops over its floating-point rate). Lists the contacts at `state` (uses the contact query).
  struct SweepCost {
    double bytes = 0;
    double flops = 0;
  };
  SweepCost sweepCost(const ParticleState& state);
  const BlockDescentSettings& settings() const { return settings_; }
  int colourCount() const { return static_cast<int>(colour_begin_.size()) - 1; }
  int threadCount() const { return thread_count_; }
  // Threads of the next full sweep: threadCount(), or with kThreadsMeasured one or every core as measured, within the
  // cap of `limits` (SolveLimits::max_threads).
  int sweepThreads(const SolveLimits& limits = {}) const;
  // With kThreadsMeasured, the slower of one thread and every core is tried again after this many sweeps on the faster.
  static constexpr int kThreadProbeInterval = 32;
  double materialConstant() const { return material_constant_n_; }
  double contactStiffness() const { return contact_stiffness_; }  // the floor; per particle it may be higher
  // Relative RMS residual of the last sweep of the last solve (forces when each particle was visited).
  double lastResidual() const { return last_residual_; }
  // Squared net force (N^2) on each particle when the last sweep visited it (0 for fixed particles).
  const Eigen::VectorXd& particleResidualsSquared() const { return residual_squared_; }
  const ContactSet& lastContacts() const { return contacts_; }

  // The frame's energy seen as a whole, for a solver that moves every free particle at once on the same energy
  // (NewtonKrylovSolver): beginFrame gathers the contacts at `state` within `margin_m` of touching (< 0: the sweeps'
  // margin) and takes its carried positions as the drag anchor; the other calls then evaluate at any positions until
  // endFrame. `state` must outlive the frame.
  void beginFrame(const ParticleState& state, double margin_m = -1);
  void endFrame() { drag_anchor_ = nullptr; }
  double frameEnergy(const Eigen::Matrix3Xd& position) const;
  // Net force (minus the gradient) on every particle (zero for fixed ones) and the inverse of each free particle's
  // 3 x 3 block of the projected Hessian, by particle index.
  void frameForces(const Eigen::Matrix3Xd& position, Eigen::Matrix3Xd& force,
                   std::vector<Eigen::Matrix3d>& inverse_blocks);
  // The projected Hessian at `position` times `direction` (rows of fixed particles zero; their directions unused).
  void frameHessianTimes(const Eigen::Matrix3Xd& position, const Eigen::Matrix3Xd& direction,
                         Eigen::Matrix3Xd& product);
  const std::vector<std::int32_t>& freeParticles() const { return free_particles_; }
  double contactMargin() const { return contact_margin_m_; }
  // Whether a particle's step is bounded by the contact margin (it collides).
  bool boundedStep(std::int32_t particle) const { return bounded_step_[static_cast<std::size_t>(particle)] != 0; }
  const ContactSet& frameContacts() const { return contacts_; }

  // One contact as a sweep reads it, gathered per particle (public for the sweep's inline helpers).
  struct ContactEntry {
    Eigen::Vector3d centre;  // obstacle centre, the partner particle's position, or a point of a half-space's plane
    Eigen::Vector3d normal;  // a half-space's outward unit normal (unused otherwise)
    double distance;         // least distance from the centre (spheres); 0 for a half-space
    std::int32_t partner;    // particle index of the partner, kObstacle or kHalfSpace
    bool same_colour;        // the partner is moved in the same parallel step
    static constexpr std::int32_t kObstacle = -1, kHalfSpace = -2;
    // How far `x` is inside the contact (> 0 when touching) and the direction that leaves it.
    double depth(const Eigen::Vector3d& x, Eigen::Vector3d& direction) const;
    double depth(const Eigen::Vector3d& x) const {
      Eigen::Vector3d unused;
      return depth(x, unused);
    }
  };

 private:
  struct NeighbourSpring {
    std::int32_t other;
    double stiffness;
  };
  void buildColouring();
  void updateDragWeights();
  void gatherContacts(const ParticleState& state, double margin_m = -1);  // < 0: contact_margin_m_
  // contact_slots_ / contact_slot_begin_ from the contacts gathered last (before the closing contact pass).
  void listContactSlots();
  // One sweep over every colour (or only the particles touching a contact); returns the summed squared residual force
  // and summed |step| of the free particles.
  void sweep(Eigen::Matrix3Xd& position, double& residual_squared_sum, double& displacement_sum, int threads,
             bool touching_only = false);
  // threads = 0: one thread or every core for the next full sweep, from the measured sweep times.
  int measuredThreadChoice() const;
  void recordSweepTime(int threads, double milliseconds);

  const MassSpringSystem& system_;
  BlockDescentSettings settings_;
  int threads_setting_ = 0;  // as constructed: > 0, 0 (every core) or kThreadsMeasured
  int thread_count_ = 1;
  // kThreadsMeasured: running estimates of a full sweep's wall time on one thread [0] and on every core [1] (ms, 0 = not
  // measured yet), and full sweeps since the slower one last ran.
  double sweep_ms_[2] = {0, 0};
  int sweeps_since_probe_ = 0;
  double material_constant_n_ = 1.0;
  double contact_stiffness_ = 0.0;
  double contact_margin_m_ = 0.0;
  double mean_rest_length_ = 0.0;
  std::vector<std::int32_t> neighbour_begin_;  // per particle, into neighbours_ (while building)
  std::vector<NeighbourSpring> neighbours_;      // each free particle's springs, in visiting order
  // Their rest lengths, entry by entry, apart: the pose changes them every frame (restLengthsChanged), and rewriting
  // them inside neighbours_ moved three times the bytes. Double: a spring at its rest length exerts exactly no force.
  std::vector<double> neighbour_rest_length_;
  std::vector<std::int32_t> slot_spring_begin_;  // per visiting slot (index into coloured_particles_), into neighbours_
  // The entries of neighbours_ whose rest length changes with the pose, (spring, entry): each tendon spring with a path
  // (system.tendon_paths), and every spring when the belly has a tone (system.belly_tone).
  std::vector<std::pair<std::int32_t, std::int32_t>> pose_dependent_entries_;
  std::vector<std::int32_t> colour_of_;        // per particle, -1 for fixed ones
  std::vector<std::int32_t> colour_begin_;     // into coloured_particles_
  std::vector<std::int32_t> coloured_particles_;
  std::vector<std::int32_t> free_particles_;
  Eigen::VectorXd regularisation_;
  Eigen::VectorXd spring_stiffness_sum_;  // per particle, N/m
  // The drag and the across-fibre tie share one quadratic per particle (both act along the same fibre direction t):
  // w (I - (1 - a) t t^T) about the carried position c plus tau (I - t t^T) about the rest carried by the bones h is,
  // up to a constant, (w + tau)(I - (1 - a') t t^T) about m = c + tau / (w + tau) (I - t t^T)(h - c), with
  // a' = w a / (w + tau). drag_weight_ and drag_along_ are the combined weight and share, drag_anchor_ points at m when
  // the tie is on (tied_anchor_), at c otherwise. The rest balance b (a constant force, energy -b^T x) moves that
  // anchor by W^-1 b with W = (w + tau)(I - (1 - a') t t^T), up to a constant.
  Eigen::VectorXd drag_weight_;           // per particle for the current frame interval, N/m (0 for fixed ones)
  double drag_along_ = 1.0;               // the combined share along the fibre (settings' drag_along_fibre untied)
  double tie_share_ = 0.0;                // tau / (w + tau): the tie's share of the merged anchor (0 untied)
  double frame_interval_s_ = kNominalFrameIntervalS;
  const Eigen::Matrix3Xd* drag_anchor_ = nullptr;  // during a solve: where the tissue carries each particle
  Eigen::Matrix3Xd tied_anchor_;                   // m above, for the frame (empty without the tie)
  // The unit fibre direction of each particle at the carried position, with the tie in the carried rest shape
  // (fibreDirections), set only while the drag is weaker along the fibre than across it (always with the tie).
  Eigen::Matrix3Xd drag_direction_;
  bool anisotropicDrag() const { return drag_along_ < 1.0; }
  bool tiesAcrossFibres() const { return settings_.across_fibre_tie > 0; }  // validated: only with the drag
  bool balancesRest() const { return tiesAcrossFibres() && settings_.balance_rest_shape; }
  // drag_direction_ from the fibres at `anchor` (nothing when the drag is isotropic).
  void updateDragDirections(const Eigen::Matrix3Xd& anchor);
  // The frame's drag anchor: `carried` (the state's carried positions, or its entry positions without them), or with the
  // tie on the merged anchor written to `merged` (throws when the state lacks its rest carried positions); sets
  // drag_direction_ on the way.
  const Eigen::Matrix3Xd& frameDragAnchor(const ParticleState& state, const Eigen::Matrix3Xd& carried,
                                          Eigen::Matrix3Xd& merged);
  // Particle p's fibre direction for the drag: zero (every direction alike) when the drag is isotropic.
  Eigen::Vector3d dragDirection(std::int32_t p) const {
    return anisotropicDrag() ? Eigen::Vector3d(drag_direction_.col(p)) : Eigen::Vector3d::Zero();
  }
  // The drag's energy 1/2 (x - c)^T D (x - c) of particle p at x with anchor c.
  double dragEnergy(std::int32_t p, const Eigen::Vector3d& x, const Eigen::Vector3d& carried) const;
  // A contact's stiffness on particle p: against an obstacle or a half-space p's own, between two muscles' particles the
  // larger of both ends' pair stiffness (a pair's energy is one).
  double contactStiffnessOf(std::int32_t p, const ContactEntry& entry) const {
    return entry.partner >= 0 ? std::max(particle_pair_stiffness_[p], particle_pair_stiffness_[entry.partner])
                              : particle_contact_stiffness_[p];
  }
  Eigen::VectorXd particle_pair_stiffness_;  // per particle, N/m: the same with muscle_contact_stiffness_scale
  Eigen::VectorXd particle_contact_stiffness_;  // per particle, N/m

  ContactQuery contact_query_;
  ContactSet contacts_;
  std::vector<std::int32_t> contact_begin_;    // per particle, into contact_entries_
  // The visiting slots (into coloured_particles_) of particles with a contact, in colour order, and per colour where
  // they begin in it (the closing contact pass visits these alone; listContactSlots).
  std::vector<std::int32_t> contact_slots_, contact_slot_begin_;
  std::vector<ContactEntry> contact_entries_;
  std::vector<std::uint8_t> bounded_step_;     // per particle: collidable (radius > 0, or any free particle against a
                                               // bone field), so with contacts queried its step is cut to the margin

  Eigen::VectorXd residual_squared_, step_length_;  // per particle, of the current sweep
  VolumeTerm volume_;                  // empty: no volume term
  std::vector<double> volume_now_;     // per muscle, during a sweep (updated colour by colour)
  Eigen::Matrix3Xd volume_gradient_;   // per particle, at the start of the sweep
  Eigen::VectorXd volume_change_;      // per particle: g . step of its visit in the current colour
  Eigen::Matrix3Xd volume_step_;       // per particle with a volume gradient: its step without the volume term
  Eigen::Matrix3Xd volume_inverse_gradient_;  // per particle: H_p^-1 g_p (its block without the volume term)
  std::vector<std::uint8_t> volume_pending_;  // per particle: its step waits for its colour's volume solve
  std::vector<std::uint8_t> volume_direct_;   // per particle: took the volume term in its own step (in contact)
  std::vector<double> colour_a_, colour_b_;   // per muscle, scratch of applyVolumeSteps
  Eigen::VectorXd step_bound_;         // per particle: the longest step allowed this visit (< 0: none)
  // The particle's step cut to its bound (the contact margin plus its starting depth).
  void limitStep(std::int32_t p, const Eigen::Vector3d& start, Eigen::Vector3d& x) const;
  // The volume term's share of the steps of one colour's particles (those with a volume gradient), then their moves.
  // `slots`: the visiting slots (into coloured_particles_) the sweep visited, [begin, end) of them; nullptr: the slots
  // begin .. end themselves.
  void applyVolumeSteps(Eigen::Matrix3Xd& position, const std::int32_t* slots, std::int32_t begin, std::int32_t end,
                        int threads);
  // The volume term's value and gradient at `position` into volume_now_ / volume_gradient_ (nothing when off).
  void evaluateVolume(const Eigen::Matrix3Xd& position);
  // sum_m k_m / 2 (V_m - target_m)^2 for the volumes in volume_now_.
  double volumeEnergy() const;
  // sum_m k_m / 2 (V_m - target_m)^2 for any per-muscle volumes.
  double volumeEnergyOf(const std::vector<double>& volumes) const;
  // The coarse step along the fibres (settings_.fibre_modes): each free particle's position along its fibre in [0, 1]
  // and its visiting slot; the step's scratch.
  Eigen::VectorXd fibre_parameter_;
  std::vector<std::int32_t> slot_of_;
  Eigen::Matrix3Xd fibre_step_, fibre_trial_;
  // Fixed chunks of the particles that the frame energy and the coarse step's sums are split into for the threads,
  // summed in order afterwards: the same bits on any number of threads.
  static constexpr int kEnergyChunks = 64;
  std::vector<double> fibre_accumulator_;  // fibreModeStep's per-chunk sums
  std::array<double, kEnergyChunks> fibre_start_energy_{};  // fibreModeStep's per-chunk frame energy at its start
  void buildFibreModes();
  // One coarse step at `position` (contacts and the volume term as the sweep about to run sees them); true when it
  // lowered the frame energy and was kept.
  bool fibreModeStep(Eigen::Matrix3Xd& position);
  // The frame energy without the volume term (springs, contacts as listed, drag).
  double energyWithoutVolume(const Eigen::Matrix3Xd& position) const;
  // Free particle p's share of the frame energy: its contacts and its drag; its springs (each listed at both ends).
  double contactAndDragEnergy(std::int32_t p, const Eigen::Matrix3Xd& position) const;
  double springEnergyAtSlot(std::size_t slot, const Eigen::Matrix3Xd& position) const;  // the particle visited there
  Eigen::Matrix3Xd chebyshev_older_, chebyshev_previous_, entry_position_;
  double last_residual_ = 0.0;
};

}  // namespace muscle_deformation
