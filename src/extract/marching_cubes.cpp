// Marching cubes with a generated, crack-free case table (see marching_cubes.hpp).
//
// This work is based on:
// - Lorensen, Cline. Marching cubes: a high resolution 3D surface construction algorithm.
//   SIGGRAPH 1987 (the classic table, kClassicTriangles).
// - Dürst. Additional reference to "marching cubes". Computer Graphics, 1988 (the face ambiguity,
//   resolved here by one rule both cubes of a face apply).
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §3 (the paper's baseline).
#include "adaptiso/marching_cubes.hpp"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
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

// The closed contours of configuration m (bit c: corner c above), each a cycle of cut edges wound
// against the edges' below→above directions; *ambiguous counts its faces with diagonal corners.
std::vector<std::vector<int>> oriented_loops(int m, int* ambiguous_faces) {
  double P[8][3];
  for (int c = 0; c < 8; ++c) P[c][0] = c & 1, P[c][1] = (c >> 1) & 1, P[c][2] = (c >> 2) & 1;
  std::vector<std::vector<int>> loops;
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
  *ambiguous_faces = ambiguous;
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
    loops.push_back(std::move(loop));
  }
  return loops;
}

// Our table: each contour fanned from its first edge.
std::array<CubeCase, 256> make_cube_cases() {
  std::array<CubeCase, 256> cases{};
  for (int m = 1; m < 255; ++m) {
    CubeCase cc;
    int ambiguous = 0;
    for (const auto& loop : oriented_loops(m, &ambiguous))
      for (std::size_t i = 1; i + 1 < loop.size(); ++i)
        cc.tri[cc.triangles++] = {std::uint8_t(loop[0]), std::uint8_t(loop[i]), std::uint8_t(loop[i + 1])};
    cc.ambiguous_faces = static_cast<std::uint8_t>(ambiguous);
    cases[m] = cc;
  }
  return cases;
}

// Lorensen & Cline's classic table as scikit-image's method="lorensen" uses it (its CASESCLASSIC,
// corners and edges renumbered to ours): configurations 0 to 255 separated by spaces, each up to 5
// triangles of three cut edges as hexadecimal digits ('.': none). Their winding comes from our
// contours (make_classic_cases), not from here.
constexpr std::string_view kClassicTriangles =
    ". 084 059 584985 4a1 0a18a0 59014a 5a159a98a 51b 08451b 91b019 1841b8b98 4b5ab4 0b508b8ab 4904a9ab9 98bb8a 268 240642 "
    "059826 259265645 8264a1 a26a12102 90582614a 26a92a9a1915 51b826 42640251b 91b901826 1b9196164692 4b54ab682 5ab52a5026a2 "
    "26890a9aba04 26a2a99ab 972 972084 072570 872847457 97214a 0a108a297 07205714a 15717818a287 51b972 40851b297 71b721201 "
    "1b7417472428 b4ab54972 2970858b58ab 72070a7aba04 72878bb8a 968769 940974764 068056576 574476 6976894a1 97696191016a "
    "14a058568576 a15a56657 968976b51 b51970740764 801817876b71 1b7174476 978876b54b4a 7607096a050bab0 ab0a04b70806760 "
    "ab76a7 63a 408a63 059a63 859845a63 614316 608630310 163146059 531583598863 b513a6 51b4083a6 1901b93a6 3a61b4b84b98 "
    "b63b56546 b6356b586508 04606b0b93b6 63b6b88b9 382a83 43a403023 83a823905 923934945a43 814821231 021231 590142123248 "
    "592521123 3823a81b5 51b40a03a023 2a823a0191b9 b94b41924a43234 8548358233b5 b50b03302 2342483b4049b94 b923b2 29763a "
    "084297a63 70572063a a63842472457 614631729 972083031386 431463570720 318386158287578 972b5163a 3a651b084297 "
    "63a72b21b201 428472417b71a63 972b53563546 53b563506860972 20b2b704b3b646b 63b6b872b28b 3973a9a89 43a034073097 "
    "0a807a05773a 3a4347745 789718731481 973930031 578580738481318 573153 51b97a9a8a73 0a403a09373951b a87a73807b71017 "
    "3a43471b4b74 54353b483739893 b50b03970730 04873b b73 b37 0847b3 9057b3 5845987b3 14ab37 a08a10b37 05914a7b3 "
    "7b35919a198a 537135 537513408 937903013 798781713418 34a374754 08a0a70757a3 4a3043037079 37939aa98 7b3268 24026437b "
    "5907b3826 b37596564692 4a1682b37 7b326121016a 05926814a7b3 9159a192a6a27b3 351375268 517713402426 826907037013 "
    "649692419793139 8264a74757a3 75a7a350a6a202a 079037043a34826 37939a2696a9 b2932b 2b329b084 b05b30320 84585383235b "
    "b29b32a14 08118a29b2b3 4a105303235b 32535b28515a8a5 529512132 408519129132 012213 841812213 932943954a34 "
    "8a5850a35952325 4a3430032 328a38 6b368b89b 0640b609b36b b365b6568580 b36b65564 14ab38b89836 10616a09636b9b6 "
    "5805685b636b14a a15a56b35365 513538589836 139195369094649 680603301 641361 893836953a34543 095a36 6806034a0a30 6a3 "
    "a7b67a a7ba67840 7a67ba590 b67ba6985845 17b147467 810871867b17 9057b47464b1 981915861b17671 a51a65675 08451656761a "
    "9679169011a6 67161a791418981 547467 086065567 904947746 986796 7827b8ba8 7027a07baa40 05982b8bab27 ba2b27a42925452 "
    "17b471427482 7b1712210 4b147b487278059 7b1712591921 1751871a8278 02a0a427a1a575a 0170791a7278a87 9271a4 827874475 "
    "027507 827874907047 927 2a629a9ba 0842969a69ba 5ba5a252062a 4524285b262aba2 19b169146629 9b6962b16860106 "
    "46b4b162b5b020b 5b1862 2a69a291a951 9629a695a1a5084 a62a21120 a62a21842412 295256654 295256085865 204624 286 9b8ba8 "
    "40949aa9b 05b0b88ba 45ba4b 14818bb89 9b1091 14818b0585b8 5b1 51a5a99a8 40949a5191a9 01a80a 41a 548958 095 048 .";

