#include "muscle_deformation/core/collision/collision_ready_model.hpp"

namespace muscle_deformation {

CollisionReadyModel buildCollisionReadyModel(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones,
                                             const ModelSettings& settings, const CollisionSettings& collision,
                                             ModelBuildReport* report, const BoneFields& prebuilt_fields) {
  CollisionReadyModel model;
  model.system = buildMassSpringSystem(muscles, bones, settings, report);
  if (collision.bone_proxy == BoneProxyKind::distance_field) {
    if (prebuilt_fields.empty()) {
      model.bone_fields = buildBoneFields(bones, collision.bone_field);
    } else {
      if (prebuilt_fields.size() != bones.size())
        throw ModelError("prebuilt bone fields: " + std::to_string(prebuilt_fields.size()) + " fields for " +
                         std::to_string(bones.size()) + " bones");
      for (const auto& field : prebuilt_fields)
        if (!field || field->settings().voxel_m != collision.bone_field.voxel_m ||
            field->settings().exterior_band_m != collision.bone_field.exterior_band_m)
          throw ModelError("prebuilt bone fields were built with other settings than collision.bone_field");
      model.bone_fields = prebuilt_fields;
    }
  } else {
    for (const Bone& bone : bones)
      model.bone_spheres.push_back(boneSpheresOneRing(bone.surface, collision.bone_sphere_rule));
  }
  model.rest_overlaps = clearRestOverlaps(model.system, model.bone_spheres);
  return model;
}

}  // namespace muscle_deformation
