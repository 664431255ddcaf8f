// adaptiso/mesh.hpp — an indexed triangle mesh with per-vertex normals, and its files.
//
// Positions and normals are float32 in world coordinates (the volume's origin and direction
// applied). Triangles are counter-clockwise seen from the side their vertex normals point to.
// write_mesh picks the format from the extension: .ply (binary little-endian, normals), .obj
// (with normals), .stl (binary; facet normals from the geometry), .glb (glTF 2.0 binary, via
// tinygltf). Every writer goes through a temporary file and a rename. read_ply reads ASCII and
// binary PLY of any scalar property types (polygons fanned into triangles), as VTK and others write.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace adaptiso {

struct Mesh {
  std::vector<std::array<float, 3>> positions;
  std::vector<std::array<float, 3>> normals;  // empty or one per position
  std::vector<std::array<std::uint32_t, 3>> triangles;

  std::size_t vertex_count() const { return positions.size(); }
  std::size_t triangle_count() const { return triangles.size(); }
};

void write_mesh(const Mesh& mesh, const std::string& path);  // throws InputError on an unknown extension
Mesh read_ply(const std::string& path);                       // throws InputError on a malformed file

// Surface area and signed enclosed volume (divergence theorem; exact for a closed mesh), in double.
double mesh_area(const Mesh& mesh);
double mesh_volume(const Mesh& mesh);

}  // namespace adaptiso
