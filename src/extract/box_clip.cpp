// Surfaces clipped to the volume's box (see box_clip.hpp).
#include "extract/box_clip.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <unordered_map>

namespace adaptiso::detail {
namespace {

// The faces to clip at: axis a's last index, or none (+∞) where the lattice is not padded.
struct Faces {
  std::array<double, 3> last;
  double slack = 0;  // voxels: a few float roundings of a world position, in index units
  bool outside(const Vec3& u) const {
    for (int a = 0; a < 3; ++a)
      if (u[a] > last[a] + slack) return true;
    return false;
  }
};

// A cut point: the plane's axis and the edge's ends, the smaller id first.
struct CutKey {
  std::uint32_t lo, hi;
  int axis;
  bool operator==(const CutKey&) const = default;
};
struct CutKeyHash {
  std::size_t operator()(const CutKey& k) const {
    return std::hash<std::uint64_t>()((std::uint64_t{k.lo} << 32 | k.hi) * 3 + static_cast<std::uint64_t>(k.axis));
  }
};

// In place: each entry becomes the sum of those before it (the last, a sentinel, the total).
std::uint32_t exclusive_scan(std::vector<std::uint32_t>& counts) {
  std::uint32_t sum = 0;
  for (auto& c : counts) {
    const std::uint32_t n = c;
    c = sum;
    sum += n;
  }
  return counts.back();
}

class Clipper {
public:
  Clipper(const Mesh& in, const GridSource& s) : in_(in) {
    geometry_.dims = s.dims;
    geometry_.spacing = s.spacing;
    geometry_.origin = s.origin;
    geometry_.direction = s.direction;
    const Dims box = s.volume_box();
    for (int a = 0; a < 3; ++a)
      faces_.last[a] = box[a] < s.dims[a] ? static_cast<double>(box[a] - 1) : std::numeric_limits<double>::infinity();
    // Positions are floats: a vertex on a face plane comes back from its world position off it by
    // up to half a float step of the largest coordinate, over the smallest spacing. Four steps: far
    // below the march's margin (1/1024 of an edge), which keeps other vertices off the planes.
    double largest = 0;
    for (int corner = 0; corner < 8; ++corner) {
      const Vec3 w =
          geometry_.voxel_to_world(corner & 1 ? s.dims[0] - 1 : 0, corner & 2 ? s.dims[1] - 1 : 0, corner & 4 ? s.dims[2] - 1 : 0);
      for (double c : w) largest = std::max(largest, std::abs(c));
    }
    const double spacing = std::min({std::abs(s.spacing[0]), std::abs(s.spacing[1]), std::abs(s.spacing[2])});
    faces_.slack = 4 * std::numeric_limits<float>::epsilon() * (largest + 1) / spacing;
    // The direction's inverse, once (world_to_voxel computes it on every call): column a is the
    // index coordinates of the world's unit vector a, scaled back by the spacing.
    for (int a = 0; a < 3; ++a) {
      Vec3 w = geometry_.origin;
      w[a] += 1;
      const Vec3 g = geometry_.world_to_voxel(w);
      for (int k = 0; k < 3; ++k) inverse_[3 * k + a] = g[k] * geometry_.spacing[k];
    }
  }

  // Which vertices lie past the box; false when none does. (Their index coordinates are made
  // again where a cut needs them: a few triangles, where an array of them all would be fresh
  // memory on every extraction.)
  bool locate() {
    const std::size_t V = in_.vertex_count();
    outside_.resize(V);
    std::atomic<bool> any{false};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, V, 16384), [&](const auto& r) {
      bool mine = false;
      for (std::size_t v = r.begin(); v < r.end(); ++v) {
        outside_[v] = faces_.outside(index_of(in_.positions[v]));
        mine = mine || outside_[v];
      }
      if (mine) any.store(true, std::memory_order_relaxed);
    });
    return any.load();
  }