// The classic table wound like ours: every triangle's three edges lie on one of our contours (the
// classic table groups the cut edges into the same pieces; a violation throws at start-up) and are
// put in that contour's cyclic order.
std::array<CubeCase, 256> make_classic_cases() {
  std::vector<std::string_view> classic;
  for (std::size_t at = 0; at < kClassicTriangles.size();) {
    const std::size_t end = std::min(kClassicTriangles.find(' ', at), kClassicTriangles.size());
    classic.push_back(kClassicTriangles.substr(at, end - at) == "." ? std::string_view() : kClassicTriangles.substr(at, end - at));
    at = end + 1;
  }
  if (classic.size() != 256) throw std::logic_error("classic cube table: not 256 configurations");
  std::array<CubeCase, 256> cases{};
  for (int m = 1; m < 255; ++m) {
    CubeCase cc;
    int ambiguous = 0;
    std::array<int, 12> loop_of{}, position{};
    loop_of.fill(-1);
    const auto loops = oriented_loops(m, &ambiguous);
    for (std::size_t l = 0; l < loops.size(); ++l)
      for (std::size_t i = 0; i < loops[l].size(); ++i)
        loop_of[loops[l][i]] = static_cast<int>(l), position[loops[l][i]] = static_cast<int>(i);
    const std::string_view list = classic[static_cast<std::size_t>(m)];
    for (std::size_t t = 0; t + 3 <= list.size(); t += 3) {
      std::array<std::uint8_t, 3> tri;
      for (std::size_t e = 0; e < 3; ++e) tri[e] = static_cast<std::uint8_t>(std::stoi(std::string(1, list[t + e]), nullptr, 16));
      const int l = loop_of[tri[0]];
      if (l < 0 || loop_of[tri[1]] != l || loop_of[tri[2]] != l) throw std::logic_error("classic cube table: a triangle across contours");
      // Three distinct positions are in cyclic order when one rotation of them increases.
      const int a = position[tri[0]], b = position[tri[1]], c = position[tri[2]];
      if (!((a < b && b < c) || (b < c && c < a) || (c < a && a < b))) std::swap(tri[1], tri[2]);
      cc.tri[cc.triangles++] = tri;
    }
    cc.ambiguous_faces = static_cast<std::uint8_t>(ambiguous);
    cases[m] = cc;
  }
  return cases;
}

const std::array<CubeCase, 256> kCubeCases = make_cube_cases();
const std::array<CubeCase, 256> kClassicCases = make_classic_cases();
constexpr std::uint32_t kNone = ~std::uint32_t{0};

// The options as run_chunk uses them.
struct Params {
  double threshold;  // a voxel is above when its value is >= threshold
  double margin;     // MarchingCubesOptions::edge_margin
  const CubeCase* table;
  const std::uint8_t* mask;
  bool values;
};

