// The compact mesh encoding (see mesh_codec.hpp), with meshoptimizer's codecs.
//
// This work is based on:
// - Cigolle, Donow, Evangelakos, Mara, McGuire, Meyer. A survey of efficient representations for
//   independent unit vectors. JCGT, 2014 (the octahedral encoding of the normals).
// - Kapoulkine. meshoptimizer's vertex and index buffer codecs (used as a library).
#include "adaptiso/mesh_codec.hpp"

#include <fmt/format.h>
#include <meshoptimizer.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <vector>

#include "adaptiso/error.hpp"
#include "util/big_array.hpp"

namespace adaptiso {
namespace {

struct Packed {  // one vertex as encoded: 8 bytes
  std::uint16_t q[3];
  std::int8_t o[2];
};
static_assert(sizeof(Packed) == 8);

// Octahedral mapping of a unit vector to two signed 8-bit coordinates.
void octahedral(const std::array<float, 3>& n, std::int8_t out[2]) {
  const double s = std::abs(n[0]) + std::abs(n[1]) + std::abs(n[2]);
  double x = s > 0 ? n[0] / s : 0, y = s > 0 ? n[1] / s : 0;
  if (n[2] < 0) {
    const double fx = (1 - std::abs(y)) * (x >= 0 ? 1 : -1), fy = (1 - std::abs(x)) * (y >= 0 ? 1 : -1);
    x = fx;
    y = fy;
  }
  out[0] = static_cast<std::int8_t>(std::lround(std::clamp(x, -1.0, 1.0) * 127));
  out[1] = static_cast<std::int8_t>(std::lround(std::clamp(y, -1.0, 1.0) * 127));
}

std::array<float, 3> from_octahedral(const std::int8_t o[2]) {
  double x = o[0] / 127.0, y = o[1] / 127.0;
  const double z = 1 - std::abs(x) - std::abs(y);
  if (z < 0) {
    const double fx = (1 - std::abs(y)) * (x >= 0 ? 1 : -1), fy = (1 - std::abs(x)) * (y >= 0 ? 1 : -1);
    x = fx;
    y = fy;
  }
  const double len = std::sqrt(x * x + y * y + z * z);
  return {static_cast<float>(x / len), static_cast<float>(y / len), static_cast<float>(z / len)};
}

template <class T>
void put(std::string& out, const T& x) {
  out.append(reinterpret_cast<const char*>(&x), sizeof x);
}

// The working arrays of an encoding, kept for the next one. The viewer encodes a surface of
// millions of triangles per request, and on virtual machines fresh memory of that size is costly
// (every page zeroed and faulted in anew): the MR head's 17 M-triangle surfaces encode in 0.70×
// the time with the arrays kept. Two sets are kept (more encodings under way get fresh ones), so
// small requests never wait behind a large one.
struct Scratch {
  std::vector<unsigned int> remap, indices, ordered;
  std::vector<Packed> packed;
  std::vector<unsigned char> vbuf, ibuf;
};

// Triangles per index stream: meshoptimizer's index codec runs on one thread, and took most of the
// 0.40 s an 8.2 M-triangle surface took to encode; streams of 2^20 triangles encode side by side
// (0.31 s on 2 cores).
// A fixed size, so the bytes do not depend on the thread count.
constexpr std::size_t kChunkTriangles = std::size_t{1} << 20;

// A stream's indices rotated by its base, the first vertex it uses first (vertices are numbered by
// first use): its new vertices then count up from 0 as the codec predicts, and the few it shares
// with earlier streams come out high. Values stay below the vertex count.
inline unsigned int rotate_down(unsigned int x, unsigned int base, unsigned int vertices) {
  return x >= base ? x - base : x + (vertices - base);
}
inline unsigned int rotate_up(unsigned int x, unsigned int base, unsigned int vertices) {
  return x < vertices - base ? x + base : x - (vertices - base);
}

struct IndexChunk {
  std::uint32_t triangles = 0, base = 0, bytes = 0;
  std::size_t at = 0;  // where its bytes start in the scratch buffer
};

// The index streams of indices[0, 3T) (renumbered by first use, rotated in place).
std::vector<IndexChunk> encode_index_chunks(unsigned int* indices, std::size_t T, std::size_t used, std::vector<unsigned char>& ibuf) {
  const std::size_t K = (T + kChunkTriangles - 1) / kChunkTriangles;
  std::vector<IndexChunk> chunks(K);
  std::vector<unsigned int> top(K, 0);
  tbb::parallel_for(std::size_t{0}, K, [&](std::size_t k) {
    const std::size_t b = 3 * k * kChunkTriangles, e = 3 * std::min(T, (k + 1) * kChunkTriangles);
    top[k] = *std::max_element(indices + b, indices + e);
  });
  const std::size_t per_chunk = meshopt_encodeIndexBufferBound(3 * std::min(T, kChunkTriangles), used);  // no larger than the mesh
  for (std::size_t k = 0; k < K; ++k) {
    chunks[k].triangles = static_cast<std::uint32_t>(std::min(T, (k + 1) * kChunkTriangles) - k * kChunkTriangles);
    chunks[k].base = k == 0 ? 0 : std::max(chunks[k - 1].base, top[k - 1] + 1);
    chunks[k].at = k * per_chunk;
  }
  detail::resize_big(ibuf, K * per_chunk);
  tbb::parallel_for(std::size_t{0}, K, [&](std::size_t k) {
    auto& c = chunks[k];
    unsigned int* first = indices + 3 * k * kChunkTriangles;
    if (c.base)
      for (std::size_t i = 0; i < 3 * std::size_t{c.triangles}; ++i)
        first[i] = rotate_down(first[i], c.base, static_cast<unsigned int>(used));
    c.bytes = static_cast<std::uint32_t>(meshopt_encodeIndexBuffer(ibuf.data() + c.at, per_chunk, first, 3 * std::size_t{c.triangles}));
  });
  return chunks;
}

class ScratchPool {
public:
  std::unique_ptr<Scratch> take() {
    std::lock_guard lock(mutex_);
    if (free_.empty()) return std::make_unique<Scratch>();
    auto s = std::move(free_.back());
    free_.pop_back();
    return s;
  }
  void give(std::unique_ptr<Scratch> s) {
    std::lock_guard lock(mutex_);
    if (free_.size() < kKept) free_.push_back(std::move(s));
  }

private:
  static constexpr std::size_t kKept = 2;  // the surface at rest and one being dragged
  std::mutex mutex_;
  std::vector<std::unique_ptr<Scratch>> free_;
};

ScratchPool& scratch_pool() {
  static ScratchPool pool;
  return pool;
}

// Positions quantized to 16 bits in the mesh's bounding box (lo + step * q) and normals as 8-bit
// octahedral pairs, in remap order, then meshoptimizer's vertex codec.
void encode_vertices(const Mesh& m, const std::vector<unsigned int>& remap, std::size_t used, float lo[3], float step[3],
                     std::vector<Packed>& packed, std::vector<unsigned char>& vbuf) {
  const std::size_t V = m.vertex_count();
  if (V) {
    float hi[3];
    for (int a = 0; a < 3; ++a) lo[a] = hi[a] = m.positions[0][a];
    for (const auto& p : m.positions)
      for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
    for (int a = 0; a < 3; ++a) step[a] = hi[a] > lo[a] ? (hi[a] - lo[a]) / 65535.0f : 1.0f;
  }
  detail::resize_big(packed, used);
  const bool normals = m.normals.size() == V;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, V, 1 << 14), [&](const auto& r) {
    for (std::size_t v = r.begin(); v < r.end(); ++v) {
      if (remap[v] == ~0u) continue;  // unused vertex
      Packed& p = packed[remap[v]];
      for (int a = 0; a < 3; ++a)  // round half up by truncation (non-negative): lround is a library call
        p.q[a] = static_cast<std::uint16_t>(std::clamp((m.positions[v][a] - lo[a]) / step[a] + 0.5f, 0.0f, 65535.0f));
      if (normals)
        octahedral(m.normals[v], p.o);
      else
        p.o[0] = p.o[1] = 0;
    }
  });
  detail::resize_big(vbuf, meshopt_encodeVertexBufferBound(used, sizeof(Packed)));
  vbuf.resize(meshopt_encodeVertexBuffer(vbuf.data(), vbuf.size(), packed.data(), used, sizeof(Packed)));
}

}  // namespace

