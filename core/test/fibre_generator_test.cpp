// Specifications of the fibre generator: analytic behaviour on a capsule, the committed fibre files, bad inputs.
#include "muscle_deformation/preprocessing/fibre_generator.hpp"

#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace md = muscle_deformation;
namespace fs = std::filesystem;

namespace {

constexpr double kRadius = 0.01;    // m
constexpr double kCylinder = 0.06;  // m, length of the straight part, from z = 0 to z = kCylinder

// A closed surface of revolution about z, wound outwards: rings at heights ring_z (increasing) with radii ring_r,
// between a pole at z_bottom (below the first ring) and one at z_top (above the last).
md::TriangleMesh surfaceOfRevolution(const std::vector<double>& ring_z, const std::vector<double>& ring_r,
                                     double z_bottom, double z_top, int segments) {
  std::vector<Eigen::Vector3d> points;
  points.emplace_back(0, 0, z_bottom);
  for (std::size_t r = 0; r < ring_z.size(); ++r)
    for (int s = 0; s < segments; ++s) {
      const double phi = 2 * M_PI * s / segments;
      points.emplace_back(ring_r[r] * std::cos(phi), ring_r[r] * std::sin(phi), ring_z[r]);
    }
  points.emplace_back(0, 0, z_top);
  const int rings = static_cast<int>(ring_z.size());
  const int top = static_cast<int>(points.size()) - 1;
  auto at = [&](int ring, int s) { return 1 + ring * segments + (s % segments); };
  std::vector<Eigen::Vector3i> faces;
  for (int s = 0; s < segments; ++s) faces.emplace_back(0, at(0, s + 1), at(0, s));
  for (int r = 0; r + 1 < rings; ++r)
    for (int s = 0; s < segments; ++s) {
      faces.emplace_back(at(r, s), at(r, s + 1), at(r + 1, s + 1));
      faces.emplace_back(at(r, s), at(r + 1, s + 1), at(r + 1, s));
    }
  for (int s = 0; s < segments; ++s) faces.emplace_back(top, at(rings - 1, s), at(rings - 1, s + 1));
  md::TriangleMesh mesh;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(points.size()));
  for (std::size_t i = 0; i < points.size(); ++i) mesh.vertices.col(static_cast<Eigen::Index>(i)) = points[i];
  mesh.triangles.resize(3, static_cast<Eigen::Index>(faces.size()));
  for (std::size_t i = 0; i < faces.size(); ++i) mesh.triangles.col(static_cast<Eigen::Index>(i)) = faces[i];
  return mesh;
}

// Capsule along z: a cylinder of radius kRadius from z = 0 to kCylinder with hemispherical caps.
md::TriangleMesh capsule(int segments = 48, int cap_rings = 12, int body_rings = 24) {
  std::vector<double> ring_z, ring_r;
  for (int i = 1; i <= cap_rings; ++i) {  // bottom cap, up to the equator z = 0
    const double a = -M_PI / 2 + M_PI / 2 * i / cap_rings;
    ring_z.push_back(kRadius * std::sin(a));
    ring_r.push_back(kRadius * std::cos(a));
  }
  for (int i = 1; i <= body_rings; ++i) {
    ring_z.push_back(kCylinder * i / body_rings);
    ring_r.push_back(kRadius);
  }
  for (int i = 1; i < cap_rings; ++i) {  // top cap, above z = kCylinder
    const double a = M_PI / 2 * i / cap_rings;
    ring_z.push_back(kCylinder + kRadius * std::sin(a));
    ring_r.push_back(kRadius * std::cos(a));
  }
  return surfaceOfRevolution(ring_z, ring_r, -kRadius, kCylinder + kRadius, segments);
}

// Shaped like a psoas: a spindle-shaped belly 18 mm in radius over the upper 22 cm, running into a tendon 2.5 mm in
// radius over the lower 8 cm (0.2 cm^2 across, as the psoas that got 13 of 64 fibres).
constexpr double kTendonRadius = 0.0025, kBellyRadius = 0.018, kBellyStart = 0.08, kMuscleTop = 0.30;
md::TriangleMesh psoasLike() {
  std::vector<double> ring_z, ring_r;
  for (int i = 1; i <= 120; ++i) {
    const double z = kMuscleTop * i / 121.0;
    const double belly = z > kBellyStart ? kBellyRadius * std::sin(M_PI * (z - kBellyStart) / (kMuscleTop - kBellyStart)) : 0;
    ring_z.push_back(z);
    ring_r.push_back(std::max(kTendonRadius, belly));
  }
  return surfaceOfRevolution(ring_z, ring_r, 0.0, kMuscleTop, 32);
}

