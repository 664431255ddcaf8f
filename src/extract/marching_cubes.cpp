// Marching cubes with a generated, crack-free case table (see marching_cubes.hpp).
#include "adaptiso/marching_cubes.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "adaptiso/error.hpp"
#include "extract/edge_point.hpp"

namespace adaptiso {
namespace {
using detail::kEdgeMargin;
using detail::to_world;

// Cube corner c = x + 2y + 4z. Edges 0-3 run along x at (y,z) = (0,0),(1,0),(0,1),(1,1);
// 4-7 along y at (x,z) = (0,0),(1,0),(0,1),(1,1); 8-11 along z at (x,y) = (0,0),(1,0),(0,1),(1,1).
struct CubeEdge {
  int a, b;    // corners, a has the lower coordinate
  int axis;    // 0 x, 1 y, 2 z
  int du, dv;  // offsets of the edge's start along the other two axes (x/y/z order, skipping axis)
};

constexpr std::array<CubeEdge, 12> make_edges() {
  std::array<CubeEdge, 12> e{};
  int n = 0;
  for (int axis = 0; axis < 3; ++axis)
    for (int v = 0; v < 2; ++v)
      for (int u = 0; u < 2; ++u) {
        int coord[3] = {0, 0, 0};
        int o1 = axis == 0 ? 1 : 0, o2 = axis == 2 ? 1 : 2;
        coord[o1] = u;
        coord[o2] = v;
        int a = coord[0] + 2 * coord[1] + 4 * coord[2];
        e[n++] = {a, a + (1 << axis), axis, u, v};
      }
  return e;
}
constexpr std::array<CubeEdge, 12> kEdges = make_edges();

int edge_between(int a, int b) {
  for (int e = 0; e < 12; ++e)
    if ((kEdges[e].a == a && kEdges[e].b == b) || (kEdges[e].a == b && kEdges[e].b == a)) return e;
  return -1;
}

struct CubeCase {
  std::uint8_t triangles = 0;
  std::uint8_t ambiguous_faces = 0;
  std::array<std::array<std::uint8_t, 3>, 12> tri{};
};

std::array<CubeCase, 256> make_cube_cases() {
  std::array<CubeCase, 256> cases{};
  double P[8][3];
  for (int c = 0; c < 8; ++c) P[c][0] = c & 1, P[c][1] = (c >> 1) & 1, P[c][2] = (c >> 2) & 1;
  for (int m = 1; m < 255; ++m) {
    auto above = [&](int c) { return (m >> c) & 1; };
    std::array<std::vector<int>, 12> link;  // contour segments join cut edges, two per cut edge
    int ambiguous = 0;
    for (int axis = 0; axis < 3; ++axis)
      for (int side = 0; side < 2; ++side) {
        const int o1 = axis == 0 ? 1 : 0, o2 = axis == 2 ? 1 : 2;
        int q[4];
        const int uv[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
        for (int i = 0; i < 4; ++i) q[i] = (side << axis) | (uv[i][0] << o1) | (uv[i][1] << o2);
        int cut[4], n = 0;
        for (int i = 0; i < 4; ++i) cut[i] = above(q[i]) != above(q[(i + 1) % 4]) ? edge_between(q[i], q[(i + 1) % 4]) : -1;
        for (int i = 0; i < 4; ++i) n += cut[i] >= 0;
        auto join = [&](int e1, int e2) {
          link[e1].push_back(e2);
          link[e2].push_back(e1);
        };
        if (n == 2) {
          int e[2], k = 0;
          for (int i = 0; i < 4; ++i)
            if (cut[i] >= 0) e[k++] = cut[i];
          join(e[0], e[1]);
        } else if (n == 4) {  // diagonal: cut each above corner off (edges before and after it)
          ++ambiguous;
          for (int i = 0; i < 4; ++i)
            if (above(q[i])) join(cut[(i + 3) % 4], cut[i]);
        }
      }
    CubeCase cc;
    cc.ambiguous_faces = static_cast<std::uint8_t>(ambiguous);
    std::array<bool, 12> used{};
    for (int start = 0; start < 12; ++start) {
      if (used[start] || link[start].empty()) continue;
      std::vector<int> loop{start};
      used[start] = true;
      for (int prev = -1, cur = start;;) {
        int next = link[cur][0] != prev ? link[cur][0] : link[cur][1];
        if (next == start) break;
        loop.push_back(next);
        used[next] = true;
        prev = cur;
        cur = next;
      }
      // Orient: the Newell normal must point against the edges' below→above directions.
      double nrm[3] = {0, 0, 0}, g[3] = {0, 0, 0};
      for (std::size_t i = 0; i < loop.size(); ++i) {
        const auto& e1 = kEdges[loop[i]];
        const auto& e2 = kEdges[loop[(i + 1) % loop.size()]];
        double p1[3], p2[3];
        for (int k = 0; k < 3; ++k) p1[k] = 0.5 * (P[e1.a][k] + P[e1.b][k]), p2[k] = 0.5 * (P[e2.a][k] + P[e2.b][k]);
        nrm[0] += (p1[1] - p2[1]) * (p1[2] + p2[2]);
        nrm[1] += (p1[2] - p2[2]) * (p1[0] + p2[0]);
        nrm[2] += (p1[0] - p2[0]) * (p1[1] + p2[1]);
        const int up = above(e1.a) ? e1.a : e1.b, down = above(e1.a) ? e1.b : e1.a;
        for (int k = 0; k < 3; ++k) g[k] += P[up][k] - P[down][k];
      }
      if (nrm[0] * g[0] + nrm[1] * g[1] + nrm[2] * g[2] > 0) std::reverse(loop.begin(), loop.end());
      for (std::size_t i = 1; i + 1 < loop.size(); ++i)
        cc.tri[cc.triangles++] = {std::uint8_t(loop[0]), std::uint8_t(loop[i]), std::uint8_t(loop[i + 1])};
    }
    cases[m] = cc;
  }
  return cases;
}

const std::array<CubeCase, 256> kCubeCases = make_cube_cases();
constexpr std::uint32_t kNone = ~std::uint32_t{0};

struct Chunk {
  std::int64_t k0 = 0, k1 = 0;  // cube layers [k0, k1)
  std::vector<std::array<float, 3>> positions, normals;
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<std::uint32_t> top_index;   // per local vertex: plane-k1 map index, or kNone
  std::vector<std::uint32_t> bottom_map;  // plane k0: map index → local vertex
  std::vector<std::uint32_t> global;      // local → global vertex
  std::size_t owned = 0, cubes_cut = 0, ambiguous = 0;
};

template <class T>
void run_chunk(const Volume& v, const T* f, double iso, Chunk& ch, bool last) {
  const std::int64_t nx = v.dims[0], ny = v.dims[1], nz = v.dims[2];
  const std::int64_t sxy = nx * ny;
  const std::size_t plane_x = static_cast<std::size_t>((nx - 1) * ny), plane_y = static_cast<std::size_t>(nx * (ny - 1));
  // Vertex ids of the x/y edges of the lower and upper plane, and of the z edges in between.
  std::vector<std::uint32_t> lower(plane_x + plane_y, kNone), upper(plane_x + plane_y, kNone), zmap(static_cast<std::size_t>(sxy), kNone);
  std::vector<std::uint8_t> above_lo(static_cast<std::size_t>(sxy)), above_hi(static_cast<std::size_t>(sxy));
  const auto& s = v.spacing;
  const auto& D = v.direction;
  auto value = [&](std::int64_t i, std::int64_t j, std::int64_t k) { return static_cast<double>(f[i + nx * j + sxy * k]); };
  auto gradient = [&](std::int64_t i, std::int64_t j, std::int64_t k, double g[3]) {
    const std::int64_t idx[3] = {i, j, k}, n[3] = {nx, ny, nz};
    for (int a = 0; a < 3; ++a) {
      std::int64_t lo[3] = {i, j, k}, hi[3] = {i, j, k};
      lo[a] = std::max<std::int64_t>(idx[a] - 1, 0);
      hi[a] = std::min<std::int64_t>(idx[a] + 1, n[a] - 1);
      g[a] = hi[a] > lo[a] ? (value(hi[0], hi[1], hi[2]) - value(lo[0], lo[1], lo[2])) / (s[a] * double(hi[a] - lo[a])) : 0.0;
    }
  };
  auto make_vertex = [&](std::int64_t i, std::int64_t j, std::int64_t k, int axis) {
    std::int64_t i2 = i + (axis == 0), j2 = j + (axis == 1), k2 = k + (axis == 2);
    double va = value(i, j, k), vb = value(i2, j2, k2);
    // Interpolate from the below end to the above end, as the tetrahedral extraction does.
    bool a_below = va < iso;
    double t = a_below ? (iso - va) / (vb - va) : (iso - vb) / (va - vb);
    t = std::clamp(t, kEdgeMargin, 1 - kEdgeMargin);
    double w = a_below ? t : 1 - t;  // weight of the (i2,j2,k2) end
    double p[3] = {s[0] * (i + w * (i2 - i)), s[1] * (j + w * (j2 - j)), s[2] * (k + w * (k2 - k))};
    double ga[3], gb[3], nrm[3];
    gradient(i, j, k, ga);
    gradient(i2, j2, k2, gb);
    for (int a = 0; a < 3; ++a) nrm[a] = -((1 - w) * ga[a] + w * gb[a]);
    double len = std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
    if (!(len > 0)) {  // flat gradient: the edge direction towards the lower end
      for (int a = 0; a < 3; ++a) nrm[a] = 0;
      nrm[axis] = a_below ? -1 : 1;
    }
    std::array<float, 3> wp, wn;
    to_world(v.origin, D, p, nrm, wp, wn);
    ch.positions.push_back(wp);
    ch.normals.push_back(wn);
    return static_cast<std::uint32_t>(ch.positions.size() - 1);
  };
  auto fill_above = [&](std::int64_t k, std::vector<std::uint8_t>& out) {
    const T* row = f + sxy * k;
    for (std::int64_t q = 0; q < sxy; ++q) out[static_cast<std::size_t>(q)] = static_cast<double>(row[q]) >= iso;
  };
  // Per plane row: 0 all below, 1 all above, 2 mixed. A row of cubes whose four corner rows are
  // uniform and equal holds no surface and is skipped without looking at its cubes.
  std::vector<std::uint8_t> rows_lo(static_cast<std::size_t>(ny)), rows_hi(static_cast<std::size_t>(ny));
  auto row_states = [&](const std::vector<std::uint8_t>& above, std::vector<std::uint8_t>& rows) {
    for (std::int64_t j = 0; j < ny; ++j) {
      const std::uint8_t* r = above.data() + j * nx;
      std::uint8_t state = r[0];
      for (std::int64_t i = 1; i < nx && state != 2; ++i)
        if (r[i] != r[0]) state = 2;
      rows[static_cast<std::size_t>(j)] = state;
    }
  };
  // Map slots are reset individually after use (clearing whole planes per layer costs more).
  std::vector<std::uint32_t*> written_z, written_lower, written_upper;
  fill_above(ch.k0, above_lo);
  row_states(above_lo, rows_lo);
  for (std::int64_t k = ch.k0; k < ch.k1; ++k) {
    fill_above(k + 1, above_hi);
    row_states(above_hi, rows_hi);
    for (auto* w : written_z) *w = kNone;
    written_z.clear();
    const bool top_is_foreign = !last && k + 1 == ch.k1;
    for (std::int64_t j = 0; j + 1 < ny; ++j) {
      const std::uint8_t s0 = rows_lo[j];
      if (s0 != 2 && rows_lo[j + 1] == s0 && rows_hi[j] == s0 && rows_hi[j + 1] == s0) continue;
      for (std::int64_t i = 0; i + 1 < nx; ++i) {
        const std::size_t q = static_cast<std::size_t>(i + nx * j);
        const std::uint8_t* lo = above_lo.data() + q;
        const std::uint8_t* hi = above_hi.data() + q;
        const int code =
            lo[0] | (lo[1] << 1) | (lo[nx] << 2) | (lo[nx + 1] << 3) | (hi[0] << 4) | (hi[1] << 5) | (hi[nx] << 6) | (hi[nx + 1] << 7);
        if (code == 0 || code == 255) continue;
        const CubeCase& cc = kCubeCases[code];
        ++ch.cubes_cut;
        ch.ambiguous += cc.ambiguous_faces;
        std::uint32_t ids[12];
        std::uint16_t needed = 0;
        for (int t = 0; t < cc.triangles; ++t)
          for (int e : cc.tri[t]) needed |= std::uint16_t(1u << e);
        for (int e = 0; e < 12; ++e) {
          if (!(needed >> e & 1)) continue;
          const CubeEdge& ce = kEdges[e];
          std::int64_t ei = i, ej = j, ek = k;
          if (ce.axis == 0)
            ej += ce.du, ek += ce.dv;
          else if (ce.axis == 1)
            ei += ce.du, ek += ce.dv;
          else
            ei += ce.du, ej += ce.dv;
          std::uint32_t* slot;
          std::size_t map_index = 0;
          bool top = false;
          if (ce.axis == 2) {
            slot = &zmap[static_cast<std::size_t>(ei + nx * ej)];
          } else {
            map_index = ce.axis == 0 ? static_cast<std::size_t>(ei + (nx - 1) * ej) : plane_x + static_cast<std::size_t>(ei + nx * ej);
            top = ek != k;
            slot = top ? &upper[map_index] : &lower[map_index];
          }
          if (*slot == kNone) {
            *slot = make_vertex(ei, ej, ek, ce.axis);
            (ce.axis == 2 ? written_z : top ? written_upper : written_lower).push_back(slot);
            ch.top_index.push_back(top && top_is_foreign ? static_cast<std::uint32_t>(map_index) : kNone);
          }
          ids[e] = *slot;
        }
        for (int t = 0; t < cc.triangles; ++t) ch.triangles.push_back({ids[cc.tri[t][0]], ids[cc.tri[t][1]], ids[cc.tri[t][2]]});
      }
    }
    if (k == ch.k0) ch.bottom_map = lower;
    // The old lower plane's buffer becomes the new upper one: reset the slots it used.
    for (auto* w : written_lower) *w = kNone;
    written_lower.swap(written_upper);
    written_upper.clear();
    lower.swap(upper);
    above_lo.swap(above_hi);
    rows_lo.swap(rows_hi);
  }
}

}  // namespace

Mesh marching_cubes(const Volume& v, double iso, MarchingCubesStats* stats) {
  if (!std::isfinite(iso)) throw InputError("the iso-value must be a finite number");
  Mesh mesh;
  const std::int64_t nz = v.dims[2];
  if (v.dims[0] < 2 || v.dims[1] < 2 || nz < 2) return mesh;
  // A fixed decomposition (not the thread count) keeps the output identical on any machine.
  const std::int64_t layers = nz - 1, nchunks = std::min<std::int64_t>(layers, 16);
  std::vector<Chunk> chunks(static_cast<std::size_t>(nchunks));
  for (std::int64_t c = 0; c < nchunks; ++c) {
    chunks[c].k0 = layers * c / nchunks;
    chunks[c].k1 = layers * (c + 1) / nchunks;
  }
  visit_values(v, [&](auto span) {
    tbb::parallel_for(std::size_t{0}, chunks.size(),
                      [&](std::size_t c) { run_chunk(v, span.data(), iso, chunks[c], c + 1 == chunks.size()); });
  });
  // Vertices on a slab's top plane belong to the next slab (which made them for its bottom plane).
  std::size_t total = 0;
  for (auto& ch : chunks) {
    ch.owned = 0;
    for (auto t : ch.top_index) ch.owned += t == kNone;
    total += ch.owned;
  }
  std::vector<std::size_t> offset(chunks.size() + 1, 0);
  for (std::size_t c = 0; c < chunks.size(); ++c) offset[c + 1] = offset[c] + chunks[c].owned;
  tbb::parallel_for(std::size_t{0}, chunks.size(), [&](std::size_t c) {
    auto& ch = chunks[c];
    ch.global.assign(ch.positions.size(), kNone);
    std::size_t next = offset[c];
    for (std::size_t l = 0; l < ch.positions.size(); ++l)
      if (ch.top_index[l] == kNone) ch.global[l] = static_cast<std::uint32_t>(next++);
  });
  mesh.positions.resize(total);
  mesh.normals.resize(total);
  std::vector<std::size_t> tri_offset(chunks.size() + 1, 0);
  for (std::size_t c = 0; c < chunks.size(); ++c) tri_offset[c + 1] = tri_offset[c] + chunks[c].triangles.size();
  mesh.triangles.resize(tri_offset.back());
  tbb::parallel_for(std::size_t{0}, chunks.size(), [&](std::size_t c) {
    auto& ch = chunks[c];
    for (std::size_t l = 0; l < ch.positions.size(); ++l) {
      if (ch.top_index[l] != kNone) {
        ch.global[l] = chunks[c + 1].global[chunks[c + 1].bottom_map[ch.top_index[l]]];
      } else {
        mesh.positions[ch.global[l]] = ch.positions[l];
        mesh.normals[ch.global[l]] = ch.normals[l];
      }
    }
  });
  tbb::parallel_for(std::size_t{0}, chunks.size(), [&](std::size_t c) {
    auto& ch = chunks[c];
    for (std::size_t t = 0; t < ch.triangles.size(); ++t)
      for (int e = 0; e < 3; ++e) mesh.triangles[tri_offset[c] + t][e] = ch.global[ch.triangles[t][e]];
  });
  if (stats) {
    *stats = {};
    for (const auto& ch : chunks) stats->cubes_cut += ch.cubes_cut, stats->ambiguous_faces += ch.ambiguous;
  }
  return mesh;
}

}  // namespace adaptiso