std::string encode_mesh_compact(const Mesh& m, std::span<const std::uint32_t> order) {
  const std::size_t V = m.vertex_count(), T = m.triangle_count();
  if (!order.empty() && order.size() != T) throw std::invalid_argument("encode_mesh_compact: the order does not list every triangle");
  std::unique_ptr<Scratch> scratch = scratch_pool().take();
  // Named references, not a structured binding: clang 14 cannot capture one in the lambdas below.
  auto &remap = scratch->remap, &indices = scratch->indices, &ordered = scratch->ordered;
  auto& packed = scratch->packed;
  auto &vbuf = scratch->vbuf, &ibuf = scratch->ibuf;
  // Vertices in first-use order: the codecs compress neighbours' differences.
  detail::resize_big(remap, V);  // ~0u (set by the remap): a vertex no triangle uses
  // The triangles as one index array (no element to take the address of when there is none).
  const unsigned int* triangles = reinterpret_cast<const unsigned int*>(m.triangles.data());
  if (!order.empty()) {
    detail::resize_big(ordered, 3 * T);
    std::atomic<bool> out_of_range{false};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T, 1 << 14), [&](const auto& r) {
      for (std::size_t i = r.begin(); i < r.end(); ++i) {
        if (order[i] >= T) {
          out_of_range = true;
          return;
        }
        std::memcpy(&ordered[3 * i], &m.triangles[order[i]], 12);
      }
    });
    if (out_of_range) {
      scratch_pool().give(std::move(scratch));
      throw std::invalid_argument("encode_mesh_compact: a triangle index in the order is out of range");
    }
    triangles = ordered.data();
  }
  if (!T) std::fill(remap.begin(), remap.end(), ~0u);
  const std::size_t used = T ? meshopt_optimizeVertexFetchRemap(remap.data(), triangles, 3 * T, V) : 0;
  // The index and vertex streams only share the remap: encode them side by side (meshoptimizer's
  // codecs run on one thread each). Same bytes as one after the other.
  float lo[3] = {0, 0, 0}, step[3] = {1, 1, 1};
  std::vector<IndexChunk> chunks;
  tbb::parallel_invoke(
      [&] {
        // Triangles reordered into our own array are renumbered in place (an element-wise map):
        // 12 bytes a triangle of memory fewer to touch.
        unsigned int* renumbered = ordered.data();
        if (order.empty()) {
          detail::resize_big(indices, 3 * T);
          renumbered = indices.data();
        }
        if (T) meshopt_remapIndexBuffer(renumbered, triangles, 3 * T, remap.data());
        chunks = encode_index_chunks(renumbered, T, used, ibuf);
      },
      [&] { encode_vertices(m, remap, used, lo, step, packed, vbuf); });
  std::size_t ibytes = 0;
  for (const auto& c : chunks) ibytes += c.bytes;
  std::string out;
  out.reserve(44 + vbuf.size() + 12 * chunks.size() + ibytes);
  out.append("ADM2", 4);
  put(out, static_cast<std::uint32_t>(used));
  put(out, static_cast<std::uint32_t>(T));
  for (float x : lo) put(out, x);
  for (float x : step) put(out, x);
  put(out, static_cast<std::uint32_t>(vbuf.size()));
  out.append(reinterpret_cast<const char*>(vbuf.data()), vbuf.size());
  put(out, static_cast<std::uint32_t>(chunks.size()));
  for (const auto& c : chunks) {
    put(out, c.triangles);
    put(out, c.base);
    put(out, c.bytes);
  }
  for (const auto& c : chunks) out.append(reinterpret_cast<const char*>(ibuf.data() + c.at), c.bytes);
  scratch_pool().give(std::move(scratch));
  return out;
}

