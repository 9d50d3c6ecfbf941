#include "muscle_deformation/core/collision/bone_distance_field.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include "muscle_deformation/core/base/anatomy.hpp"

#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <vector>

namespace muscle_deformation {

namespace {
void initialiseOpenVdbOnce() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}
}  // namespace

std::string validate(const BoneFieldSettings& settings) {
  if (!(settings.voxel_m > 0) || !std::isfinite(settings.voxel_m)) return "bone field voxel size must be > 0";
  if (!(settings.exterior_band_m >= 2 * settings.voxel_m) || !std::isfinite(settings.exterior_band_m))
    return "bone field exterior band must be at least two voxels";
  return "";
}

struct BoneDistanceField::Grid {
  openvdb::FloatGrid::Ptr grid;
  double inverse_voxel = 1;
};

BoneDistanceField::BoneDistanceField(const TriangleMesh& surface, const BoneFieldSettings& settings,
                                     const std::string& name)
    : grid_(std::make_unique<Grid>()), name_(name), settings_(settings) {
  const auto start = std::chrono::steady_clock::now();
  if (const std::string problem = validate(settings); !problem.empty()) throw BoneFieldError(name + ": " + problem);
  const SurfaceTopologyReport topology = checkSurfaceTopology(surface);
  if (!topology.closedManifold())
    throw BoneFieldError(name + ": surface is not a closed 2-manifold (" + topology.describe() +
                         "), so its inside is undefined; repair it (repair_surfaces) or use the sphere proxy");
  if (!surface.vertices.allFinite()) throw BoneFieldError(name + ": surface has non-finite vertices");
  initialiseOpenVdbOnce();

  std::vector<openvdb::Vec3s> points;
  points.reserve(static_cast<std::size_t>(surface.vertices.cols()));
  for (Eigen::Index v = 0; v < surface.vertices.cols(); ++v)
    points.emplace_back(static_cast<float>(surface.vertices(0, v)), static_cast<float>(surface.vertices(1, v)),
                        static_cast<float>(surface.vertices(2, v)));
  std::vector<openvdb::Vec3I> triangles;
  triangles.reserve(static_cast<std::size_t>(surface.triangles.cols()));
  for (Eigen::Index t = 0; t < surface.triangles.cols(); ++t)
    triangles.emplace_back(static_cast<unsigned>(surface.triangles(0, t)), static_cast<unsigned>(surface.triangles(1, t)),
                           static_cast<unsigned>(surface.triangles(2, t)));
  // The inside is filled, so memory grows with the bone's volume over the voxel's: a surface far larger than a bone
  // (metres across, as in analytic tests) gets coarser voxels instead of gigabytes.
  voxel_m_ = std::max(settings.voxel_m, std::cbrt(std::abs(enclosedVolume(surface)) / kMaxInsideVoxels));
  const auto transform = openvdb::math::Transform::createLinearTransform(voxel_m_);
  const float exterior_voxels = static_cast<float>(std::max(settings.exterior_band_m / voxel_m_, 2.0));
  // The whole inside is filled: a particle deep in a bone still reads how far and which way out is.
  grid_->grid = openvdb::tools::meshToSignedDistanceField<openvdb::FloatGrid>(
      *transform, points, triangles, std::vector<openvdb::Vec4I>{}, exterior_voxels,
      std::numeric_limits<float>::max());
  grid_->inverse_voxel = 1.0 / voxel_m_;
  if (!grid_->grid || grid_->grid->activeVoxelCount() == 0)
    throw BoneFieldError(name + ": the surface gave an empty distance field (smaller than a voxel of " +
                         std::to_string(voxel_m_) + " m?)");
  reach_ = boundsOf(surface.vertices);
  reach_.min.array() -= exteriorBand();
  reach_.max.array() += exteriorBand();
  build_ms_ = millisecondsSince(start);
}

BoneDistanceField::~BoneDistanceField() = default;

AlignedBox BoneDistanceField::reachIn(const Eigen::Isometry3d& pose) const {
  AlignedBox result;
  for (int corner = 0; corner < 8; ++corner)
    result.extend(pose * Eigen::Vector3d(corner & 1 ? reach_.max.x() : reach_.min.x(),
                                         corner & 2 ? reach_.max.y() : reach_.min.y(),
                                         corner & 4 ? reach_.max.z() : reach_.min.z()));
  return result;
}

