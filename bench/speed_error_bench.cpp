// Speed against error on the well-posed problem: the bundled thigh13 muscles (13), block descent with the node's
// tissue drag (a frame has one answer, block_descent_solver.hpp), at several resolutions and spring layouts, streamed
// over the 1-cycle gait and solved cold at five gait poses. Each configuration is one point with three kinds of error:
//
//   convergence  RMS particle distance to the converged answer of the same model (resolution and layout), as the
//                real-time bench measures it: stream frames against the converged stream (every frame warm from the
//                previous converged frame, kStreamReferenceSweeps sweeps; frame 0 cold) from the same converged frame
//                0; cold poses against the same pose given kColdReferenceSweeps sweeps from its rigid pre-transform.
//   resolution   RMS and largest distance between the vertices of the skinned muscle surfaces and those of the finest
//                model (80 particles per fibre, 128 fibres per muscle, converged) at the same gait frames (stream:
//                18, 36, 54, 72; frame 0 is every stream's common start) or poses (cold: the five gait poses); and the
//                same for each muscle's mean belly fibre length. The surfaces are the skin of the particles alone:
//                neither the skin's contact with the bones nor the volume projection moves them, so the figure is the
//                model's and not a correction's.
//   anatomy      (stream) each muscle's belly length over the gait against gait2392 (gait_lengths.hpp): the excursion
//                ratio farthest from 1 and the lowest r over the 13 muscles; and the model's volume error (the skinned
//                surface before any projection) at its worst muscle and compared frame or pose (skinning every frame
//                of the finest model costs seconds a frame, so the stream's volume is read at the compared frames).
//
// The references' own convergence is measured and written: their force residual and how far the last stream frame and
// the middle cold pose move when given as many sweeps again.
//
// Resolution per muscle: from the converged streams, each muscle's surface error against the finest model at each
// resolution; a mixed model takes for each muscle the coarsest resolution whose error at every checked frame stays
// within the worst muscle's error of uniform 20 particles per fibre, and is measured (references and configurations)
// like the uniform ones in the same run.
//
// The peer: Bullet's soft bodies on the 20 x 64 model's particles and springs (bullet_peer.hpp), streamed over the gait
// from the converged frame 0 at its default and more position iterations: frame time and distance to the converged
// stream (solver "bullet_soft_body"; its other errors null).
//
// Fibre sets: 64 per muscle are the bundled ones (data/fibres/); 32 and 128 are generated here the same way
// (generate_fibres' Laplace streamlines seeded on the field's mid-value section); a muscle whose section does not fit
// 128 separate fibres keeps fewer (the count used is written).
//
// Writes out/bench/speed_vs_error.json: one object per configuration (keys below; null where not measured), one per
// (model, muscle) for the per-muscle errors (solver "per_muscle"), one per model for its references (solver
// "reference") and one for the machine's measured bandwidth and floating-point rate (solver "machine").
//
//   speed_error_bench [--out DIR] [--quick]
#include "bench_util.hpp"
#include "convergence_run.hpp"
#include "gait_lengths.hpp"
#include "machine_floor.hpp"
#include "node_defaults.hpp"
#include "stream_play.hpp"
#ifdef MD_HAVE_BULLET
#include "bullet_peer.hpp"
#endif

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/preprocessing/fibre_generator.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

using namespace muscle_deformation;

