// The edges of a set of tetrahedra (see wireframe.hpp).
#include "adaptiso/wireframe.hpp"

#include <fmt/format.h>
#include <tbb/parallel_sort.h>

#include <algorithm>

#include "adaptiso/error.hpp"

namespace adaptiso {

Wireframe tetrahedra_wireframe(const TetGrid& grid, std::span<const std::uint32_t> tets, std::size_t max_edges) {
  if (tets.size() > max_edges)  // at least one new edge per tetrahedron: refuse before the work
    throw InputError(fmt::format("{} tetrahedra are too many to draw (at most {} edges)", tets.size(), max_edges));
  std::vector<std::uint64_t> keys;
  keys.reserve(tets.size() * 6);
  for (std::uint32_t t : tets) {
    const auto& q = grid.tets[t];
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) keys.push_back((std::uint64_t{std::min(q[a], q[b])} << 32) | std::max(q[a], q[b]));
  }
  tbb::parallel_sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  if (keys.size() > max_edges) throw InputError(fmt::format("{} edges are too many to draw (at most {})", keys.size(), max_edges));
  std::vector<std::uint32_t> used;
  used.reserve(2 * keys.size());
  for (auto k : keys) used.push_back(static_cast<std::uint32_t>(k >> 32)), used.push_back(static_cast<std::uint32_t>(k));
  tbb::parallel_sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  Wireframe w;
  w.positions.resize(used.size());
  for (std::size_t i = 0; i < used.size(); ++i) {
    const Vec3 p = grid.world_position(used[i]);
    w.positions[i] = {static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2])};
  }
  auto local = [&](std::uint32_t v) { return static_cast<std::uint32_t>(std::lower_bound(used.begin(), used.end(), v) - used.begin()); };
  w.edges.resize(keys.size());
  for (std::size_t e = 0; e < keys.size(); ++e)
    w.edges[e] = {local(static_cast<std::uint32_t>(keys[e] >> 32)), local(static_cast<std::uint32_t>(keys[e]))};
  return w;
}

}  // namespace adaptiso