struct Chunk {
  std::int64_t k0 = 0, k1 = 0;  // cube layers [k0, k1)
  std::vector<std::array<float, 3>> positions, normals;
  std::vector<float> values;  // per local vertex, when Params::values
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<std::uint32_t> top_index;  // per local vertex: plane-k1 map index, or kNone
  // Plane k0's vertices as (map index, local vertex), sorted: the slab below looks its top-plane
  // vertices up here (thousands on the bunny's planes, against a dense copy of the plane's map per
  // slab: 2 MB of fresh pages each).
  std::vector<std::pair<std::uint32_t, std::uint32_t>> bottom;
  std::vector<std::uint32_t> global;  // local → global vertex
  std::size_t owned = 0, cubes_cut = 0, ambiguous = 0;

  std::uint32_t bottom_vertex(std::uint32_t map_index) const {
    auto it = std::lower_bound(bottom.begin(), bottom.end(), std::pair{map_index, std::uint32_t{0}});
    return it != bottom.end() && it->first == map_index ? it->second : kNone;
  }
};

// The maps a slab works with, kept per thread and reused by its next slab: fresh ones for each of
// the 16 slabs put page faults and page clearing at a fifth of a profile of the bunny. Every slot
// is kNone between slabs.
struct Scratch {
  std::vector<std::uint32_t> lower, upper, zmap;  // vertex ids of the lower/upper plane's x and y edges, the z edges between
  std::vector<std::uint8_t> above_lo, above_hi, rows_lo, rows_hi, columns;
  std::vector<std::uint32_t*> written_z, written_lower, written_upper;  // the slots in use, reset one by one
};

// A voxel is above when its value v >= threshold. In its own type T that is v >= the smallest T
// at or above threshold (integers: the ceiling; float: threshold rounded up to a float), the same
// answer for every v, and a comparison the compiler vectorises. *none: no T reaches it.
template <class T>
T threshold_in(double threshold, bool* none) {
  *none = false;
  if constexpr (std::is_integral_v<T>) {
    const double c = std::ceil(threshold);
    if (!(c <= static_cast<double>(std::numeric_limits<T>::max()))) return *none = true, T{};
    return c <= static_cast<double>(std::numeric_limits<T>::lowest()) ? std::numeric_limits<T>::lowest() : static_cast<T>(c);
  } else if constexpr (std::is_same_v<T, float>) {
    float t = static_cast<float>(threshold);
    if (static_cast<double>(t) < threshold) t = std::nextafter(t, std::numeric_limits<float>::infinity());
    return t;
  } else {
    return threshold;
  }
}

// Plane k's above flags (x fastest), one byte a voxel.
template <class T>
void classify_plane(const T* f, std::int64_t sxy, std::int64_t k, double threshold, std::vector<std::uint8_t>& out) {
  bool none = false;
  const T t = threshold_in<T>(threshold, &none);
  if (none) {
    std::fill(out.begin(), out.end(), std::uint8_t{0});
    return;
  }
  const T* row = f + sxy * k;
  std::uint8_t* o = out.data();
  for (std::int64_t q = 0; q < sxy; ++q) o[q] = row[q] >= t;
}