// The two hemispherical caps as patches: origin at the bottom (z <= 0), insertion at the top (z >= kCylinder).
md::AttachmentPatches capPatches(const md::TriangleMesh& mesh) {
  md::AttachmentPatches patches;
  for (Eigen::Index v = 0; v < mesh.vertexCount(); ++v) {
    if (mesh.vertices(2, v) <= 1e-12) patches.origin_vertices.push_back(static_cast<int>(v));
    if (mesh.vertices(2, v) >= kCylinder - 1e-12) patches.insertion_vertices.push_back(static_cast<int>(v));
  }
  return patches;
}

md::FibreGeneratorOptions smallOptions() {
  md::FibreGeneratorOptions options;
  options.fibre_count = 24;
  options.voxel_size = 0.001;
  options.min_inside_voxels = 0;
  return options;
}

md::TriangleMesh box(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  md::TriangleMesh mesh;
  mesh.vertices.resize(3, 8);
  for (int i = 0; i < 8; ++i)
    mesh.vertices.col(i) = Eigen::Vector3d(i & 1 ? hi.x() : lo.x(), i & 2 ? hi.y() : lo.y(), i & 4 ? hi.z() : lo.z());
  // Vertex i has bit 0 = x, bit 1 = y, bit 2 = z at the upper bound; faces wound outwards.
  const int faces[12][3] = {{0, 2, 3}, {0, 3, 1}, {4, 5, 7}, {4, 7, 6}, {0, 1, 5}, {0, 5, 4},
                            {2, 6, 7}, {2, 7, 3}, {0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5}};
  mesh.triangles.resize(3, 12);
  for (int t = 0; t < 12; ++t) mesh.triangles.col(t) = Eigen::Vector3i(faces[t][0], faces[t][1], faces[t][2]);
  return mesh;
}



}  // namespace

TEST(FibreGenerator, CapsuleMeshIsAClosedOutwardSurface) {
  const md::TriangleMesh mesh = capsule();
  EXPECT_TRUE(md::checkSurfaceTopology(mesh).closedManifold()) << md::checkSurfaceTopology(mesh).describe();
  const double exact = M_PI * kRadius * kRadius * kCylinder + 4.0 / 3.0 * M_PI * std::pow(kRadius, 3);
  EXPECT_NEAR(md::enclosedVolume(mesh), exact, 0.02 * exact);
  EXPECT_NEAR(md::windingNumber(mesh, Eigen::Vector3d(0.002, 0, 0.03)), 1.0, 1e-9);
  EXPECT_NEAR(md::windingNumber(mesh, Eigen::Vector3d(0.02, 0, 0.03)), 0.0, 1e-9);
}

