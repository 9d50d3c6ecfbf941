// Fibre generation, shared by every step (private header): helpers, the checks of the input and of the fibres.
#pragma once

#include "muscle_deformation/preprocessing/fibre_generator.hpp"

#include <limits>
#include <string>
#include <vector>

// generateFibres (fibre_generator.hpp) is made of steps, one file each in this folder:
//   attachment_patches.cpp  the origin and insertion patches from the bones (findAttachmentPatches)
//   fibre_field.cpp         voxel grid, voxelisation, the harmonic field solve, cross-sections (fibre_field.hpp)
//   fibre_tracing.cpp       geometry helpers, seeds, streamlines, resampling, tracing from a cross-section
//                           (fibre_tracing.hpp)
//   fibre_checks.cpp        the checks of a fibre set (checkFibres, FibreCheckReport::describe, windingNumber)
//   fibre_generator.cpp     the checks of the input, generateFibres (the steps in order) and saveFibresVtk
// What they share is in namespace fibre_steps, declared in this header and the two named above (none is installed).
namespace muscle_deformation::fibre_steps {

struct Field;
struct CrossSection;

constexpr double kInf = std::numeric_limits<double>::infinity();

// Metres as millimetres with `precision` decimals, for messages: "12.35 mm".
std::string mm(double metres, int precision = 2);

// The checks of the input (fibre_generator.cpp): each throws FibreGenerationError saying what is wrong.
void requireClosed(const TriangleMesh& surface);
void validateOptions(const FibreGeneratorOptions& options);
void validatePatches(const TriangleMesh& surface, const AttachmentPatches& patches);

// The checks of a fibre set (fibre_checks.cpp), with the coverage measured on `section` (the one the seeds were
// spread over).
FibreCheckReport runChecks(const TriangleMesh& surface, const AttachmentPatches& patches,
                           const std::vector<Polyline>& fibres, const Field& field, const CrossSection& section,
                           const FibreGeneratorOptions& options);

}  // namespace muscle_deformation::fibre_steps