namespace {

double elapsedSeconds() {
  static const auto start = std::chrono::steady_clock::now();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// One model of the thigh13 muscles: its resolution and spring layout. A mixed model gives each muscle its own.
struct ModelVariant {
  std::string label;
  int particles_per_fibre = 20;
  int fibres_per_muscle = 64;
  SpringLayout layout = SpringLayout::nearest_neighbours;
  int neighbours = 18;
  std::vector<int> muscle_particles_per_fibre;  // mixed: per muscle (else empty)
  std::vector<int> muscle_fibres;               // mixed: per muscle, a key of the fibre sets (else empty)
  bool mixed() const { return !muscle_particles_per_fibre.empty(); }
};

std::string layoutLabel(SpringLayout layout, int neighbours) {
  return layout == SpringLayout::nearest_neighbours ? "nearest" + std::to_string(neighbours) : toString(layout);
}

ModelVariant uniform(int particles_per_fibre, int fibres, SpringLayout layout = SpringLayout::nearest_neighbours,
                     int neighbours = 18) {
  ModelVariant v;
  v.particles_per_fibre = particles_per_fibre;
  v.fibres_per_muscle = fibres;
  v.layout = layout;
  v.neighbours = neighbours;
  v.label = std::to_string(particles_per_fibre) + " x " + std::to_string(fibres) + " " + layoutLabel(layout, neighbours);
  return v;
}

using FibreSets = std::map<int, std::vector<std::vector<Polyline>>>;  // fibres per muscle -> [muscle] fibres

std::vector<Muscle> musclesOf(const BundledScene& bundled, const FibreSets& sets, const ModelVariant& v) {
  std::vector<Muscle> muscles = bundled.scene.muscles;
  for (std::size_t m = 0; m < muscles.size(); ++m) {
    const int fibres = v.mixed() ? v.muscle_fibres[m] : v.fibres_per_muscle;
    muscles[m].fibres = sets.at(fibres)[m];
    muscles[m].particles_per_fibre = v.mixed() ? v.muscle_particles_per_fibre[m] : 0;
  }
  return muscles;
}

// The node's pipeline for a model, skinning the particles with neither the skin's bone contact nor the volume
// projection (the model's own surface) and measuring its volume.
PipelineSettings pipelineFor(const CoreSettings& node, const ModelVariant& v, SolverKind kind, int threads,
                             int lbfgs_history = 0) {
  PipelineSettings settings = node.pipeline;
  ModelSettings& model = settings.simulation.model;
  model.particles_per_fibre = v.particles_per_fibre;
  model.spring_layout = v.layout;
  model.nearest_neighbours = v.neighbours;
  settings.simulation.solver_kind = kind;
  settings.simulation.local_global.lbfgs_history = lbfgs_history;
  settings.threads = threads;
  settings.skin_surfaces = true;
  settings.measure_fidelity = true;
  settings.keep_surfaces_out_of_bones = false;
  settings.surface_volume.keep_volume = false;
  return settings;
}

FrameStopping sweepsOf(const CoreSettings& node, int sweeps) {
  FrameStopping stopping = node.stream.stopping;
  stopping.sweeps.rule = StoppingRule::iterations;
  stopping.sweeps.max_iterations = sweeps;
  stopping.sweeps.limits = {};
  return stopping;
}

// Per muscle mean belly fibre length (m) of the pipeline's current state.
std::vector<double> fibreLengthsOf(const DeformationPipeline& pipeline) {
  bench::MuscleLengths lengths;
  bench::addLengthsOf(pipeline, lengths);
  std::vector<double> out;
  for (const std::vector<double>& series : lengths.belly) out.push_back(series.front());
  return out;
}

// The last frame's per-muscle mean belly fibre lengths of a series just appended to.
std::vector<double> latestBellyLengths(const bench::MuscleLengths& lengths) {
  std::vector<double> out;
  for (const std::vector<double>& series : lengths.belly) out.push_back(series.back());
  return out;
}

// Largest |volume error| (% of rest) over the frame's muscles; absent without metrics.
std::optional<double> volumeErrorOf(const FrameResult& frame) {
  if (!frame.has_metrics) return std::nullopt;
  double worst = 0;
  for (const MuscleMetrics& muscle : frame.metrics.muscles) worst = std::max(worst, std::abs(muscle.volume_error_pct));
  return worst;
}

// Sums of squared vertex distances, counts and largest distance, per muscle.
struct SurfaceError {
  std::vector<double> squared_sum, max;
  std::vector<long> count;
  std::vector<double> worst_frame_rms;  // per muscle: the largest RMS of one frame

  void add(const std::vector<Vertices>& surfaces, const std::vector<Vertices>& finest) {
    if (surfaces.empty() || surfaces.size() != finest.size())
      throw std::runtime_error("no skinned surfaces to compare (skinning disabled?)");
    if (squared_sum.empty()) {
      squared_sum.assign(surfaces.size(), 0.0);
      max.assign(surfaces.size(), 0.0);
      count.assign(surfaces.size(), 0);
      worst_frame_rms.assign(surfaces.size(), 0.0);
    }
    for (std::size_t m = 0; m < surfaces.size(); ++m) {
      const Eigen::VectorXd distance = (surfaces[m] - finest[m]).colwise().norm();
      squared_sum[m] += distance.squaredNorm();
      count[m] += distance.size();
      max[m] = std::max(max[m], distance.maxCoeff());
      worst_frame_rms[m] = std::max(worst_frame_rms[m], std::sqrt(distance.squaredNorm() / distance.size()));
    }
  }
  bool empty() const { return squared_sum.empty(); }
  double rmsMm() const {
    double sum = 0;
    long n = 0;
    for (std::size_t m = 0; m < squared_sum.size(); ++m) {
      sum += squared_sum[m];
      n += count[m];
    }
    return 1e3 * std::sqrt(sum / static_cast<double>(n));
  }
  double maxMm() const { return 1e3 * *std::max_element(max.begin(), max.end()); }
};

// |difference| of each muscle's mean belly fibre length to the finest model's, over the checked frames.
struct LengthError {
  double squared_sum = 0, max = 0;
  long count = 0;
  void add(const std::vector<double>& lengths, const std::vector<double>& finest) {
    for (std::size_t m = 0; m < lengths.size(); ++m) {
      const double d = std::abs(lengths[m] - finest[m]);
      squared_sum += d * d;
      max = std::max(max, d);
      ++count;
    }
  }
  std::optional<double> rmsMm() const {
    return count ? std::optional<double>(1e3 * std::sqrt(squared_sum / static_cast<double>(count))) : std::nullopt;
  }
  std::optional<double> maxMm() const { return count ? std::optional<double>(1e3 * max) : std::nullopt; }
};

// The converged answers of one model, and what the finest model's are compared with.
struct References {
  std::vector<Eigen::Matrix3Xd> stream;                // [gait frame]
  std::vector<Eigen::Matrix3Xd> cold;                  // [pose]
  std::vector<std::vector<Vertices>> stream_surfaces;  // [checked frame][muscle]
  std::vector<std::vector<Vertices>> cold_surfaces;    // [pose][muscle]
  std::vector<std::vector<double>> stream_fibre_lengths, cold_fibre_lengths;  // [checked / pose][muscle] (m)
  bench::MuscleLengths lengths;                        // every frame of the converged stream
  std::optional<double> stream_volume_error_max_pct, cold_volume_error_max_pct;  // absent without metrics
  std::vector<double> stream_residuals, cold_residuals, stream_ms, cold_ms;
  double stream_moves_mm = 0, cold_moves_mm = 0;
  long particles = 0, fibres = 0;
};

// What one configuration measured.
struct Point {
  std::string mode, solver, configuration;
  int iterations = 0, threads = 0;
  std::vector<double> frame_ms;
  std::vector<double> convergence_sq;  // per frame: squared RMS (m^2) to the same model's reference
  SurfaceError surface;
  LengthError fibre_length;
  std::optional<double> volume_error_max_pct;
  bench::MuscleLengths lengths;  // stream: every frame
  bool reference = false;
};

struct Context {
  const BundledScene& bundled;
  const CoreSettings& node;
  FibreSets fibre_sets;
  std::vector<BoneTransforms> gait;        // every gait frame
  std::vector<std::size_t> checked;        // stream frames compared with the finest model
  std::vector<std::size_t> poses;          // cold poses
  bench::Gait2392Lengths gait2392;
  int stream_reference_sweeps = 60, cold_reference_sweeps = 300;
  const References* finest = nullptr;
  bench::JsonRecords records;
};

bool isChecked(const Context& c, std::size_t frame, std::size_t& index) {
  const auto it = std::find(c.checked.begin(), c.checked.end(), frame);
  index = static_cast<std::size_t>(it - c.checked.begin());
  return it != c.checked.end();
}

void addVolume(std::optional<double>& worst, const std::optional<double>& value) {
  if (value) worst = std::max(worst.value_or(0.0), *value);
}

References referencesOf(Context& c, const ModelVariant& v) {
  References r;
  const std::vector<Muscle> muscles = musclesOf(c.bundled, c.fibre_sets, v);
  DeformationPipeline pipeline(c.bundled.scene.muscle_descriptions, muscles, c.bundled.scene.bones,
                               pipelineFor(c.node, v, SolverKind::block_descent, 0));
  r.particles = pipeline.system().particleCount();
  for (const Muscle& m : muscles) r.fibres += static_cast<long>(m.fibres.size());
  const FrameStopping stream_stopping = sweepsOf(c.node, c.stream_reference_sweeps);
  const FrameStopping cold_stopping = sweepsOf(c.node, c.cold_reference_sweeps);
  for (std::size_t f = 0; f < c.gait.size(); ++f) {
    std::size_t k = 0;
    const bool checked = isChecked(c, f, k);
    const FrameResult& frame = pipeline.solve(c.gait[f], f == 0 ? StartMode::cold : StartMode::warm,
                                              f == 0 ? cold_stopping : stream_stopping, checked, checked,
                                              1.0 / bench::kGaitRateHz);
    r.stream.push_back(pipeline.state().position);
    if (f > 0) {
      r.stream_residuals.push_back(frame.stats.solver.residual);
      r.stream_ms.push_back(frame.stats.solve_ms);
    }
    addVolume(r.stream_volume_error_max_pct, volumeErrorOf(frame));
    bench::addLengthsOf(pipeline, r.lengths);
    if (checked) {
      r.stream_surfaces.push_back(frame.surfaces);
      r.stream_fibre_lengths.push_back(latestBellyLengths(r.lengths));
    }
  }
  // The last frame given as many sweeps again (nothing is streamed after it).
  pipeline.refine(stream_stopping, false, false);
  r.stream_moves_mm = bench::rmsMillimetres(pipeline.state().position, r.stream.back());
  for (std::size_t k = 0; k < c.poses.size(); ++k) {
    const FrameResult& frame = pipeline.solve(c.gait[c.poses[k]], StartMode::cold, cold_stopping, true, true);
    r.cold.push_back(pipeline.state().position);
    r.cold_residuals.push_back(frame.stats.solver.residual);
    r.cold_ms.push_back(frame.stats.solve_ms);
    addVolume(r.cold_volume_error_max_pct, volumeErrorOf(frame));
    r.cold_surfaces.push_back(frame.surfaces);
    r.cold_fibre_lengths.push_back(fibreLengthsOf(pipeline));
    if (k == c.poses.size() / 2) {
      pipeline.refine(cold_stopping, false, false);
      r.cold_moves_mm = bench::rmsMillimetres(pipeline.state().position, r.cold.back());
    }
  }
  return r;
}

// The anatomy figures of a streamed gait: the excursion ratio farthest from 1 (as a ratio), the lowest r, and how many
// muscles reach r >= 0.9.
struct Anatomy {
  std::optional<double> ratio_worst, r_worst;
  int r_at_least_0_9 = 0, compared = 0, undefined = 0;
};

Anatomy anatomyOf(const Context& c, const bench::MuscleLengths& lengths) {
  Anatomy a;
  if (lengths.belly.empty() || lengths.belly.front().size() < c.gait2392.frames) return a;
  for (std::size_t m = 0; m < lengths.belly.size(); ++m) {
    const std::vector<double>& reference = c.gait2392.length[m];
    if (reference.empty()) continue;
    const std::vector<double> product(lengths.belly[m].begin(),
                                      lengths.belly[m].begin() + static_cast<long>(c.gait2392.frames));
    const double ratio = bench::range(product) / bench::range(reference);
    const double r = bench::correlation(product, reference);
    ++a.compared;
    if (!std::isfinite(ratio) || ratio <= 0 || !std::isfinite(r)) {
      ++a.undefined;  // a constant length series: no excursion ratio or r (counted, not hidden)
      continue;
    }
    if (r >= 0.9) ++a.r_at_least_0_9;
    if (!a.ratio_worst || std::abs(std::log(ratio)) > std::abs(std::log(*a.ratio_worst))) a.ratio_worst = ratio;
    if (!a.r_worst || r < *a.r_worst) a.r_worst = r;
  }
  return a;
}

void record(Context& c, const ModelVariant& v, const References& own, const Point& p) {
  bench::JsonRecords& out = c.records;
  out.begin();
  out.add("scene", "thigh13");
  out.add("mode", p.mode);
  out.add("solver", p.solver);
  out.add("configuration", p.configuration);
  out.add("model", v.label);
  out.add("spring_layout", layoutLabel(v.layout, v.neighbours));
  out.add("mixed_resolution", v.mixed() ? 1.0 : 0.0);
  out.add("reference", p.reference ? 1.0 : 0.0);
  out.addMeasured("iterations", p.iterations > 0 ? std::optional<double>(p.iterations) : std::nullopt);
  out.add("threads", p.threads);
  out.addMeasured("particles_per_fibre", v.mixed() ? std::nullopt : std::optional<double>(v.particles_per_fibre));
  out.addMeasured("fibres_per_muscle", v.mixed() ? std::nullopt : std::optional<double>(v.fibres_per_muscle));
  out.add("particles", static_cast<double>(own.particles));
  out.add("fibres", static_cast<double>(own.fibres));
  out.addMeasured("frame_ms_median", p.frame_ms.empty() ? std::nullopt : std::optional<double>(bench::median(p.frame_ms)));
  std::optional<double> convergence;
  if (!p.reference && !p.convergence_sq.empty()) {
    double sum = 0;
    for (double sq : p.convergence_sq) sum += sq;
    convergence = 1e3 * std::sqrt(sum / static_cast<double>(p.convergence_sq.size()));
  }
  out.addMeasured("convergence_rms_mm", convergence);
  out.addMeasured("resolution_rms_mm", p.surface.empty() ? std::nullopt : std::optional<double>(p.surface.rmsMm()));
  out.addMeasured("resolution_max_mm", p.surface.empty() ? std::nullopt : std::optional<double>(p.surface.maxMm()));
  out.addMeasured("fibre_length_rms_mm", p.fibre_length.rmsMm());
  out.addMeasured("fibre_length_max_mm", p.fibre_length.maxMm());
  out.addMeasured("model_volume_error_max_pct", p.volume_error_max_pct);
  const Anatomy anatomy = p.mode == "stream" ? anatomyOf(c, p.lengths) : Anatomy{};
  out.addMeasured("length_ratio_worst", anatomy.ratio_worst);
  out.addMeasured("length_r_worst", anatomy.r_worst);
  out.addMeasured("length_r_at_least_0_9",
                  anatomy.compared ? std::optional<double>(anatomy.r_at_least_0_9) : std::nullopt);
  out.addMeasured("length_undefined", anatomy.compared ? std::optional<double>(anatomy.undefined) : std::nullopt);
  if (p.reference) {
    const bool stream = p.mode == "stream";
    out.add("reference_sweeps", stream ? c.stream_reference_sweeps : c.cold_reference_sweeps);
    const std::vector<double>& residuals = stream ? own.stream_residuals : own.cold_residuals;
    out.addMeasured("reference_residual_median",
                    residuals.empty() ? std::nullopt : std::optional<double>(bench::median(residuals)));
    out.add("reference_moves_mm", stream ? own.stream_moves_mm : own.cold_moves_mm);
  }
  out.end();
  std::printf("[%6.1f s] %-6s %-28s %-44s frame %8.2f ms; convergence %s mm; surface to finest %s mm RMS, %s max; "
              "volume %s %%; length ratio %s, r %s\n",
              elapsedSeconds(), p.mode.c_str(), v.label.c_str(), p.configuration.c_str(), bench::median(p.frame_ms),
              convergence ? std::to_string(*convergence).substr(0, 6).c_str() : "-",
              p.surface.empty() ? "-" : std::to_string(p.surface.rmsMm()).substr(0, 5).c_str(),
              p.surface.empty() ? "-" : std::to_string(p.surface.maxMm()).substr(0, 5).c_str(),
              p.volume_error_max_pct ? std::to_string(*p.volume_error_max_pct).substr(0, 5).c_str() : "-",
              anatomy.ratio_worst ? std::to_string(*anatomy.ratio_worst).substr(0, 5).c_str() : "-",
              anatomy.r_worst ? std::to_string(*anatomy.r_worst).substr(0, 5).c_str() : "-");
  std::fflush(stdout);
}

// The references as points of their own: the converged models' resolution and anatomy errors.
void recordReferences(Context& c, const ModelVariant& v, const References& r) {
  Point stream;
  stream.mode = "stream";
  stream.solver = "block_descent";
  stream.configuration = "converged (" + std::to_string(c.stream_reference_sweeps) + " sweeps a frame)";
  stream.iterations = c.stream_reference_sweeps;
  stream.frame_ms = r.stream_ms;
  stream.reference = true;
  stream.lengths = r.lengths;
  stream.volume_error_max_pct = r.stream_volume_error_max_pct;
  Point cold = stream;
  cold.mode = "cold";
  cold.configuration = "converged (" + std::to_string(c.cold_reference_sweeps) + " sweeps)";
  cold.iterations = c.cold_reference_sweeps;
  cold.frame_ms = r.cold_ms;
  cold.lengths = {};
  cold.volume_error_max_pct = r.cold_volume_error_max_pct;
  // The finest model's references are what the others are compared with: no resolution error of their own.
  const bool is_finest = &r == c.finest;
  for (std::size_t k = 0; k < c.checked.size() && !is_finest; ++k) {
    stream.surface.add(r.stream_surfaces[k], c.finest->stream_surfaces[k]);
    stream.fibre_length.add(r.stream_fibre_lengths[k], c.finest->stream_fibre_lengths[k]);
  }
  for (std::size_t k = 0; k < c.poses.size() && !is_finest; ++k) {
    cold.surface.add(r.cold_surfaces[k], c.finest->cold_surfaces[k]);
    cold.fibre_length.add(r.cold_fibre_lengths[k], c.finest->cold_fibre_lengths[k]);
  }
  record(c, v, r, stream);
  record(c, v, r, cold);
  // Per muscle: the converged stream's surface error at its worst checked frame.
  for (std::size_t m = 0; m < c.bundled.scene.muscles.size() && !is_finest; ++m) {
    c.records.begin();
    c.records.add("scene", "thigh13");
    c.records.add("mode", "stream");
    c.records.add("solver", "per_muscle");
    c.records.add("model", v.label);
    c.records.add("mixed_resolution", v.mixed() ? 1.0 : 0.0);
    c.records.add("muscle", c.bundled.scene.muscles[m].name);
    c.records.addMeasured("particles_per_fibre", v.mixed() ? std::optional<double>(v.muscle_particles_per_fibre[m])
                                                           : std::optional<double>(v.particles_per_fibre));
    c.records.addMeasured("fibres_per_muscle", v.mixed() ? std::optional<double>(v.muscle_fibres[m])
                                                         : std::optional<double>(v.fibres_per_muscle));
    c.records.add("spring_layout", layoutLabel(v.layout, v.neighbours));
    c.records.add("surface_rms_mm_worst_frame", 1e3 * stream.surface.worst_frame_rms[m]);
    c.records.add("surface_max_mm", 1e3 * stream.surface.max[m]);
    c.records.end();
  }
  std::printf("[%6.1f s] %s: %ld particles, %ld fibres; references: stream residual median %.2e, last frame moves "
              "%.4f mm RMS with %d more sweeps; cold residual median %.2e, middle pose moves %.4f mm with %d more\n",
              elapsedSeconds(), v.label.c_str(), r.particles, r.fibres, bench::median(r.stream_residuals),
              r.stream_moves_mm, c.stream_reference_sweeps, bench::median(r.cold_residuals), r.cold_moves_mm,
              c.cold_reference_sweeps);
}

struct Config {
  std::string label;
  SolverKind kind = SolverKind::block_descent;
  int iterations = 1;  // per frame; 0 under the node's time budget (not a fixed count)
  int threads = 0;
  int lbfgs_history = 0;
  bool node_stopping = false;  // the node's own frame stopping (its time budget, catch-up and deep-contact sweeps)
};

Config blockDescent(int sweeps, int threads = 0) {
  Config config;
  config.label = "block_descent " + std::to_string(sweeps) + (sweeps == 1 ? " sweep" : " sweeps") +
                 (threads == 1 ? ", 1 thread" : "");
  config.iterations = sweeps;
  config.threads = threads;
  return config;
}

// A point of `mode` for a configuration, before anything is measured.
Point pointOf(const std::string& mode, const Config& config) {
  Point p;
  p.mode = mode;
  p.solver = toString(config.kind);
  p.configuration = config.label;
  p.iterations = config.iterations;
  p.threads = config.threads;
  return p;
}

// The local/global solver's quasi-Newton mode (L-BFGS, history 16), no drag.
Config localGlobal(int iterations) {
  Config config;
  config.label = "local_global lbfgs16 " + std::to_string(iterations) + " iterations";
  config.kind = SolverKind::local_global;
  config.iterations = iterations;
  config.lbfgs_history = 16;
  return config;
}

void measureStream(Context& c, const ModelVariant& v, const References& own, const Config& config) {
  const std::vector<Muscle> muscles = musclesOf(c.bundled, c.fibre_sets, v);
  StreamSessionSettings stream_settings = c.node.stream;
  if (!config.node_stopping) stream_settings.stopping = sweepsOf(c.node, config.iterations);
  StreamSession session(c.bundled.scene.muscle_descriptions, muscles, c.bundled.scene.bones,
                        pipelineFor(c.node, v, config.kind, config.threads, config.lbfgs_history), stream_settings);
  Point p = pointOf("stream", config);
  session.continueFrom(bench::streamStamp(0), c.gait[0], own.stream[0]);
  bench::addLengthsOf(session.pipeline(), p.lengths);
  for (std::size_t f = 1; f < c.gait.size(); ++f) {
    std::size_t k = 0;
    const bool checked = isChecked(c, f, k);
    const FrameResult* frame =
        bench::frameOf(session.offer(bench::streamStamp(f), c.gait[f], FrameWants{checked, checked}));
    if (frame) {
      p.frame_ms.push_back(frame->stats.solve_ms);
      addVolume(p.volume_error_max_pct, volumeErrorOf(*frame));
    }
    const double rms = 1e-3 * bench::rmsMillimetres(session.pipeline().state().position, own.stream[f]);
    p.convergence_sq.push_back(rms * rms);
    bench::addLengthsOf(session.pipeline(), p.lengths);
    if (checked && frame) {
      p.surface.add(frame->surfaces, c.finest->stream_surfaces[k]);
      p.fibre_length.add(latestBellyLengths(p.lengths), c.finest->stream_fibre_lengths[k]);
    }
  }
  record(c, v, own, p);
}

void measureCold(Context& c, const ModelVariant& v, const References& own, const Config& config) {
  const std::vector<Muscle> muscles = musclesOf(c.bundled, c.fibre_sets, v);
  DeformationPipeline pipeline(c.bundled.scene.muscle_descriptions, muscles, c.bundled.scene.bones,
                               pipelineFor(c.node, v, config.kind, config.threads, config.lbfgs_history));
  Point p = pointOf("cold", config);
  for (std::size_t k = 0; k < c.poses.size(); ++k) {
    const FrameResult& frame =
        pipeline.solve(c.gait[c.poses[k]], StartMode::cold, sweepsOf(c.node, config.iterations), true, true);
    p.frame_ms.push_back(frame.stats.solve_ms);
    addVolume(p.volume_error_max_pct, volumeErrorOf(frame));
    const double rms = 1e-3 * bench::rmsMillimetres(pipeline.state().position, own.cold[k]);
    p.convergence_sq.push_back(rms * rms);
    p.surface.add(frame.surfaces, c.finest->cold_surfaces[k]);
    p.fibre_length.add(fibreLengthsOf(pipeline), c.finest->cold_fibre_lengths[k]);
  }
  record(c, v, own, p);
}

// The peer (bullet_peer.hpp) on the same model's particles and springs, streamed over the gait from the converged
// frame 0: frame time and distance to the converged stream. Its surfaces, lengths and volume are not measured (they
// would need our skinning of its particles): null. With the bone meshes as colliders Bullet meets each mesh triangle
// by triangle and may take seconds a frame on this scene, so that variant plays until the gait ends or `budget_s` is
// spent, and names the frames it played.
void measurePeer(Context& c, const ModelVariant& v, const References& own, int position_iterations,
                 bool bone_colliders, double budget_s) {
#ifdef MD_HAVE_BULLET
  const std::vector<Muscle> muscles = musclesOf(c.bundled, c.fibre_sets, v);
  const DeformationPipeline model(c.bundled.scene.muscle_descriptions, muscles, c.bundled.scene.bones,
                                  bench::particlesOnly(pipelineFor(c.node, v, SolverKind::block_descent, 0)));
  // Bullet's own distance-field voxel (0.25 m): ours (a particle radius) did not end one frame in 80 s.
  // With colliders, Bullet frees its cache of triangle shapes pair by pair when a body leaves the world: measured, more
  // than 13 minutes after three frames. That peer is left to the end of the process instead.
  std::unique_ptr<bench::BulletPeer> owned = std::make_unique<bench::BulletPeer>(
      model.system(), c.bundled.scene.bones, position_iterations, bone_colliders, -1, 0);
  bench::BulletPeer& peer = *owned;
  if (bone_colliders) static_cast<void>(owned.release());
  peer.start(own.stream[0], c.gait[0]);
  Point p;
  p.mode = "stream";
  p.solver = "bullet_soft_body";
  // Played until the gait ends or the budget is spent (then the frames played are named).
  const auto played_start = std::chrono::steady_clock::now();
  std::size_t frames = 1;
  bool finite = true;
  for (; frames < c.gait.size() && finite; ++frames) {
    p.frame_ms.push_back(peer.step(c.gait[frames], 1.0 / bench::kGaitRateHz));
    const Eigen::Matrix3Xd x = peer.positions();
    finite = x.allFinite();
    const double rms = 1e-3 * bench::rmsMillimetres(x, own.stream[frames]);
    p.convergence_sq.push_back(rms * rms);
    if (std::chrono::duration<double>(std::chrono::steady_clock::now() - played_start).count() > budget_s) {
      ++frames;
      break;
    }
  }
  p.configuration = "bullet soft body, " + std::to_string(position_iterations) + " position iteration" +
                    (position_iterations == 1 ? " (its default)" : "s") +
                    (bone_colliders ? ", bone meshes as colliders" : ", no bone colliders") +
                    (frames < c.gait.size() ? ", first " + std::to_string(frames - 1) + " frames" : "");
  p.iterations = position_iterations;
  p.threads = 1;
  if (!finite) {
    p.convergence_sq.clear();  // a stream that left finite numbers has no distance: absent
    p.configuration += " (diverged)";
  }
  record(c, v, own, p);
  c.records.begin();
  c.records.add("scene", "thigh13");
  c.records.add("mode", "stream");
  c.records.add("solver", "peer_setup");
  c.records.add("configuration", p.configuration);
  c.records.add("frames", static_cast<double>(frames - 1));
  c.records.add("bone_colliders", bone_colliders ? 1.0 : 0.0);
  c.records.add("median_radius_mm", 1e3 * peer.medianRadius());
  c.records.end();
#else
  (void)c, (void)v, (void)own, (void)bone_colliders, (void)budget_s;
  std::printf("[%6.1f s] the peer (Bullet soft bodies, %d position iterations) not measured: built without "
              "libbullet-dev\n", elapsedSeconds(), position_iterations);
#endif
}

// Fibre sets of `count` fibres per muscle for the scene's muscles, made as the bundled ones were.
std::vector<std::vector<Polyline>> generatedFibres(const BundledScene& bundled, int count) {
  std::vector<std::vector<Polyline>> sets;
  for (const Muscle& muscle : bundled.scene.muscles) {
    const TriangleMesh* origin = nullptr;
    const TriangleMesh* insertion = nullptr;
    for (const Bone& bone : bundled.scene.bones) {
      if (bone.name == muscle.origin_bone) origin = &bone.surface;
      if (bone.name == muscle.insertion_bone) insertion = &bone.surface;
    }
    FibreGeneratorOptions options;
    options.fibre_count = count;
    options.seed_section = SeedSection::mid_value;
    FibreGenerationResult result = generateFibres(muscle.surface, origin, insertion, options);
    std::printf("[%6.1f s]   %s: %zu of %d fibres%s\n", elapsedSeconds(), muscle.name.c_str(), result.fibres.size(),
                count, result.checks.passed() ? "" : (" (checks: " + result.checks.failures.front() + ")").c_str());
    sets.push_back(std::move(result.fibres));
  }
  return sets;
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  elapsedSeconds();
  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR, {"thigh13"});
  const CoreSettings node = bench::loadNodeDefaults();
  Context c{bundled, node, {}, {}, {}, {}, bench::gait2392LengthsFor(bundled), 60, 300, nullptr, {}};
  const std::size_t frames = options.quick ? 12 : bundled.gait.frames.size();
  for (std::size_t f = 0; f < frames; ++f) c.gait.push_back(boneTransformsOf(bundled.scene.bones, gaitPose(bundled, f)));
  c.poses = options.quick ? std::vector<std::size_t>{6, 11} : fiveGaitFrames(bundled);
  c.checked = {c.poses.begin() + 1, c.poses.end()};  // frame 0 is every stream's common start
  if (options.quick) {
    c.stream_reference_sweeps = 10;
    c.cold_reference_sweeps = 20;
  }

  // The models, the finest first (every other is compared with it).
  const ModelVariant finest = options.quick ? uniform(20, 64) : uniform(80, 128);
  const ModelVariant base = uniform(20, 64);
  std::vector<ModelVariant> models = {finest};
  if (!options.quick) {
    for (const int ppf : {10, 15, 20, 40, 80}) models.push_back(uniform(ppf, 64));
    for (const int fibres : {32, 128}) models.push_back(uniform(20, fibres));
    models.push_back(uniform(20, 64, SpringLayout::nearest_neighbours, 10));
    models.push_back(uniform(20, 64, SpringLayout::cubic26));
  } else {
    models.push_back(uniform(10, 64));
  }
  c.fibre_sets[64] = {};
  for (const Muscle& m : bundled.scene.muscles) c.fibre_sets[64].push_back(m.fibres);
  for (const ModelVariant& v : models)
    if (!c.fibre_sets.count(v.fibres_per_muscle)) {
      std::printf("[%6.1f s] generating %d fibres per muscle\n", elapsedSeconds(), v.fibres_per_muscle);
      c.fibre_sets[v.fibres_per_muscle] = generatedFibres(bundled, v.fibres_per_muscle);
    }

  const auto configurationsOf = [&](const ModelVariant& v) {
    std::vector<Config> stream, cold;
    const bool is_base = v.label == base.label && !v.mixed();
    for (const int sweeps : is_base ? std::vector<int>{1, 2, 4, 8} : std::vector<int>{1, 4})
      stream.push_back(blockDescent(sweeps));
    for (const int sweeps : is_base ? std::vector<int>{10, 20, 40, 80} : std::vector<int>{10, 20, 40})
      cold.push_back(blockDescent(sweeps));
    if (is_base) {
      stream.push_back(blockDescent(1, 1));
      Config node_default;
      node_default.label = "node default (budget " +
                           std::to_string(static_cast<int>(node.stream.stopping.sweeps.time_budget_ms)) + " ms)";
      node_default.kind = node.pipeline.simulation.solver_kind;
      node_default.node_stopping = true;
      node_default.iterations = 0;
      node_default.threads = node.pipeline.threads;
      stream.push_back(node_default);
      for (const int iterations : {30, 100}) {
        Config verlet;
        verlet.label = "verlet " + std::to_string(iterations) + " iterations";
        verlet.kind = SolverKind::verlet;
        verlet.iterations = iterations;
        stream.push_back(verlet);
      }
      for (const int iterations : {10, 30}) stream.push_back(localGlobal(iterations));
      cold.push_back(localGlobal(120));
    }
    return std::make_pair(stream, cold);
  };

  References finest_references;
  std::map<std::string, std::vector<double>> per_muscle_worst;  // model label -> per muscle worst-frame RMS (m)
  const auto run = [&](const ModelVariant& v) {
    std::printf("[%6.1f s] model %s: references\n", elapsedSeconds(), v.label.c_str());
    std::fflush(stdout);
    References own = referencesOf(c, v);
    const References* own_references = &own;
    if (!c.finest) {
      finest_references = std::move(own);
      c.finest = own_references = &finest_references;
    }
    const References& r = *own_references;
    recordReferences(c, v, r);
    SurfaceError errors;
    for (std::size_t k = 0; k < c.checked.size(); ++k) errors.add(r.stream_surfaces[k], c.finest->stream_surfaces[k]);
    per_muscle_worst[v.label] = errors.worst_frame_rms;
    const auto [stream, cold] = configurationsOf(v);
    for (const Config& config : stream) measureStream(c, v, r, config);
    for (const Config& config : cold) measureCold(c, v, r, config);
    if (v.label == base.label && !v.mixed()) {
      for (const int iterations : options.quick ? std::vector<int>{1, 4} : std::vector<int>{1, 4, 16, 64})
        measurePeer(c, v, r, iterations, false, 1e9);
      measurePeer(c, v, r, 1, true, options.quick ? 20.0 : 60.0);
    }
  };
  // The machine's memory bandwidth and floating-point rate on every core, measured before the models so that the
  // section names the machine its times were taken on without depending on another bench's run.
  const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const bench::MachineFloor machine = bench::measureMachineFloor(cores);
  std::printf("[%6.1f s] machine: %.1f GB/s, %.1f Gflop/s on %d threads\n", elapsedSeconds(), machine.bandwidth_gbs,
              machine.gflops, machine.threads);
  c.records.begin();
  c.records.add("scene", "thigh13");
  c.records.add("solver", "machine");
  c.records.add("bandwidth_gbs", machine.bandwidth_gbs);
  c.records.add("gflops", machine.gflops);
  c.records.add("floor_threads", static_cast<double>(machine.threads));
  c.records.end();

  for (const ModelVariant& v : models) run(v);

  // Resolution per muscle: the coarsest measured nearest18 model whose surface error for that muscle stays within the
  // worst muscle's error of uniform 20 x 64 at every checked frame, less a margin. Without it the muscle that sets the
  // target keeps 20 x 64 at exactly the target, and its neighbours' coarser models move it past (2026-11-28: the rectus
  // femoris 8.516 against 8.509 mm): the margin, 1 % of the target, is over ten times that interaction.
  if (!options.quick) {
    constexpr double kTargetMargin = 0.01;
    const std::vector<double>& uniform20 = per_muscle_worst.at(base.label);
    const double worst = *std::max_element(uniform20.begin(), uniform20.end());
    const double target = (1.0 - kTargetMargin) * worst;
    ModelVariant mixed;
    mixed.label = "per muscle within " + std::to_string(1e3 * target).substr(0, 4) + " mm";
    std::printf("[%6.1f s] resolution per muscle, target %.3f mm RMS (the worst muscle of %s, %.3f, less %.0f %%):\n",
                elapsedSeconds(), 1e3 * target, base.label.c_str(), 1e3 * worst, 100 * kTargetMargin);
    for (std::size_t m = 0; m < bundled.scene.muscles.size(); ++m) {
      // The coarsest within the target, finer than 20 x 64 where that is not (the finest model is the reference);
      // 20 x 64 where none is.
      const ModelVariant* chosen = nullptr;
      long fewest = 0;
      double chosen_error = 0;
      for (const ModelVariant& v : models) {
        if (v.label == finest.label || v.layout != SpringLayout::nearest_neighbours || v.neighbours != 18) continue;
        const long size = static_cast<long>(v.particles_per_fibre) * v.fibres_per_muscle;
        const double error = per_muscle_worst.at(v.label)[m];
        if (error <= target &&
            (!chosen || size < fewest || (size == fewest && error < chosen_error))) {
          chosen = &v;
          fewest = size;
          chosen_error = error;
        }
      }
      if (!chosen) chosen = &base;
      mixed.muscle_particles_per_fibre.push_back(chosen->particles_per_fibre);
      mixed.muscle_fibres.push_back(chosen->fibres_per_muscle);
      std::printf("  %-28s %d x %d (its error there %.3f mm)\n", bundled.scene.muscles[m].name.c_str(),
                  chosen->particles_per_fibre, chosen->fibres_per_muscle, 1e3 * per_muscle_worst.at(chosen->label)[m]);
    }
    run(mixed);
  }
  std::printf("[%6.1f s] done\n", elapsedSeconds());
  return bench::finish(c.records, options, "speed_vs_error.json");
}
