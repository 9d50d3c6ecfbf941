// Exports one converged gait frame of the bundled scene for tools/analysis/hessian_spectrum.py: particles (fixed flag,
// muscle, fibre, sample, position, radius), springs (ends, stiffness, rest length) and the contacts touching at the
// state, in a flat little-endian binary file. Not part of make bench: a measurement behind docs/realtime.md.
//
//   hessian_export SELECTION SWEEPS FRAME OUT.bin [TISSUE_RELAXATION_S]
//   (SELECTION: a muscle name or tag, or "all"; e.g. hessian_export thigh13 2000 30 /tmp/thigh13.bin 0)
#include "node_defaults.hpp"
#include "stream_play.hpp"

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>

using namespace muscle_deformation;

namespace {
template <class T>
void put(std::ofstream& out, const T& value) {
  out.write(reinterpret_cast<const char*>(&value), sizeof(T));
}
}  // namespace

int main(int argc, char** argv) {
  if (argc < 5) {
    std::fprintf(stderr, "usage: %s SELECTION SWEEPS FRAME OUT.bin [TISSUE_RELAXATION_S]\n", argv[0]);
    return 2;
  }
  const std::string selection = argv[1];
  const int sweeps = std::atoi(argv[2]);
  const int frame = std::atoi(argv[3]);
  const BundledScene bundled =
      loadBundledScene(MD_PACKAGE_DIR, selection == "all" ? std::vector<std::string>{} : std::vector<std::string>{selection});
  const CoreSettings node = bench::loadNodeDefaults();
  PipelineSettings settings = bench::particlesOnly(node.pipeline);
  settings.simulation.solver_kind = SolverKind::block_descent;
  settings.simulation.block_descent.tissue_relaxation_s = argc > 5 ? std::atof(argv[5]) : 0.0;
  FrameStopping stopping = node.stream.stopping;
  stopping.sweeps.rule = StoppingRule::iterations;
  stopping.sweeps.max_iterations = sweeps;
  stopping.sweeps.limits = {};
  DeformationPipeline simulation(bundled.scene.muscle_descriptions, bundled.scene.muscles, bundled.scene.bones,
                                 settings);
  const FrameStats stats =
      simulation
          .solve(boneTransformsOf(simulation.bones(), gaitPose(bundled, static_cast<std::size_t>(frame))),
                 StartMode::cold, stopping, false, false)
          .stats;
  const MassSpringSystem& system = simulation.system();
  const Eigen::Matrix3Xd& x = simulation.state().position;
  ContactSet contacts;
  // Touching contacts only (margin 0); the query refreshes the world's broad-phase caches.
  const_cast<CollisionWorld*>(simulation.collisionWorld())->findContacts(simulation.state(), contacts, 0.0);
  std::ofstream out(argv[4], std::ios::binary);
  put<std::int64_t>(out, system.particleCount());
  put<std::int64_t>(out, static_cast<std::int64_t>(system.springs.size()));
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    put<std::uint8_t>(out, system.is_fixed[static_cast<std::size_t>(i)]);
    put<std::int32_t>(out, system.muscle_of[static_cast<std::size_t>(i)]);
    put<std::int32_t>(out, system.fibre_of[static_cast<std::size_t>(i)]);
    put<std::int32_t>(out, system.sample_of[static_cast<std::size_t>(i)]);
    for (int k = 0; k < 3; ++k) put<double>(out, x(k, i));
    for (int k = 0; k < 3; ++k) put<double>(out, system.rest_position(k, i));
    put<double>(out, system.radius[i]);
  }
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    put<std::int32_t>(out, system.springs.first[s]);
    put<std::int32_t>(out, system.springs.second[s]);
    put<double>(out, system.springs.stiffness[static_cast<Eigen::Index>(s)]);
    put<double>(out, system.springs.rest_length[static_cast<Eigen::Index>(s)]);
  }
  put<std::int64_t>(out, static_cast<std::int64_t>(contacts.half_spaces.size()));
  for (const auto& h : contacts.half_spaces) {
    put<std::int32_t>(out, h.particle);
    for (int k = 0; k < 3; ++k) put<double>(out, h.normal[k]);
  }
  put<std::int64_t>(out, static_cast<std::int64_t>(contacts.pairs.size()));
  for (const auto& p : contacts.pairs) {
    put<std::int32_t>(out, p.first);
    put<std::int32_t>(out, p.second);
    put<double>(out, p.distance);
  }
  if (!out) {
    std::fprintf(stderr, "cannot write %s\n", argv[4]);
    return 1;
  }
  std::printf("%ld particles, %zu springs, %d sweeps, force residual %.2e, %zu touching contacts -> %s\n",
              static_cast<long>(system.particleCount()), system.springs.size(), stats.solver.iterations,
              stats.solver.residual, contacts.size(), argv[4]);
  return 0;
}
