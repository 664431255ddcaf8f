// adaptiso/mesh_io.hpp — mesh files.
//
// write_mesh picks the format from the extension: .ply (binary little-endian, normals), .obj
// (with normals), .stl (binary; facet normals from the geometry), .glb (glTF 2.0 binary, via
// tinygltf); all in the mesh's (world) coordinates. Every writer goes through a temporary file
// and a rename (atomic_file.hpp). read_ply reads ASCII and binary PLY of any scalar property
// types (polygons fanned into triangles), as VTK and others write them.
#pragma once
#include <string>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/mesh.hpp"

namespace adaptiso {

bool is_mesh_file_name(const std::string& path);             // .ply .obj .stl .glb (any case)
void write_mesh(const Mesh& mesh, const std::string& path);  // throws InputError on an unknown extension
// The same file written but not yet in place (StagedFile, atomic_file.hpp): commit() puts it there.
StagedFile stage_mesh(const Mesh& mesh, const std::string& path);
// The bytes write_mesh would write for a file of that name (the viewer's downloads).
std::string mesh_file_bytes(const Mesh& mesh, const std::string& name);
Mesh read_ply(const std::string& path);  // throws InputError on a malformed file

}  // namespace adaptiso