Mesh decode_mesh_compact(std::string_view b) {
  auto fail = [](const char* why) { throw InputError(fmt::format("compact mesh: {}", why)); };
  std::size_t at = 0;
  auto take = [&](void* dst, std::size_t n) {
    if (b.size() - at < n) fail("truncated");
    std::memcpy(dst, b.data() + at, n);
    at += n;
  };
  char magic[4];
  take(magic, 4);
  if (std::memcmp(magic, "ADM2", 4) != 0) fail("bad magic");
  std::uint32_t V, T, vbytes, K;
  float lo[3], step[3];
  take(&V, 4);
  take(&T, 4);
  take(lo, 12);
  take(step, 12);
  take(&vbytes, 4);
  if (b.size() - at < vbytes) fail("truncated vertices");
  if (V > vbytes * std::uint64_t{32} + 64) fail("vertex count");  // the codec needs at least ~1/32 byte a vertex
  std::vector<Packed> packed(V);
  if (meshopt_decodeVertexBuffer(packed.data(), V, sizeof(Packed), reinterpret_cast<const unsigned char*>(b.data() + at), vbytes) != 0)
    fail("vertex stream");
  at += vbytes;
  take(&K, 4);
  if (K != (T + kChunkTriangles - 1) / kChunkTriangles) fail("index stream count");
  std::vector<IndexChunk> chunks(K);
  std::uint64_t ibytes = 0, triangles = 0;
  for (auto& c : chunks) {
    take(&c.triangles, 4);
    take(&c.base, 4);
    take(&c.bytes, 4);
    if (c.triangles == 0 || c.triangles > kChunkTriangles || c.base > V) fail("index stream table");
    if (c.triangles > c.bytes * std::uint64_t{16} + 64) fail("triangle count");
    triangles += c.triangles;
    ibytes += c.bytes;
  }
  if (triangles != T) fail("triangle count");
  if (b.size() - at != ibytes) fail("index stream size");
  Mesh m;
  m.triangles.resize(T);
  std::size_t t = 0;
  for (const auto& c : chunks) {
    unsigned int* first = &m.triangles[t][0];
    if (meshopt_decodeIndexBuffer(first, 3 * std::size_t{c.triangles}, 4, reinterpret_cast<const unsigned char*>(b.data() + at), c.bytes) !=
        0)
      fail("index stream");
    for (std::size_t i = 0; i < 3 * std::size_t{c.triangles}; ++i) {
      if (first[i] >= V) fail("index out of range");
      first[i] = rotate_up(first[i], c.base, V);
    }
    at += c.bytes;
    t += c.triangles;
  }
  m.positions.resize(V);
  m.normals.resize(V);
  for (std::size_t v = 0; v < V; ++v) {
    for (int a = 0; a < 3; ++a) m.positions[v][a] = lo[a] + step[a] * packed[v].q[a];
    m.normals[v] = from_octahedral(packed[v].o);
  }
  return m;
}

}  // namespace adaptiso
