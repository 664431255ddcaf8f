// adaptiso/mesh_codec.hpp — a compact encoding of a mesh for the wire (the viewer's surfaces).
//
// Positions are quantized to 16 bits per axis over the mesh's bounding box (an error of at most
// half a step: extent / 131070 per axis), normals to 8-bit octahedral coordinates (about 0.6° at
// worst), 8 bytes a vertex in first-use order, compressed with meshoptimizer's vertex codec;
// triangles with its index codec. Layout, little-endian:
//   char[4] "ADM2"; u32 vertex count V; u32 triangle count T; f32 origin[3]; f32 step[3]
//   (position = origin + step ⊙ q); u32 vertex bytes; vertex stream; u32 stream count K =
//   ⌈T / 2^20⌉; K × (u32 triangles, u32 base, u32 bytes); K index streams
// The vertex stream decodes (meshopt_decodeVertexBuffer, 8-byte vertices) to u16 qx, qy, qz and
// i8 ox, oy, the octahedral normal (x, y = o / 127; z = 1 − |x| − |y|; where z < 0,
// (x, y) ← ((1 − |y|)·sign x, (1 − |x|)·sign y); then normalised); index stream k
// (meshopt_decodeIndexBuffer) to the u32 indices of its triangles (2^20 each but the last, in
// order), each rotated down by the stream's base modulo V: index = (decoded + base) mod V. The
// streams are encoded side by side (meshoptimizer's codec runs on one thread; an 8.2 M-triangle
// surface: 0.31 s against 0.40 s on 2 cores) and the base, the first vertex a stream uses first,
// keeps its new vertices counting up from 0 as the codec predicts. The same triangles as the
// mesh, in the same order and winding (the index codec may rotate a triangle's corners), the
// vertices renumbered by first use.
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <string_view>

#include "adaptiso/mesh.hpp"

namespace adaptiso {

// With an order (a permutation of the triangles' indices), the triangles are encoded in that
// order instead: the codecs compress spatially coherent triangles best (Extractor::
// triangles_in_march_order: a surface after incremental steps took 8.7 bytes a triangle in its
// own order and 4.9 in the march's). Throws std::invalid_argument when the order's size is not
// the triangle count or an index is out of range.
std::string encode_mesh_compact(const Mesh& mesh, std::span<const std::uint32_t> order = {});
// The decoded mesh (positions and normals as quantized); throws InputError on a malformed buffer.
Mesh decode_mesh_compact(std::string_view bytes);

}  // namespace adaptiso