  // Which triangles stay whole, which go and which are cut (into `pieces_`), and which vertices
  // are still used: everything the output's arrays are made from, read from the input alone.
  void plan() {
    const std::size_t V = in_.vertex_count(), T = in_.triangle_count();
    // Per triangle: kept whole (1), dropped (0) or cut (its pieces, one thread below: they are few).
    first_.assign(T + 1, 0);
    crosses_.assign(T, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T, 16384), [&](const auto& r) {
      for (std::size_t t = r.begin(); t < r.end(); ++t) {
        const auto& tri = in_.triangles[t];
        if (outside_[tri[0]] | outside_[tri[1]] | outside_[tri[2]])
          crosses_[t] = 1;
        else
          first_[t] = 1;
      }
    });
    for (std::size_t t = 0; t < T; ++t)
      if (crosses_[t]) first_[t] = cut(in_.triangles[t], V, pieces_);  // ids ≥ V are cut points
    triangles_ = exclusive_scan(first_);                               // first_[t]: the pieces before t
    // The vertices still used, in their order, then the cut points in theirs.
    const std::size_t N = V + cut_u_.size();
    std::vector<std::uint8_t> used(N, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T, 16384), [&](const auto& r) {
      for (std::size_t t = r.begin(); t < r.end(); ++t)
        if (!crosses_[t])
          for (std::uint32_t v : in_.triangles[t]) std::atomic_ref<std::uint8_t>(used[v]).store(1, std::memory_order_relaxed);
    });
    for (const auto& p : pieces_)
      for (std::uint32_t v : p) used[v] = 1;
    id_.resize(N + 1);
    for (std::size_t v = 0; v < N; ++v) id_[v] = used[v];
    vertices_ = exclusive_scan(id_);  // id_[v]: v's place when used
    for (std::size_t v = 0; v < N; ++v)
      if (!used[v]) id_[v] = kUnused;
  }

  // The planned mesh written into `out` (and `map`).
  void write(Mesh& out, ClipMap* map) {
    const std::size_t V = in_.vertex_count(), T = in_.triangle_count(), N = V + cut_u_.size();
    const bool normals = in_.normals.size() == V;
    out.positions.resize(vertices_);
    out.normals.resize(normals ? vertices_ : 0);
    out.triangles.resize(triangles_);
    std::vector<std::uint32_t> from(map ? vertices_ : 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, N, 16384), [&](const auto& r) {
      for (std::size_t v = r.begin(); v < r.end(); ++v) {
        const std::uint32_t i = id_[v];
        if (i == kUnused) continue;
        if (v < V) {
          out.positions[i] = in_.positions[v];
          if (normals) out.normals[i] = in_.normals[v];
        } else {
          place_cut_point(out, i, v - V, normals);
        }
        if (map) from[i] = v < V ? static_cast<std::uint32_t>(v) : ClipMap::kNew;
      }
    });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T, 16384), [&](const auto& r) {
      for (std::size_t t = r.begin(); t < r.end(); ++t)
        if (!crosses_[t]) {
          const auto& tri = in_.triangles[t];
          out.triangles[first_[t]] = {id_[tri[0]], id_[tri[1]], id_[tri[2]]};
        }
    });
    write_pieces(out);
    if (map) {
      map->first = std::move(first_);
      map->vertex_from = std::move(from);
    }
  }

  // The same into the input mesh itself, when every triangle's pieces land at or before its own
  // place (first_[t] ≤ t: a triangle cut into several has as many dropped before it), so that
  // one pass in order never overwrites what it has still to read; false, untouched, otherwise.
  // The copy's arrays were fresh memory: 0.27 s of a single thread's clip of the 512×512×120 MR
  // head's 7.3 M triangles at 0.5 voxels, most of it the kernel zeroing their pages.
  bool write_in_place(Mesh& mesh) {
    const std::size_t V = in_.vertex_count(), T = in_.triangle_count();
    for (std::size_t t = 0; t <= T; ++t)
      if (first_[t] > t) return false;
    const bool normals = in_.normals.size() == V;
    for (std::size_t v = 0; v < V; ++v) {  // id_[v] ≤ v: in order, nothing unread is overwritten
      const std::uint32_t i = id_[v];
      if (i == kUnused) continue;
      mesh.positions[i] = mesh.positions[v];
      if (normals) mesh.normals[i] = mesh.normals[v];
    }
    mesh.positions.resize(vertices_);
    mesh.normals.resize(normals ? vertices_ : 0);  // as the copy: none unless one per vertex
    for (std::size_t c = 0; c < cut_u_.size(); ++c)
      if (id_[V + c] != kUnused) place_cut_point(mesh, id_[V + c], c, normals);
    for (std::size_t t = 0; t < T; ++t)
      if (!crosses_[t]) {
        const auto tri = mesh.triangles[t];
        mesh.triangles[first_[t]] = {id_[tri[0]], id_[tri[1]], id_[tri[2]]};
      }
    write_pieces(mesh);
    mesh.triangles.resize(triangles_);
    return true;
  }