std::size_t BoneDistanceField::memoryBytes() const { return static_cast<std::size_t>(grid_->grid->memUsage()); }

struct BoneDistanceField::Probe::Impl {
  openvdb::FloatGrid::ConstAccessor accessor;
  double inverse_voxel;
  double half_diagonal;
  explicit Impl(const BoneDistanceField& field)
      : accessor(field.grid_->grid->getConstAccessor()),
        inverse_voxel(field.grid_->inverse_voxel),
        half_diagonal(0.5 * std::sqrt(3.0) * field.voxel_m_) {}
};

BoneDistanceField::Probe::Probe(const BoneDistanceField& field) : impl_(std::make_unique<Impl>(field)) {}
BoneDistanceField::Probe::~Probe() = default;
BoneDistanceField::Probe::Probe(Probe&&) noexcept = default;

double BoneDistanceField::Probe::distance(const Eigen::Vector3d& point) const {
  Eigen::Vector3d unused;
  return distance(point, unused);
}

bool BoneDistanceField::Probe::closerThan(const Eigen::Vector3d& point, double limit, double& distance,
                                         Eigen::Vector3d& gradient) const {
  const Eigen::Vector3d index = (point * impl_->inverse_voxel).array().round();
  const double nearest = impl_->accessor.getValue(openvdb::Coord(static_cast<openvdb::Int32>(index.x()),
                                                                 static_cast<openvdb::Int32>(index.y()),
                                                                 static_cast<openvdb::Int32>(index.z())));
  if (nearest - impl_->half_diagonal >= limit) {
    distance = nearest - impl_->half_diagonal;  // a lower bound
    return false;
  }
  distance = this->distance(point, gradient);
  return distance < limit;
}

double BoneDistanceField::Probe::distance(const Eigen::Vector3d& point, Eigen::Vector3d& gradient) const {
  // Voxel (i, j, k) holds the distance at the point (i, j, k) x voxel: interpolate the eight around `point`.
  const Eigen::Vector3d index = point * impl_->inverse_voxel;
  const Eigen::Vector3d lower = index.array().floor();
  const Eigen::Vector3d f = index - lower;
  const openvdb::Coord base(static_cast<openvdb::Int32>(lower.x()), static_cast<openvdb::Int32>(lower.y()),
                            static_cast<openvdb::Int32>(lower.z()));
  double v[2][2][2];
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      for (int k = 0; k < 2; ++k) v[i][j][k] = impl_->accessor.getValue(base.offsetBy(i, j, k));
  // Along z, then y, then x; the gradient differentiates the same interpolant.
  double along_z[2][2], along_z_dz[2][2];
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j) {
      along_z[i][j] = v[i][j][0] + f.z() * (v[i][j][1] - v[i][j][0]);
      along_z_dz[i][j] = v[i][j][1] - v[i][j][0];
    }
  double along_y[2], along_y_dy[2], along_y_dz[2];
  for (int i = 0; i < 2; ++i) {
    along_y[i] = along_z[i][0] + f.y() * (along_z[i][1] - along_z[i][0]);
    along_y_dy[i] = along_z[i][1] - along_z[i][0];
    along_y_dz[i] = along_z_dz[i][0] + f.y() * (along_z_dz[i][1] - along_z_dz[i][0]);
  }
  const double value = along_y[0] + f.x() * (along_y[1] - along_y[0]);
  gradient.x() = (along_y[1] - along_y[0]) * impl_->inverse_voxel;
  gradient.y() = (along_y_dy[0] + f.x() * (along_y_dy[1] - along_y_dy[0])) * impl_->inverse_voxel;
  gradient.z() = (along_y_dz[0] + f.x() * (along_y_dz[1] - along_y_dz[0])) * impl_->inverse_voxel;
  return value;
}

BoneFields buildBoneFields(const std::vector<Bone>& bones, const BoneFieldSettings& settings) {
  BoneFields fields;
  for (const Bone& bone : bones)
    fields.push_back(std::make_shared<const BoneDistanceField>(bone.surface, settings, "bone '" + bone.name + "'"));
  return fields;
}

FieldReadCache::FieldReadCache(Eigen::Index points)
    : at_(Eigen::Matrix3Xd::Zero(3, points)),
      distance_(Eigen::VectorXd::Constant(points, -std::numeric_limits<double>::infinity())) {}

}  // namespace muscle_deformation
