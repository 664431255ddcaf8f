// adaptiso/mesh.hpp — an indexed triangle mesh with per-vertex normals, and its measures.
//
// Positions and normals are float32 in world coordinates (the volume's origin and direction
// applied). Triangles are counter-clockwise seen from the side their vertex normals point to.
// Files: mesh_io.hpp.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

namespace adaptiso {

struct Mesh {
  std::vector<std::array<float, 3>> positions;
  std::vector<std::array<float, 3>> normals;  // empty or one per position
  std::vector<std::array<std::uint32_t, 3>> triangles;

  std::size_t vertex_count() const { return positions.size(); }
  std::size_t triangle_count() const { return triangles.size(); }
};

// Surface area and signed enclosed volume (divergence theorem; exact for a closed mesh), in double.
double mesh_area(const Mesh& mesh);
double mesh_volume(const Mesh& mesh);

}  // namespace adaptiso
