#include "poly_data_conversion.hpp"

#include <vtkCellArray.h>
#include <vtkNew.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>

#include <vector>

namespace muscle_deformation {

vtkSmartPointer<vtkPolyData> toPolyData(const TriangleMesh& mesh) {
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(mesh.vertexCount());
  for (Eigen::Index i = 0; i < mesh.vertexCount(); ++i)
    points->SetPoint(i, mesh.vertices(0, i), mesh.vertices(1, i), mesh.vertices(2, i));
  vtkNew<vtkCellArray> polys;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    const vtkIdType ids[3] = {mesh.triangles(0, t), mesh.triangles(1, t), mesh.triangles(2, t)};
    polys->InsertNextCell(3, ids);
  }
  auto data = vtkSmartPointer<vtkPolyData>::New();
  data->SetPoints(points);
  data->SetPolys(polys);
  return data;
}

TriangleMesh toTriangleMesh(vtkPolyData* data, double scale) {
  TriangleMesh mesh;
  const vtkIdType point_count = data->GetNumberOfPoints();
  mesh.vertices.resize(3, point_count);
  for (vtkIdType i = 0; i < point_count; ++i) {
    double p[3];
    data->GetPoint(i, p);
    for (int k = 0; k < 3; ++k) mesh.vertices(k, i) = p[k] * scale;
  }
  std::vector<int> corners;
  vtkIdType count = 0;
  const vtkIdType* ids = nullptr;
  vtkCellArray* polys = data->GetPolys();
  for (polys->InitTraversal(); polys->GetNextCell(count, ids);) {
    for (vtkIdType k = 1; k + 1 < count; ++k) {
      corners.push_back(static_cast<int>(ids[0]));
      corners.push_back(static_cast<int>(ids[k]));
      corners.push_back(static_cast<int>(ids[k + 1]));
    }
  }
  vtkCellArray* strips = data->GetStrips();
  for (strips->InitTraversal(); strips->GetNextCell(count, ids);) {
    for (vtkIdType k = 0; k + 2 < count; ++k) {
      const bool odd = (k % 2) == 1;
      corners.push_back(static_cast<int>(ids[k]));
      corners.push_back(static_cast<int>(odd ? ids[k + 2] : ids[k + 1]));
      corners.push_back(static_cast<int>(odd ? ids[k + 1] : ids[k + 2]));
    }
  }
  mesh.triangles = Eigen::Map<const Triangles>(corners.data(), 3, static_cast<Eigen::Index>(corners.size() / 3));
  return mesh;
}

}  // namespace muscle_deformation
