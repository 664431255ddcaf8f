// Internal: what the viewer's caches cost, and how much memory the viewer may hold (issue 41: on
// the chest CT, 200 clients × 4 levels took the server from 1.16 GB to 7.4 GB, then answered
// "500 out of memory" to every new client). The estimates are measured, not derived: an
// Extractor's heap (glibc's mallinfo2, in use + mapped) after a fresh march and after an
// incremental step with the march-order permutation asked for, on the levels of detail of the
// chest CT prepared at 0.08 of its range (tests/view/test_sessions.cpp keeps them honest).
#pragma once
#include <cstddef>
#include <cstdint>
#include <limits>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "adaptiso/prepare.hpp"

namespace adaptiso::detail {

// This process's resident set (bytes, /proc/self/statm); 0 where there is none.
std::uint64_t resident_bytes();

// --memory-budget's default: half of the machine's physical memory, and no more than this process
// holds plus what the system can give it now (util/memory.hpp: MemAvailable, `ulimit -v`,
// ADAPTISO_MEMORY_LIMIT). The other half is for the browser drawing the surfaces (a software
// renderer holds a few GB for a large one), the page cache and whatever else the machine runs.
std::uint64_t default_memory_budget();

// 1.2 GB, 340 MB, 12 kB: for messages.
std::string byte_size_text(std::uint64_t bytes);

// The bytes a prepared grid's arrays hold (vertices, tetrahedra, index, hierarchy).
std::uint64_t grid_bytes(const PreparedGrid& grid);

// An Extractor's memory on a grid with a surface of `triangles` triangles: its sweep state (a
// byte and a bit per tetrahedron, 8 bytes per index node) and 200 bytes per triangle (measured
// 162–164 after a fresh march, 187–197 after a step with the march order asked for: the mesh,
// the slots of the active tetrahedra, the cut edges' ends kept for re-interpolation, the march's
// and the step's scratch).
constexpr std::uint64_t kExtractorBytesPerTriangle = 200;
std::uint64_t extractor_fixed_bytes(const PreparedGrid& grid);
std::uint64_t extractor_bytes(const PreparedGrid& grid, std::size_t triangles);
// A surface's answer: the plain encoding (24 bytes a vertex, 12 a triangle, two triangles a
// vertex) is the larger of the two.
constexpr std::uint64_t kAnswerBytesPerTriangle = 24;

// The triangle counts seen per kind of surface (a level of detail, or another key the server
// chooses) and band of iso-values (64 across the value range),
// to foresee what an extraction will hold before it runs: a count depends on the iso-value far
// more than on the moment (the chest at level 0: 1.19 M triangles at 100, 0.2 M at 230).
// Thread-safe.
class SurfaceSizes {
public:
  void reset(double min, double max);
  void record(std::size_t key, double iso, std::size_t triangles);
  // The count last seen in the iso-value's band for the key, else the one seen in the nearest band;
  // `unknown` when the key has none.
  std::size_t expected(std::size_t key, double iso, std::size_t unknown) const;

private:
  static constexpr std::size_t kBands = 64;
  static constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();
  std::size_t band(double iso) const;
  mutable std::mutex mutex_;
  double min_ = 0, max_ = 0;
  std::unordered_map<std::size_t, std::vector<std::size_t>> counts_;  // per key, per band; kNone: not seen
};

}  // namespace adaptiso::detail