// Tolerances: in the cylindrical part away from the caps (more than one radius from either) the field is uniform up
// to a decaying end effect and its discretisation, so each fibre must stay within 0.1 mm (a tenth of a voxel) of the
// axis-parallel line through its middle and run within 1 degree of the axis.
TEST(FibreGenerator, CapsuleFibresAreStraightAndParallelToTheAxisFromCapToCap) {
  const md::TriangleMesh mesh = capsule();
  const md::FibreGeneratorOptions options = smallOptions();
  const md::FibreGenerationResult result = md::generateFibres(mesh, capPatches(mesh), options);
  ASSERT_EQ(result.fibres.size(), 24u);
  EXPECT_TRUE(result.checks.passed()) << result.checks.describe();
  const double h = result.voxel_size;
  for (const md::Polyline& fibre : result.fibres) {
    // From the origin cap to the insertion cap, rising all the way. (The patches' triangles reach one body ring,
    // kCylinder / 24, past the caps, and streamlines stop within two voxels of a patch.)
    EXPECT_LT(fibre(2, 0), kCylinder / 24 + 2 * h);
    EXPECT_GT(fibre(2, fibre.cols() - 1), kCylinder - kCylinder / 24 - 2 * h);
    for (Eigen::Index i = 0; i + 1 < fibre.cols(); ++i) EXPECT_GT(fibre(2, i + 1), fibre(2, i));
    // Inside the capsule.
    for (Eigen::Index i = 0; i < fibre.cols(); ++i) {
      const double z = std::clamp(fibre(2, i), 0.0, kCylinder);
      EXPECT_LT((fibre.col(i) - Eigen::Vector3d(0, 0, z)).norm(), kRadius + h);
    }
    // Straight and axial in the middle part.
    Eigen::Vector2d middle = Eigen::Vector2d::Zero();
    double best = 1e9;
    for (Eigen::Index i = 0; i < fibre.cols(); ++i) {
      if (std::abs(fibre(2, i) - kCylinder / 2) < best) {
        best = std::abs(fibre(2, i) - kCylinder / 2);
        middle = fibre.col(i).head<2>();
      }
    }
    for (Eigen::Index i = 0; i + 1 < fibre.cols(); ++i) {
      if (fibre(2, i) < kRadius || fibre(2, i + 1) > kCylinder - kRadius) continue;
      EXPECT_LT((fibre.col(i).head<2>() - middle).norm(), 1e-4) << "lateral drift at z = " << fibre(2, i);
      const Eigen::Vector3d d = (fibre.col(i + 1) - fibre.col(i)).normalized();
      EXPECT_LT(std::acos(std::min(1.0, d.z())), M_PI / 180) << "tilted at z = " << fibre(2, i);
    }
  }
  // Spread over the whole cross-section: some fibre near the axis and some near the rim.
  double inner = 1, outer = 0;
  for (const md::Polyline& fibre : result.fibres) {
    const double r = fibre.col(fibre.cols() / 2).head<2>().norm();
    inner = std::min(inner, r);
    outer = std::max(outer, r);
  }
  EXPECT_LT(inner, 0.3 * kRadius);
  EXPECT_GT(outer, 0.6 * kRadius);
  EXPECT_GT(result.checks.coverage, 0.95);
  EXPECT_NEAR(result.checks.cross_section_area, M_PI * kRadius * kRadius, 0.1 * M_PI * kRadius * kRadius);
}

TEST(FibreGenerator, BonesNearTheEndsGiveThePatchesAndWithoutBonesTheUpperEndIsTheOrigin) {
  const md::TriangleMesh mesh = capsule();
  md::FibreGeneratorOptions options = smallOptions();
  // A plate touching the top cap (origin) and one touching the bottom cap (insertion).
  const md::TriangleMesh top = box({-0.02, -0.02, kCylinder + kRadius}, {0.02, 0.02, kCylinder + kRadius + 0.01});
  const md::TriangleMesh bottom = box({-0.02, -0.02, -kRadius - 0.01}, {0.02, 0.02, -kRadius});
  const md::AttachmentPatches patches = md::findAttachmentPatches(mesh, &top, &bottom, options);
  EXPECT_TRUE(patches.origin_from_bone);
  EXPECT_TRUE(patches.insertion_from_bone);
  for (int v : patches.origin_vertices) EXPECT_GT(mesh.vertices(2, v), kCylinder) << v;
  for (int v : patches.insertion_vertices) EXPECT_LT(mesh.vertices(2, v), 0.0) << v;

  const md::AttachmentPatches fallback = md::findAttachmentPatches(mesh, nullptr, nullptr, options);
  EXPECT_FALSE(fallback.origin_from_bone);
  for (int v : fallback.origin_vertices) EXPECT_GT(mesh.vertices(2, v), kCylinder) << v;
  for (int v : fallback.insertion_vertices) EXPECT_LT(mesh.vertices(2, v), 0.0) << v;

  // A bone far away is ignored in favour of the principal-axis end.
  const md::TriangleMesh far = box({0.5, 0.5, 0.5}, {0.6, 0.6, 0.6});
  const md::AttachmentPatches with_far = md::findAttachmentPatches(mesh, &top, &far, options);
  EXPECT_TRUE(with_far.origin_from_bone);
  EXPECT_FALSE(with_far.insertion_from_bone);
  for (int v : with_far.insertion_vertices) EXPECT_LT(mesh.vertices(2, v), 0.0) << v;

  options.fibre_count = 8;
  const md::FibreGenerationResult result = md::generateFibres(mesh, &top, &bottom, options);
  EXPECT_TRUE(result.checks.passed()) << result.checks.describe();
  for (const md::Polyline& fibre : result.fibres) EXPECT_GT(fibre(2, 0), fibre(2, fibre.cols() - 1));  // top -> bottom
}

