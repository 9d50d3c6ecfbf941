// Between the core's triangle meshes and VTK's vtkPolyData, shared by the loaders (mesh_io.cpp) and the surface repair
// (surface_repair.cpp). Private to the core's sources: no public header includes VTK.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <vtkSmartPointer.h>

class vtkPolyData;

namespace muscle_deformation {

// Double-precision points in column order and one triangle cell per column of mesh.triangles, in order.
vtkSmartPointer<vtkPolyData> toPolyData(const TriangleMesh& mesh);

// Every point of `data` in order (times `scale`), and the triangles of its polygons, each fanned from its first
// vertex (exact for the convex polygons mesh tools write, and it keeps the winding), followed by those of its triangle
// strips (every other one with two corners swapped to keep the orientation). Vertices and lines are ignored, as are
// polygons and strips of fewer than 3 points. Point ids are taken as they are: callers check them first.
TriangleMesh toTriangleMesh(vtkPolyData* data, double scale = 1.0);

}  // namespace muscle_deformation
