// Marching tetrahedra (Lürig & Ertl §2.4) with shared vertices per cut edge; see extract.hpp.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_scan.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>

#include "adaptiso/extract.hpp"

namespace adaptiso {
namespace {

// A cut edge as local vertex indices: `below` (value < iso) and `above` (value >= iso).
struct LocalEdge {
  std::uint8_t below, above;
};
struct Case {
  std::uint8_t triangles = 0;
  LocalEdge tri[2][3];
};

// The 16 cases (bit k set = vertex k above), oriented on the reference tetrahedron
// (0,0,0),(1,0,0),(0,1,0),(0,0,1), which is positively oriented like every grid tetrahedron, so the
// orientation carries over to any of them by an affine map of positive determinant.
std::array<Case, 16> make_cases() {
  const double P[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  std::array<Case, 16> cases{};
  for (int code = 1; code < 15; ++code) {
    std::vector<int> A, B;
    for (int k = 0; k < 4; ++k) ((code >> k) & 1 ? A : B).push_back(k);
    std::vector<std::vector<LocalEdge>> tris;
    if (A.size() == 1 || B.size() == 1) {
      std::vector<LocalEdge> t;
      if (A.size() == 1)
        for (int b : B) t.push_back({std::uint8_t(b), std::uint8_t(A[0])});
      else
        for (int a : A) t.push_back({std::uint8_t(B[0]), std::uint8_t(a)});
      tris.push_back(t);
    } else {  // a quad around the cycle a1b1, a1b2, a2b2, a2b1, split along one diagonal
      LocalEdge q[4] = {{std::uint8_t(B[0]), std::uint8_t(A[0])}, {std::uint8_t(B[0]), std::uint8_t(A[1])},
                        {std::uint8_t(B[1]), std::uint8_t(A[1])}, {std::uint8_t(B[1]), std::uint8_t(A[0])}};
      tris.push_back({q[0], q[1], q[2]});
      tris.push_back({q[0], q[2], q[3]});
    }
    double cb[3] = {0, 0, 0}, ca[3] = {0, 0, 0};
    for (int b : B)
      for (int k = 0; k < 3; ++k) cb[k] += P[b][k] / B.size();
    for (int a : A)
      for (int k = 0; k < 3; ++k) ca[k] += P[a][k] / A.size();
    Case c;
    c.triangles = static_cast<std::uint8_t>(tris.size());
    for (std::size_t t = 0; t < tris.size(); ++t) {
      double m[3][3];
      for (int i = 0; i < 3; ++i)
        for (int k = 0; k < 3; ++k) m[i][k] = 0.5 * (P[tris[t][i].below][k] + P[tris[t][i].above][k]);
      double u[3], v[3];
      for (int k = 0; k < 3; ++k) u[k] = m[1][k] - m[0][k], v[k] = m[2][k] - m[0][k];
      double n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
      double d = n[0] * (cb[0] - ca[0]) + n[1] * (cb[1] - ca[1]) + n[2] * (cb[2] - ca[2]);
      if (d < 0) std::swap(tris[t][1], tris[t][2]);  // face the lower values
      for (int i = 0; i < 3; ++i) c.tri[t][i] = tris[t][i];
    }
    cases[code] = c;
  }
  return cases;
}

const std::array<Case, 16> kCases = make_cases();

inline std::uint64_t edge_key(std::uint32_t below, std::uint32_t above) {
  // Keep (below, above) order in the key: the same grid edge is always cut in the same direction.
  return (std::uint64_t{below} << 32) | above;
}

// Open-addressing map from edge key to mesh vertex, numbering vertices by first use.
class EdgeMap {
public:
  explicit EdgeMap(std::size_t expected) { rehash(std::bit_ceil(std::max<std::size_t>(64, expected * 2))); }
  std::uint32_t find_or_add(std::uint64_t key, std::vector<std::uint64_t>& order) {
    if (order.size() * 10 >= cap_ * 7) grow(order);
    std::size_t h = hash(key);
    for (;; h = (h + 1) & (cap_ - 1)) {
      if (slots_[h] == kEmpty) {
        slots_[h] = key;
        ids_[h] = static_cast<std::uint32_t>(order.size());
        order.push_back(key);
        return ids_[h];
      }
      if (slots_[h] == key) return ids_[h];
    }
  }

private:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
  std::size_t hash(std::uint64_t k) const { return static_cast<std::size_t>((k * 0x9E3779B97F4A7C15ull) >> shift_); }
  void rehash(std::size_t cap) {
    cap_ = cap;
    shift_ = 64 - std::countr_zero(cap);
    slots_.assign(cap, kEmpty);
    ids_.assign(cap, 0);
  }
  void grow(const std::vector<std::uint64_t>& order) {
    rehash(cap_ * 2);
    for (std::uint32_t i = 0; i < order.size(); ++i) {
      std::size_t h = hash(order[i]);
      while (slots_[h] != kEmpty) h = (h + 1) & (cap_ - 1);
      slots_[h] = order[i];
      ids_[h] = i;
    }
  }
  std::size_t cap_ = 0;
  int shift_ = 0;
  std::vector<std::uint64_t> slots_;
  std::vector<std::uint32_t> ids_;
};

constexpr double kEdgeMargin = 1.0 / 1024;

}  // namespace

void march_tetrahedra(const TetGrid& g, const std::vector<std::uint32_t>& active, double iso, Mesh& mesh) {
  const std::size_t n = active.size();
  std::vector<std::uint8_t> codes(n);
  std::vector<std::uint64_t> first_tri(n + 1, 0);
  // 1. Case of every active tetrahedron; triangle offsets by a prefix sum (parallel).
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const auto& t = g.tets[active[i]];
      std::uint8_t c = 0;
      for (int k = 0; k < 4; ++k) c |= static_cast<std::uint8_t>((g.values[t[k]] >= iso) << k);
      codes[i] = c;
    }
  });
  for (std::size_t i = 0; i < n; ++i) first_tri[i + 1] = first_tri[i] + kCases[codes[i]].triangles;
  const std::size_t T = first_tri[n];
  // 2. Corner keys (parallel), 3. shared vertices by first use (sequential: deterministic order).
  std::vector<std::uint64_t> keys(3 * T);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const auto& t = g.tets[active[i]];
      const Case& c = kCases[codes[i]];
      std::uint64_t* k = &keys[3 * first_tri[i]];
      for (int q = 0; q < c.triangles; ++q)
        for (int e = 0; e < 3; ++e) *k++ = edge_key(t[c.tri[q][e].below], t[c.tri[q][e].above]);
    }
  });
  mesh.triangles.resize(T);
  std::vector<std::uint64_t> order;
  order.reserve(T / 2 + 16);
  {
    EdgeMap map(T / 2 + 16);
    for (std::size_t i = 0; i < T; ++i)
      for (int e = 0; e < 3; ++e) mesh.triangles[i][e] = map.find_or_add(keys[3 * i + e], order);
  }
  // 4. Positions and normals by linear interpolation along each cut edge (parallel).
  const std::size_t V = order.size();
  mesh.positions.resize(V);
  mesh.normals.resize(V);
  const auto& s = g.source;
  const auto& D = s.direction;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, V, 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const std::uint32_t a = static_cast<std::uint32_t>(order[i] >> 32), b = static_cast<std::uint32_t>(order[i]);
      const double va = g.values[a], vb = g.values[b];
      double t = (iso - va) / (vb - va);
      t = std::clamp(t, kEdgeMargin, 1 - kEdgeMargin);
      double p[3], nrm[3];
      for (int k = 0; k < 3; ++k) {
        const double pa = s.spacing[k] * g.ijk[a][k], pb = s.spacing[k] * g.ijk[b][k];
        p[k] = pa + t * (pb - pa);
        nrm[k] = -((1 - t) * g.gradients[a][k] + t * g.gradients[b][k]);
      }
      double len = std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
      if (!(len > 0)) {  // gradients cancel: fall back to the edge direction, towards lower values
        for (int k = 0; k < 3; ++k) nrm[k] = s.spacing[k] * (double(g.ijk[a][k]) - double(g.ijk[b][k]));
        len = std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
      }
      double w[3], wn[3];
      for (int k = 0; k < 3; ++k) {
        w[k] = s.origin[k] + D[3 * k] * p[0] + D[3 * k + 1] * p[1] + D[3 * k + 2] * p[2];
        wn[k] = D[3 * k] * nrm[0] + D[3 * k + 1] * nrm[1] + D[3 * k + 2] * nrm[2];
      }
      double wl = std::sqrt(wn[0] * wn[0] + wn[1] * wn[1] + wn[2] * wn[2]);
      if (!(wl > 0)) wl = 1;
      mesh.positions[i] = {float(w[0]), float(w[1]), float(w[2])};
      mesh.normals[i] = {float(wn[0] / wl), float(wn[1] / wl), float(wn[2] / wl)};
    }
  });
}

ExtractStats Extractor::extract(double iso, Mesh& mesh) {
  using Clock = std::chrono::steady_clock;
  ExtractStats st;
  st.iso = iso;
  st.in_range = iso >= grid_.source.min && iso <= grid_.source.max;
  auto t0 = Clock::now();
  sweep_to(tree_, grid_, state_, iso);
  active_.clear();
  active_tetrahedra(tree_, state_, active_);
  auto t1 = Clock::now();
  march_tetrahedra(grid_, active_, iso, mesh);
  auto t2 = Clock::now();
  st.walked = state_.walked;
  st.active = active_.size();
  st.triangles = mesh.triangle_count();
  st.vertices = mesh.vertex_count();
  st.sweep_seconds = std::chrono::duration<double>(t1 - t0).count();
  st.march_seconds = std::chrono::duration<double>(t2 - t1).count();
  return st;
}

}  // namespace adaptiso