TEST(FibreGenerator, SavedFibresReadBackWithinTheWrittenPrecision) {
  const md::TriangleMesh mesh = capsule();
  md::FibreGeneratorOptions options = smallOptions();
  options.fibre_count = 6;
  const md::FibreGenerationResult result = md::generateFibres(mesh, capPatches(mesh), options);
  const std::string path = (fs::temp_directory_path() / "md_fibre_generator_test.vtk").string();
  md::saveFibresVtk(path, result.fibres);
  const std::vector<md::Polyline> loaded = md::loadPolylines(path);
  ASSERT_EQ(loaded.size(), result.fibres.size());
  for (std::size_t i = 0; i < loaded.size(); ++i) {
    ASSERT_EQ(loaded[i].cols(), options.points_per_fibre);
    EXPECT_LE((loaded[i] - result.fibres[i]).cwiseAbs().maxCoeff(), 0.5e-5 + 1e-12);
  }
  fs::remove(path);
}

TEST(FibreGenerator, BadInputsGiveClearErrors) {
  const md::TriangleMesh mesh = capsule();
  md::FibreGeneratorOptions options = smallOptions();

  md::TriangleMesh open = mesh;
  open.triangles.conservativeResize(3, open.triangles.cols() - 1);
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::FibreGenerationError>([&] { md::generateFibres(open, nullptr, nullptr, options); }), "closed");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::FibreGenerationError>([&] { md::generateFibres(md::TriangleMesh{}, nullptr, nullptr, options); }), "empty");

  options.fibre_count = 0;
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::FibreGenerationError>([&] { md::generateFibres(mesh, nullptr, nullptr, options); }), "at least 1");
  options = smallOptions();
  options.voxel_size = -1;
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::FibreGenerationError>([&] { md::generateFibres(mesh, nullptr, nullptr, options); }), "voxel size");
  options = smallOptions();
  options.voxel_size = 1e-5;  // a 2000 x 2000 x 9000 grid
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::FibreGenerationError>([&] { md::generateFibres(mesh, nullptr, nullptr, options); }), "larger voxel");

  options = smallOptions();
  md::AttachmentPatches patches = capPatches(mesh);
  patches.insertion_vertices.push_back(patches.origin_vertices.front());
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::FibreGenerationError>([&] { md::generateFibres(mesh, patches, options); }), "overlap");
  patches = capPatches(mesh);
  patches.origin_vertices.clear();
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::FibreGenerationError>([&] { md::generateFibres(mesh, patches, options); }), "at least one surface vertex");
  patches = capPatches(mesh);
  patches.origin_vertices.push_back(100000);
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::FibreGenerationError>([&] { md::generateFibres(mesh, patches, options); }), "out of range");
}

TEST(FibreGenerator, ChecksCatchFibresOutsideOffThePatchesAndTouching) {
  const md::TriangleMesh mesh = capsule();
  const md::FibreGeneratorOptions options = smallOptions();
  md::Polyline outside(3, 2), short_one(3, 2), twin(3, 2);
  outside << 0.05, 0.05, 0, 0, 0, kCylinder;  // leaves the capsule
  short_one << 0, 0, 0, 0, 0.02, 0.04;        // inside but touches neither cap
  twin = short_one;
  const md::FibreCheckReport report = md::checkFibres(mesh, capPatches(mesh), {outside, short_one, twin}, options);
  EXPECT_FALSE(report.passed());
  EXPECT_GT(report.points_outside, 0);
  EXPECT_GE(report.bad_starts, 2);
  EXPECT_DOUBLE_EQ(report.min_pairwise_distance, 0.0);
  EXPECT_LT(report.coverage, 0.9);
}