// Cube layers [ch.k0, ch.k1). The planes k0 and k1 come classified (first, last): the slab below
// and the slab above use the same flags, so they agree on every cut edge of the plane they share
// even when the values change meanwhile.
template <class T>
void run_chunk(const Volume& v, const T* f, double iso, const Params& prm, Chunk& ch, bool last, const std::vector<std::uint8_t>& first,
               const std::vector<std::uint8_t>& last_plane, Scratch& sc) {
  const std::int64_t nx = v.dims[0], ny = v.dims[1], nz = v.dims[2];
  const std::int64_t sxy = nx * ny;
  const std::size_t plane_x = static_cast<std::size_t>((nx - 1) * ny), plane_y = static_cast<std::size_t>(nx * (ny - 1));
  if (sc.lower.size() != plane_x + plane_y) {  // this thread's first slab
    sc.lower.assign(plane_x + plane_y, kNone);
    sc.upper.assign(plane_x + plane_y, kNone);
    sc.zmap.assign(static_cast<std::size_t>(sxy), kNone);
    sc.above_lo.resize(static_cast<std::size_t>(sxy));
    sc.above_hi.resize(static_cast<std::size_t>(sxy));
    sc.rows_lo.resize(static_cast<std::size_t>(ny));
    sc.rows_hi.resize(static_cast<std::size_t>(ny));
    sc.columns.resize(static_cast<std::size_t>(nx));
  }
  auto& lower = sc.lower;
  auto& upper = sc.upper;
  auto& zmap = sc.zmap;
  auto& above_lo = sc.above_lo;
  auto& above_hi = sc.above_hi;
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
    bool a_below = va < prm.threshold;
    double t = a_below ? (iso - va) / (vb - va) : (iso - vb) / (va - vb);
    t = std::clamp(t, prm.margin, 1 - prm.margin);
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
    if (prm.values) ch.values.push_back(0.0f);
    return static_cast<std::uint32_t>(ch.positions.size() - 1);
  };
  // Per plane row: 0 all below, 1 all above, 2 mixed. A row of cubes whose four corner rows are
  // uniform and equal holds no surface and is skipped without looking at its cubes.
  auto& rows_lo = sc.rows_lo;
  auto& rows_hi = sc.rows_hi;
  auto row_states = [&](const std::vector<std::uint8_t>& above, std::vector<std::uint8_t>& rows) {
    for (std::int64_t j = 0; j < ny; ++j) {
      const std::uint8_t* r = above.data() + j * nx;
      // Flags are 0 or 1: the row is mixed when the other flag occurs in it.
      rows[static_cast<std::size_t>(j)] = nx > 1 && std::memchr(r + 1, r[0] ^ 1, static_cast<std::size_t>(nx - 1)) ? 2 : r[0];
    }
  };
  // Map slots are reset individually after use (clearing whole planes per layer costs more).
  auto& written_z = sc.written_z;
  auto& written_lower = sc.written_lower;
  auto& written_upper = sc.written_upper;
  above_lo = first;
  row_states(above_lo, rows_lo);
  for (std::int64_t k = ch.k0; k < ch.k1; ++k) {
    if (k + 1 == ch.k1)
      above_hi = last_plane;
    else
      classify_plane(f, sxy, k + 1, prm.threshold, above_hi);
    row_states(above_hi, rows_hi);
    for (auto* w : written_z) *w = kNone;
    written_z.clear();
    const bool top_is_foreign = !last && k + 1 == ch.k1;
    for (std::int64_t j = 0; j + 1 < ny; ++j) {
      const std::uint8_t s0 = rows_lo[j];
      if (s0 != 2 && rows_lo[j + 1] == s0 && rows_hi[j] == s0 && rows_hi[j + 1] == s0) continue;
      // Each column of four corners (y, z) once as bits 0, 2, 4, 6; cube i's code is column i
      // plus column i+1 shifted to the odd bits (corner c = x + 2y + 4z).
      const std::uint8_t *l0 = above_lo.data() + nx * j, *h0 = above_hi.data() + nx * j;
      std::uint8_t* col = sc.columns.data();
      for (std::int64_t i = 0; i < nx; ++i)
        col[i] = static_cast<std::uint8_t>(l0[i] | (l0[nx + i] << 2) | (h0[i] << 4) | (h0[nx + i] << 6));
      for (std::int64_t i = 0; i + 1 < nx; ++i) {
        if (i + 9 <= nx) {  // eight cubes all below or all above: skipped in one test
          std::uint64_t a, b;
          std::memcpy(&a, col + i, 8);
          std::memcpy(&b, col + i + 1, 8);
          if ((a | b) == 0 || (a & b) == 0x5555555555555555u) {
            i += 7;
            continue;
          }
        }
        const int code = col[i] | (col[i + 1] << 1);
        if (code == 0 || code == 255) continue;
        if (prm.mask && !prm.mask[static_cast<std::size_t>((i + 1) + nx * (j + 1) + sxy * (k + 1))]) continue;
        const CubeCase& cc = prm.table[code];
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
        if (prm.values) {
          double lo_v = value(i, j, k), hi_v = lo_v;
          for (int c = 1; c < 8; ++c) {
            const double x = value(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2));
            lo_v = std::min(lo_v, x), hi_v = std::max(hi_v, x);
          }
          const float range = static_cast<float>(hi_v - lo_v);
          for (int e = 0; e < 12; ++e)
            if (needed >> e & 1) ch.values[ids[e]] = std::max(ch.values[ids[e]], range);
        }
      }
    }
    if (k == ch.k0) {
      for (auto* w : written_lower) ch.bottom.emplace_back(static_cast<std::uint32_t>(w - lower.data()), *w);
      std::sort(ch.bottom.begin(), ch.bottom.end());
    }
    // The old lower plane's buffer becomes the new upper one: reset the slots it used.
    for (auto* w : written_lower) *w = kNone;
    written_lower.swap(written_upper);
    written_upper.clear();
    lower.swap(upper);
    above_lo.swap(above_hi);
    rows_lo.swap(rows_hi);
  }
  // Leave every slot kNone for this thread's next slab.
  for (auto* w : written_z) *w = kNone;
  for (auto* w : written_lower) *w = kNone;
  written_z.clear();
  written_lower.clear();
}

}  // namespace