private:
  static constexpr std::uint32_t kUnused = ~std::uint32_t{0};

  // Cut point c (index coordinates) placed at out's vertex i, in the world.
  void place_cut_point(Mesh& out, std::uint32_t i, std::size_t c, bool normals) const {
    const Vec3& u = cut_u_[c];
    const Vec3 w = geometry_.voxel_to_world(u[0], u[1], u[2]);
    out.positions[i] = {static_cast<float>(w[0]), static_cast<float>(w[1]), static_cast<float>(w[2])};
    if (normals) out.normals[i] = cut_n_[c];
  }
  // The cut triangles' pieces at their places.
  void write_pieces(Mesh& out) const {
    std::size_t piece = 0;
    for (std::size_t t = 0; t < crosses_.size(); ++t)
      if (crosses_[t])
        for (std::uint32_t k = first_[t]; k < first_[t + 1]; ++k, ++piece) {
          const auto& p = pieces_[piece];
          out.triangles[k] = {id_[p[0]], id_[p[1]], id_[p[2]]};
        }
  }

  Vec3 index_of(const std::array<float, 3>& p) const {
    const auto& o = geometry_.origin;
    const double w[3] = {p[0] - o[0], p[1] - o[1], p[2] - o[2]};
    Vec3 u;
    for (int a = 0; a < 3; ++a)
      u[a] = (inverse_[3 * a] * w[0] + inverse_[3 * a + 1] * w[1] + inverse_[3 * a + 2] * w[2]) / geometry_.spacing[a];
    return u;
  }
  Vec3 at(std::uint32_t v) const { return v < outside_.size() ? index_of(in_.positions[v]) : cut_u_[v - outside_.size()]; }

  // The cut point of edge (p, q) with axis a's face plane, made once.
  std::uint32_t cut_point(std::uint32_t p, std::uint32_t q, int a, std::size_t V) {
    const CutKey key{std::min(p, q), std::max(p, q), a};
    const auto [it, fresh] = cuts_.try_emplace(key, static_cast<std::uint32_t>(V + cut_u_.size()));
    if (!fresh) return it->second;
    const Vec3 lo = at(key.lo), hi = at(key.hi);
    const double t = std::clamp((faces_.last[a] - lo[a]) / (hi[a] - lo[a]), 0.0, 1.0);
    Vec3 u;
    for (int k = 0; k < 3; ++k) u[k] = lo[k] + t * (hi[k] - lo[k]);
    u[a] = faces_.last[a];
    cut_u_.push_back(u);
    std::array<float, 3> n{0, 0, 0};
    if (!in_.normals.empty()) {
      const auto &nl = normal(key.lo), &nh = normal(key.hi);
      double m[3], len = 0;
      for (int k = 0; k < 3; ++k) {
        m[k] = (1 - t) * nl[k] + t * nh[k];
        len += m[k] * m[k];
      }
      len = std::sqrt(len);
      for (int k = 0; k < 3; ++k) n[k] = len > 0 ? static_cast<float>(m[k] / len) : nl[k];
    }
    cut_n_.push_back(n);
    return it->second;
  }
  const std::array<float, 3>& normal(std::uint32_t v) const {
    return v < in_.normals.size() ? in_.normals[v] : cut_n_[v - in_.normals.size()];
  }

  // The triangle cut by the face planes (Sutherland–Hodgman) and fanned; returns its pieces.
  std::uint32_t cut(const std::array<std::uint32_t, 3>& tri, std::size_t V, std::vector<std::array<std::uint32_t, 3>>& pieces) {
    std::vector<std::uint32_t>& poly = poly_;
    std::vector<std::uint32_t>& next = next_;
    poly.assign(tri.begin(), tri.end());
    for (int a = 0; a < 3 && poly.size() >= 3; ++a) {
      if (!std::isfinite(faces_.last[a])) continue;
      const double limit = faces_.last[a] + faces_.slack;
      next.clear();
      for (std::size_t i = 0; i < poly.size(); ++i) {
        const std::uint32_t p = poly[i], q = poly[(i + 1) % poly.size()];
        const bool p_in = at(p)[a] <= limit, q_in = at(q)[a] <= limit;
        if (p_in) next.push_back(p);
        if (p_in != q_in) next.push_back(cut_point(p, q, a, V));
      }
      poly.swap(next);
      // A piece with no point off this face plane has no area: a triangle of the padding touching it.
      if (std::all_of(poly.begin(), poly.end(), [&](std::uint32_t v) { return at(v)[a] >= faces_.last[a] - faces_.slack; })) poly.clear();
    }
    if (poly.size() < 3) return 0;
    for (std::size_t i = 1; i + 1 < poly.size(); ++i) pieces.push_back({poly[0], poly[i], poly[i + 1]});
    return static_cast<std::uint32_t>(poly.size() - 2);
  }

  const Mesh& in_;
  Volume geometry_;  // the grid frame alone: no samples
  Faces faces_{};
  std::array<double, 9> inverse_{};  // the direction's inverse, row-major
  std::vector<std::uint8_t> outside_;
  std::vector<Vec3> cut_u_;
  std::vector<std::array<float, 3>> cut_n_;
  std::unordered_map<CutKey, std::uint32_t, CutKeyHash> cuts_;
  std::vector<std::uint32_t> poly_, next_;
  // plan()'s: per triangle its first output triangle (and the total after), whether it is cut;
  // the cut ones' pieces in triangle order; per vertex (then cut point) its output place.
  std::vector<std::uint32_t> first_, id_;
  std::vector<std::uint8_t> crosses_;
  std::vector<std::array<std::uint32_t, 3>> pieces_;
  std::uint32_t triangles_ = 0, vertices_ = 0;
};

}  // namespace

bool clip_to_volume_box(const Mesh& in, const GridSource& source, Mesh& out, ClipMap* map) {
  if (!source.padded()) return false;
  Clipper c(in, source);
  if (!c.locate()) return false;
  c.plan();
  c.write(out, map);
  return true;
}

Clipped clip_to_volume_box(Mesh& mesh, const GridSource& source) {
  if (!source.padded()) return Clipped::nothing;
  Clipper c(mesh, source);
  if (!c.locate()) return Clipped::nothing;
  c.plan();
  if (c.write_in_place(mesh)) return Clipped::in_place;
  Mesh out;
  c.write(out, nullptr);
  mesh = std::move(out);
  return Clipped::copied;
}

void carry_vertex_keys(const ClipMap& map, const std::vector<std::uint64_t>& keys, std::uint64_t cut, std::vector<std::uint64_t>& out) {
  out.resize(map.vertex_from.size());
  for (std::size_t v = 0; v < out.size(); ++v) out[v] = map.vertex_from[v] == ClipMap::kNew ? cut : keys[map.vertex_from[v]];
}

}  // namespace adaptiso::detail