// The seeds are spread over the largest cross-section, in the belly: a muscle that narrows into a long thin tendon gets
// its full fibre count there, where the field's mid-value, which falls in the tendon, left most of the fibres out.
TEST(FibreGenerator, AMuscleWithAThinTendonGetsItsFullFibreCountSeededInTheBelly) {
  const md::TriangleMesh muscle = psoasLike();
  ASSERT_TRUE(md::checkSurfaceTopology(muscle).closedManifold());
  md::FibreGeneratorOptions options;
  options.min_inside_voxels = 30000;

  const md::FibreGenerationResult belly = md::generateFibres(muscle, nullptr, nullptr, options);
  EXPECT_EQ(belly.fibres.size(), 64u);
  EXPECT_TRUE(belly.checks.passed()) << belly.checks.describe();
  EXPECT_GT(belly.checks.cross_section_area, 0.5 * M_PI * kBellyRadius * kBellyRadius) << belly.checks.describe();
  for (const md::Polyline& fibre : belly.fibres)  // every fibre runs from the belly's end down the tendon
    EXPECT_LT(fibre(2, fibre.cols() - 1), 0.05);

  options.seed_section = md::SeedSection::mid_value;
  const md::FibreGenerationResult mid = md::generateFibres(muscle, nullptr, nullptr, options);
  EXPECT_LT(mid.checks.cross_section_area, 2 * M_PI * kTendonRadius * kTendonRadius) << mid.checks.describe();
  EXPECT_LT(mid.fibres.size(), 64u) << mid.checks.describe();
  EXPECT_FALSE(mid.checks.passed());
}

// A muscle whose bone is absent or too far still gets its fibres, along its principal axis, and a warning saying so.
TEST(FibreGenerator, AnAbsentOrFarBoneGivesFibresAlongThePrincipalAxisWithAWarning) {
  const md::TriangleMesh mesh = capsule();
  md::FibreGeneratorOptions options = smallOptions();
  options.fibre_count = 8;
  const md::TriangleMesh top = box({-0.02, -0.02, kCylinder + kRadius}, {0.02, 0.02, kCylinder + kRadius + 0.01});
  const md::TriangleMesh far = box({0.5, 0.5, 0.5}, {0.6, 0.6, 0.6});
  const md::FibreGenerationResult result = md::generateFibres(mesh, &top, &far, options);
  EXPECT_TRUE(result.checks.passed()) << result.checks.describe();
  EXPECT_EQ(result.fibres.size(), 8u);
  ASSERT_EQ(result.warnings.size(), 1u);
  EXPECT_CONTAINS(result.warnings[0], "no usable insertion bone region");
  EXPECT_CONTAINS(result.warnings[0], "too far");

  const md::FibreGenerationResult without = md::generateFibres(mesh, &top, nullptr, options);
  EXPECT_TRUE(without.checks.passed()) << without.checks.describe();
  ASSERT_EQ(without.warnings.size(), 1u);
  EXPECT_CONTAINS(without.warnings[0], "none given");
}

// Every committed fibre file passes the checks against its surface and the patches its scene bones give.
TEST(FibreGenerator, EveryCommittedFibreFilePassesTheChecks) {
  const std::string package = MD_PACKAGE_DIR;
  const md::SceneDescription scene = md::loadSceneDescription(package + "/config/scenes/right_hip_thigh.yaml");
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(scene, scene.urdf_file));
  std::map<std::string, md::TriangleMesh> bones;
  for (md::Bone& bone : md::loadBones(skeleton, md::makeUriResolver({{"muscle_deformation", package}}, package),
                                      scene.frame)) {
    bones[bone.name] = std::move(bone.surface);
  }
  md::FibreGeneratorOptions options;  // the defaults generate_fibres used then: seeds on the field's mid-value
  options.seed_section = md::SeedSection::mid_value;
  for (const md::MuscleDescription& m : scene.muscles) {
    SCOPED_TRACE(m.name);
    const md::TriangleMesh surface = md::loadClosedSurface(md::resolveScenePath(scene, m.surface_file));
    const std::vector<md::Polyline> fibres = md::loadPolylines(md::resolveScenePath(scene, m.fibre_file));
    EXPECT_EQ(fibres.size(), 64u);
    const auto origin = bones.find(m.origin_bone), insertion = bones.find(m.insertion_bone);
    const md::AttachmentPatches patches =
        md::findAttachmentPatches(surface, origin == bones.end() ? nullptr : &origin->second,
                                  insertion == bones.end() ? nullptr : &insertion->second, options);
    const md::FibreCheckReport report = md::checkFibres(surface, patches, fibres, options);
    EXPECT_TRUE(report.passed()) << report.describe();
    EXPECT_GT(report.min_pairwise_distance, 0.0);
  }
}