Mesh marching_cubes(const Volume& v, double iso, MarchingCubesStats* stats) {
  return marching_cubes(v, iso, MarchingCubesOptions{}, stats);
}

Mesh marching_cubes(const Volume& v, double iso, const MarchingCubesOptions& options, MarchingCubesStats* stats) {
  static_assert(MarchingCubesOptions{}.edge_margin == kEdgeMargin, "the header's default is the extraction's margin");
  if (!std::isfinite(iso)) throw InputError("the iso-value must be a finite number");
  if (!(options.edge_margin >= 0 && options.edge_margin < 0.5))
    throw std::invalid_argument("marching_cubes: edge_margin must be in [0, 0.5)");
  // For any double x, x > iso exactly when x >= the next double after iso, and every voxel type
  // converts to double exactly: one comparison serves both conventions.
  const Params params{options.strictly_above ? std::nextafter(iso, std::numeric_limits<double>::infinity()) : iso, options.edge_margin,
                      options.classic_table ? kClassicCases.data() : kCubeCases.data(), options.mask, options.values != nullptr};
  if (options.values) options.values->clear();
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
  // The planes between slabs, classified once for the slabs on both sides.
  const std::int64_t sxy = v.dims[0] * v.dims[1];
  std::vector<std::vector<std::uint8_t>> shared(chunks.size() + 1, std::vector<std::uint8_t>(static_cast<std::size_t>(sxy)));
  visit_values(v, [&](auto span) {
    tbb::parallel_for(std::size_t{0}, shared.size(), [&](std::size_t c) {
      classify_plane(span.data(), sxy, c < chunks.size() ? chunks[c].k0 : layers, params.threshold, shared[c]);
    });
    tbb::enumerable_thread_specific<Scratch> scratch;
    tbb::parallel_for(std::size_t{0}, chunks.size(), [&](std::size_t c) {
      run_chunk(v, span.data(), iso, params, chunks[c], c + 1 == chunks.size(), shared[c], shared[c + 1], scratch.local());
    });
  });
  shared.clear();
  // Vertices on a slab's top plane belong to the next slab, which made them for its bottom plane,
  // unless it did not (a mask left its cubes there out): then they stay this slab's.
  std::size_t total = 0;
  for (std::size_t c = 0; c < chunks.size(); ++c) {
    auto& ch = chunks[c];
    ch.owned = 0;
    for (auto& t : ch.top_index) {
      if (t != kNone && chunks[c + 1].bottom_vertex(t) == kNone) t = kNone;
      ch.owned += t == kNone;
    }
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
  if (options.values) options.values->assign(total, 0.0f);
  std::vector<std::size_t> tri_offset(chunks.size() + 1, 0);
  for (std::size_t c = 0; c < chunks.size(); ++c) tri_offset[c + 1] = tri_offset[c] + chunks[c].triangles.size();
  mesh.triangles.resize(tri_offset.back());
  tbb::parallel_for(std::size_t{0}, chunks.size(), [&](std::size_t c) {
    auto& ch = chunks[c];
    for (std::size_t l = 0; l < ch.positions.size(); ++l) {
      if (ch.top_index[l] != kNone) {
        ch.global[l] = chunks[c + 1].global[chunks[c + 1].bottom_vertex(ch.top_index[l])];
      } else {
        mesh.positions[ch.global[l]] = ch.positions[l];
        mesh.normals[ch.global[l]] = ch.normals[l];
        if (options.values) (*options.values)[ch.global[l]] = ch.values[l];
      }
    }
  });
  // A shared vertex's value is the largest of both slabs' cubes: slab c updates only slab c+1's
  // vertices, so the slabs do not write the same entries.
  if (options.values)
    tbb::parallel_for(std::size_t{0}, chunks.size(), [&](std::size_t c) {
      auto& ch = chunks[c];
      for (std::size_t l = 0; l < ch.positions.size(); ++l)
        if (ch.top_index[l] != kNone) (*options.values)[ch.global[l]] = std::max((*options.values)[ch.global[l]], ch.values[l]);
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
