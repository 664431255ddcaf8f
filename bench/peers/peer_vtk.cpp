// VTK peers (see peer_vtk.hpp). Built as C++17.
#include "peer_vtk.hpp"
#include "timing.hpp"

#include <vtkCellArray.h>
#include <vtkCellArrayIterator.h>
#include <vtkContour3DLinearGrid.h>
#include <vtkFloatArray.h>
#include <vtkFlyingEdges3D.h>
#include <vtkImageData.h>
#include <vtkMarchingCubes.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPolyData.h>
#include <vtkSMPTools.h>
#include <vtkSpanSpace.h>
#include <vtkXMLUnstructuredGridReader.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <thread>

namespace {

using Clock = std::chrono::steady_clock;

vtkSmartPointer<vtkImageData> image(const float* values, const int dims[3], const double spacing[3]) {
  auto img = vtkSmartPointer<vtkImageData>::New();
  img->SetDimensions(dims[0], dims[1], dims[2]);
  img->SetSpacing(spacing[0], spacing[1], spacing[2]);
  img->SetOrigin(0, 0, 0);
  vtkNew<vtkFloatArray> a;
  a->SetName("v");
  const vtkIdType n = vtkIdType(dims[0]) * dims[1] * dims[2];
  a->SetArray(const_cast<float*>(values), n, 1);  // no copy; the caller keeps the buffer alive
  img->GetPointData()->SetScalars(a);
  return img;
}

void to_mesh(vtkPolyData* pd, PeerMesh& m) {
  m.xyz.resize(3 * std::size_t(pd->GetNumberOfPoints()));
  for (vtkIdType i = 0; i < pd->GetNumberOfPoints(); ++i) {
    double p[3];
    pd->GetPoint(i, p);
    for (int a = 0; a < 3; ++a) m.xyz[3 * i + a] = float(p[a]);
  }
  m.triangles.clear();
  auto it = vtk::TakeSmartPointer(pd->GetPolys()->NewIterator());
  for (it->GoToFirstCell(); !it->IsDoneWithTraversal(); it->GoToNextCell()) {
    vtkIdType npts;
    const vtkIdType* ids;
    it->GetCurrentCell(npts, ids);
    for (vtkIdType k = 2; k < npts; ++k) {
      m.triangles.push_back(std::uint32_t(ids[0]));
      m.triangles.push_back(std::uint32_t(ids[k - 1]));
      m.triangles.push_back(std::uint32_t(ids[k]));
    }
  }
}

// One image-contouring filter (flying edges or marching cubes) timed the same way.
template <class Filter>
double contour_image(const float* values, const int dims[3], const double spacing[3], double iso, int repeat, PeerMesh& out) {
  auto img = image(values, dims, spacing);
  vtkNew<Filter> f;
  f->SetInputData(img);
  f->SetValue(0, iso);
  f->ComputeNormalsOn();
  double t = best_of(repeat, [&] {
    f->Modified();
    f->Update();
  });
  to_mesh(f->GetOutput(), out);
  return t;
}

}  // namespace

double vtk_flying_edges(const float* values, const int dims[3], const double spacing[3], double iso, int repeat, PeerMesh& out,
                        std::string& backend) {
  const double t = contour_image<vtkFlyingEdges3D>(values, dims, spacing, iso, repeat, out);
  backend = vtkSMPTools::GetBackend();
  return t;
}

double vtk_marching_cubes(const float* values, const int dims[3], const double spacing[3], double iso, int repeat, PeerMesh& out) {
  return contour_image<vtkMarchingCubes>(values, dims, spacing, iso, repeat, out);
}

void vtk_grid_contours(const std::string& vtu, const std::vector<double>& isos, int repeat) {
  vtkNew<vtkXMLUnstructuredGridReader> reader;
  reader->SetFileName(vtu.c_str());
  auto t0 = Clock::now();
  reader->Update();
  const double load = std::chrono::duration<double>(Clock::now() - t0).count();
  vtkNew<vtkContour3DLinearGrid> c;
  c->SetInputConnection(reader->GetOutputPort());
  c->SetInputArrayToProcess(0, 0, 0, vtkDataObject::FIELD_ASSOCIATION_POINTS, "value");
  c->MergePointsOn();
  c->ComputeNormalsOff();
  vtkNew<vtkSpanSpace> tree;
  c->SetScalarTree(tree);
  c->UseScalarTreeOn();
  c->SetValue(0, isos.empty() ? 0.0 : isos[0]);
  t0 = Clock::now();
  c->Update();  // builds the scalar tree
  const double first = std::chrono::duration<double>(Clock::now() - t0).count();
  std::printf("{\"method\":\"vtkContour3DLinearGrid+vtkSpanSpace\",\"stage\":\"setup\",\"load_seconds\":%.3f,\"first_seconds\":%.3f}\n",
              load, first);
  for (double iso : isos) {
    c->SetValue(0, iso);
    double t = best_of(repeat, [&] {
      c->Modified();
      c->Update();
    });
    vtkPolyData* out = vtkPolyData::SafeDownCast(c->GetOutputDataObject(0));
    std::printf("{\"method\":\"vtkContour3DLinearGrid+vtkSpanSpace\",\"iso\":%.9g,\"triangles\":%lld,\"seconds\":%.6f,\"threads\":%u}\n",
                iso, out ? (long long)out->GetNumberOfCells() : 0LL, t, std::thread::hardware_concurrency());
  }
  std::fflush(stdout);
}
