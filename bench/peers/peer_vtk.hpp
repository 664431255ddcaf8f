// VTK side of peer_bench, behind plain types: VTK 9.1's headers do not compile as C++20, so
// peer_vtk.cpp is built as C++17 and never sees adaptiso's headers.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

struct PeerMesh {
  std::vector<float> xyz;
  std::vector<std::uint32_t> triangles;
};

// Best-of-`repeat` seconds of vtkFlyingEdges3D / vtkMarchingCubes on a float image (origin 0).
double vtk_flying_edges(const float* values, const int dims[3], const double spacing[3], double iso, int repeat, PeerMesh& out,
                        std::string& smp_backend);
double vtk_marching_cubes(const float* values, const int dims[3], const double spacing[3], double iso, int repeat, PeerMesh& out);
// vtkContour3DLinearGrid with a vtkSpanSpace scalar tree over a .vtu with point scalars "value":
// prints one JSON line per iso-value (and one for loading and the first, tree-building, run).
void vtk_grid_contours(const std::string& vtu, const std::vector<double>& isos, int repeat);
