// Specks dropped (specks.hpp).
#include "extract/specks.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <vector>

#include "adaptiso/volume.hpp"

namespace adaptiso::detail {
namespace {

// Union-find over the vertices, by index (the smaller root wins: the labels do not depend on the
// order of the unions), with path halving.
class Pieces {
public:
  explicit Pieces(std::size_t n) : parent_(n) { std::iota(parent_.begin(), parent_.end(), std::uint32_t{0}); }
  std::uint32_t root(std::uint32_t v) {
    while (parent_[v] != v) v = parent_[v] = parent_[parent_[v]];
    return v;
  }
  void join(std::uint32_t a, std::uint32_t b) {
    a = root(a), b = root(b);
    if (a != b) parent_[std::max(a, b)] = std::min(a, b);
  }

private:
  std::vector<std::uint32_t> parent_;
};

}  // namespace

Specks drop_specks(Mesh& mesh, const GridSource& source, double diagonal) {
  const std::size_t n = mesh.positions.size();
  if (!(diagonal > 0) || mesh.triangles.empty()) return {};
  Pieces pieces(n);
  for (const auto& t : mesh.triangles) pieces.join(t[0], t[1]), pieces.join(t[0], t[2]);
  // The pieces numbered in their roots' order (a root is its piece's smallest vertex, so it comes
  // first), then each piece's box (a vertex of no triangle is a piece of its own, a point: a speck).
  std::vector<std::uint32_t> piece(n);
  std::uint32_t count = 0;
  for (std::uint32_t v = 0; v < n; ++v) {
    const std::uint32_t r = pieces.root(v);
    piece[v] = r == v ? count++ : piece[r];
  }
  constexpr float kInf = std::numeric_limits<float>::infinity();
  std::vector<std::array<float, 6>> box(count, {kInf, kInf, kInf, -kInf, -kInf, -kInf});
  const double smallest = std::min({source.spacing[0], source.spacing[1], source.spacing[2]});
  for (std::uint32_t v = 0; v < n; ++v) {
    const auto& w = mesh.positions[v];
    const Vec3 g = world_to_grid(source.origin, source.direction, {w[0], w[1], w[2]});
    auto& b = box[piece[v]];
    for (int k = 0; k < 3; ++k) {
      const float x = static_cast<float>(g[k] / smallest);
      b[k] = std::min(b[k], x), b[k + 3] = std::max(b[k + 3], x);
    }
  }
  // A speck: a piece whose box's diagonal is under `diagonal`.
  std::vector<std::uint8_t> speck(count, 0);
  Specks dropped;
  for (std::uint32_t p = 0; p < count; ++p) {
    double d2 = 0;
    for (int k = 0; k < 3; ++k) d2 += std::pow(double(box[p][k + 3]) - box[p][k], 2);
    speck[p] = d2 < diagonal * diagonal;
  }
  std::vector<std::array<float, 6>>().swap(box);
  for (const auto& t : mesh.triangles) {
    std::uint8_t& s = speck[piece[t[0]]];
    if (s == 1) ++dropped.pieces, s = 2;  // 2: a speck counted
    dropped.triangles += s != 0;
  }
  if (dropped.triangles == 0) return {};
  // Keep the rest, vertices renumbered in their order (first use stays first use): a vertex goes
  // with its piece.
  constexpr std::uint32_t kGone = std::numeric_limits<std::uint32_t>::max();
  std::vector<std::uint32_t> to(n, kGone);
  std::size_t kept = 0;
  for (const auto& t : mesh.triangles)
    if (!speck[piece[t[0]]]) mesh.triangles[kept++] = t;
  mesh.triangles.resize(kept);
  std::uint32_t next = 0;
  const bool normals = mesh.normals.size() == n;
  for (std::uint32_t v = 0; v < n; ++v) {
    if (speck[piece[v]]) continue;
    to[v] = next;
    mesh.positions[next] = mesh.positions[v];
    if (normals) mesh.normals[next] = mesh.normals[v];
    ++next;
  }
  mesh.positions.resize(next);
  if (normals) mesh.normals.resize(next);
  for (auto& t : mesh.triangles)
    for (auto& v : t) v = to[v];
  return dropped;
}

}  // namespace adaptiso::detail
