// Reconstruction analysis — Lürig & Ertl §2.1, "reconstruction analysis" (Tables 1–3).
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.1, "reconstruction analysis" (Tables 1–3).
//
// The octree is implicit: a cube at level l (edge L = 2^l voxels) with index c spans voxels
// [c·L, c·L + L] on each axis, clipped to the volume. Cubes are processed depth first; a cube
// merges when its 8 children merged and every voxel of its (clipped) box is reproduced within the
// bound by trilinear interpolation from the box corners. The paper propagates error increments to
// the sub-cubes and reverts them on failure; because trilinear interpolation is linear in the
// corner values, the sum of those increments at a voxel is exactly value − reconstruction, which
// we evaluate directly. That needs no per-voxel error field (4 bytes/voxel saved) and no revert
// pass, and a cube whose value range (min/max, propagated up from its children) is within the
// bound is accepted without touching its voxels.
// Per-vertex counters are evaluated lazily when the kept set is built: a midpoint vertex is
// dropped when all cubes of its birth level that hold it merged.
#include <tbb/concurrent_vector.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <fmt/format.h>
#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <limits>
#include <optional>

#include "adaptiso/reduce.hpp"
#include "util/progress_counter.hpp"

namespace adaptiso {
namespace {

struct CubeResult {
  bool merged;
  double mn, mx;
};

template <class T>
class Octree {
public:
  Octree(const Volume& vol, std::span<const T> vals, double bound, OctreeMerges& om, const Progress& progress)
      : v_(vals.data()), d_(vol.dims), bound_(bound), om_(om), progress_(progress) {
    std::int64_t ext = std::max({d_[0], d_[1], d_[2]}) - 1;
    int m = 1;
    while ((std::int64_t{1} << m) < ext) ++m;
    om.levels = m;
    om.size = std::int64_t{1} << m;
    om.dims = d_;
    om.counts.resize(static_cast<std::size_t>(m));
    om.merged.resize(static_cast<std::size_t>(m));
    for (int l = 1; l <= m; ++l) {
      Dims n{};
      // Cubes meeting the volume, within the extended cube [0, S]³ (none starts at S).
      for (int a = 0; a < 3; ++a) n[a] = std::min((d_[a] - 1) / (std::int64_t{1} << l) + 1, (std::int64_t{1} << m) >> l);
      om.counts[static_cast<std::size_t>(l - 1)] = n;
      om.merged[static_cast<std::size_t>(l - 1)].assign(static_cast<std::size_t>(n[0] * n[1] * n[2]), 0);
    }
    done_.emplace(progress_, "reduce: reconstruction", static_cast<std::uint64_t>(om.counts[0][0] * om.counts[0][1] * om.counts[0][2]));
  }

  void run() {
    CubeResult r = process(om_.levels, 0, 0, 0);
    if (r.merged) add_clipped_corners(om_.levels, 0, 0, 0);
  }

  tbb::concurrent_vector<std::int64_t> forced;  // clipped corners of leaves crossing the border

private:
  const T* v_;
  Dims d_;
  double bound_;
  OctreeMerges& om_;
  const Progress& progress_;
  std::optional<detail::ProgressCounter> done_;  // atomic cubes, made once their count is known

  // Every voxel of the box [lo, hi] against trilinear interpolation from the box corners; row(y, z)
  // points at the box's first voxel of that row (the volume, or a block copied out of it).
  template <class Row>
  bool test_rows(const std::int64_t lo[3], const std::int64_t hi[3], Row row) const {
    double c[8];
    for (int i = 0; i < 8; ++i) c[i] = static_cast<double>(row(i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2])[i & 1 ? hi[0] - lo[0] : 0]);
    const double wx = static_cast<double>(hi[0] - lo[0]), wy = static_cast<double>(hi[1] - lo[1]), wz = static_cast<double>(hi[2] - lo[2]);
    for (std::int64_t z = lo[2]; z <= hi[2]; ++z) {
      const double tz = wz > 0 ? static_cast<double>(z - lo[2]) / wz : 0.0;
      for (std::int64_t y = lo[1]; y <= hi[1]; ++y) {
        const double ty = wy > 0 ? static_cast<double>(y - lo[1]) / wy : 0.0;
        const double a0 = c[0] + (c[2] - c[0]) * ty, a1 = c[4] + (c[6] - c[4]) * ty;
        const double b0 = c[1] + (c[3] - c[1]) * ty, b1 = c[5] + (c[7] - c[5]) * ty;
        const double a = a0 + (a1 - a0) * tz, b = b0 + (b1 - b0) * tz;
        const double slope = wx > 0 ? (b - a) / wx : 0.0;
        const auto* r = row(y, z);
        for (std::int64_t x = 0; x <= hi[0] - lo[0]; ++x)
          if (std::abs(static_cast<double>(r[x]) - (a + slope * static_cast<double>(x))) > bound_) return false;
      }
    }
    return true;
  }

  // Rows of the box starting at lo, read straight from the volume.
  auto volume_rows(const std::int64_t lo[3]) const {
    return [this, lo](std::int64_t y, std::int64_t z) { return v_ + lo[0] + d_[0] * (y + d_[1] * z); };
  }

  bool test(const std::int64_t lo[3], const std::int64_t hi[3]) const { return test_rows(lo, hi, volume_rows(lo)); }

  // An atomic cube: merged when its value range, or else trilinear interpolation from its corners,
  // stays within the bound. row(y, z) as in test_rows.
  template <class Row>
  CubeResult atomic_cube(std::int64_t cx, std::int64_t cy, std::int64_t cz, const std::int64_t lo[3], const std::int64_t hi[3], Row row) {
    double mn = std::numeric_limits<double>::infinity(), mx = -mn;
    for (std::int64_t z = lo[2]; z <= hi[2]; ++z)
      for (std::int64_t y = lo[1]; y <= hi[1]; ++y) {
        const auto* r = row(y, z);
        for (std::int64_t x = 0; x <= hi[0] - lo[0]; ++x) {
          const double s = static_cast<double>(r[x]);
          mn = std::min(mn, s);
          mx = std::max(mx, s);
        }
      }
    const bool ok = mx - mn <= bound_ || test_rows(lo, hi, row);
    if (ok) set_merged(1, cx, cy, cz);
    return {ok, mn, mx};
  }

  // The 8 atomic children of level-2 cube (cx, cy, cz) from one copy of its (at most 5³) voxels:
  // each voxel is read and converted once instead of once per atomic cube holding it (~1.7×).
  void atomic_children(std::int64_t cx, std::int64_t cy, std::int64_t cz, CubeResult ch[8], bool exists[8]) {
    std::int64_t lo[3], hi[3];
    box(2, cx, cy, cz, lo, hi);
    double blk[5][5][5];
    for (std::int64_t z = lo[2]; z <= hi[2]; ++z)
      for (std::int64_t y = lo[1]; y <= hi[1]; ++y) {
        const T* r = v_ + d_[0] * (y + d_[1] * z);
        for (std::int64_t x = lo[0]; x <= hi[0]; ++x) blk[z - lo[2]][y - lo[1]][x - lo[0]] = static_cast<double>(r[x]);
      }
    for (int i = 0; i < 8; ++i) {
      const std::int64_t c[3] = {2 * cx + (i & 1), 2 * cy + ((i >> 1) & 1), 2 * cz + ((i >> 2) & 1)};
      exists[i] = inside(1, c[0], c[1], c[2]);
      if (!exists[i]) {
        ch[i] = CubeResult{true, std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
        continue;
      }
      std::int64_t a[3], b[3];  // the child's box in block coordinates
      for (int k = 0; k < 3; ++k) {
        a[k] = 2 * (c[k] & 1);
        b[k] = std::min(a[k] + 2, hi[k] - lo[k]);
      }
      ch[i] = atomic_cube(c[0], c[1], c[2], a, b, [&](std::int64_t y, std::int64_t z) { return &blk[z][y][a[0]]; });
    }
  }

  void set_merged(int l, std::int64_t cx, std::int64_t cy, std::int64_t cz) {
    const Dims& n = om_.counts[static_cast<std::size_t>(l - 1)];
    om_.merged[static_cast<std::size_t>(l - 1)][static_cast<std::size_t>(cx + n[0] * (cy + n[1] * cz))] = 1;
  }

  bool inside(int l, std::int64_t cx, std::int64_t cy, std::int64_t cz) const {
    const Dims& n = om_.counts[static_cast<std::size_t>(l - 1)];
    return cx < n[0] && cy < n[1] && cz < n[2];
  }

  void box(int l, std::int64_t cx, std::int64_t cy, std::int64_t cz, std::int64_t lo[3], std::int64_t hi[3]) const {
    const std::int64_t L = std::int64_t{1} << l, c[3] = {cx, cy, cz};
    for (int a = 0; a < 3; ++a) {
      lo[a] = c[a] * L;
      hi[a] = std::min(lo[a] + L, d_[a] - 1);
    }
  }

  // A leaf that crosses the far border interpolates from its clipped corners: keep them.
  void add_clipped_corners(int l, std::int64_t cx, std::int64_t cy, std::int64_t cz) {
    std::int64_t lo[3], hi[3];
    box(l, cx, cy, cz, lo, hi);
    const std::int64_t L = std::int64_t{1} << l;
    if (lo[0] + L == hi[0] && lo[1] + L == hi[1] && lo[2] + L == hi[2]) return;  // lattice corners are kept anyway
    for (int i = 0; i < 8; ++i)
      forced.push_back((i & 1 ? hi[0] : lo[0]) + d_[0] * ((i & 2 ? hi[1] : lo[1]) + d_[1] * (i & 4 ? hi[2] : lo[2])));
  }

  CubeResult process(int l, std::int64_t cx, std::int64_t cy, std::int64_t cz) {
    std::int64_t lo[3], hi[3];
    box(l, cx, cy, cz, lo, hi);
    if (l == 1)  // only when the whole volume is one atomic cube; otherwise see atomic_children
      return atomic_cube(cx, cy, cz, lo, hi, volume_rows(lo));
    CubeResult ch[8];
    bool exists[8];
    auto child = [&](int i) {
      std::int64_t x = 2 * cx + (i & 1), y = 2 * cy + ((i >> 1) & 1), z = 2 * cz + ((i >> 2) & 1);
      exists[i] = inside(l - 1, x, y, z);
      ch[i] = exists[i] ? process(l - 1, x, y, z)
                        : CubeResult{true, std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
    };
    if (l >= 5) {
      tbb::parallel_for(0, 8, child);
    } else if (l == 2) {
      atomic_children(cx, cy, cz, ch, exists);
    } else {
      for (int i = 0; i < 8; ++i) child(i);
    }
    if (l == 5) {
      done_->advance(512);  // atomic cubes per level-5 cube
    }
    bool all = true;
    double mn = std::numeric_limits<double>::infinity(), mx = -mn;
    for (int i = 0; i < 8; ++i) {
      all = all && ch[i].merged;
      mn = std::min(mn, ch[i].mn);
      mx = std::max(mx, ch[i].mx);
    }
    bool ok = all && (mx - mn <= bound_ || test(lo, hi));
    if (ok) {
      set_merged(l, cx, cy, cz);
    } else {
      for (int i = 0; i < 8; ++i)
        if (exists[i] && ch[i].merged) add_clipped_corners(l - 1, 2 * cx + (i & 1), 2 * cy + ((i >> 1) & 1), 2 * cz + ((i >> 2) & 1));
    }
    return {ok, mn, mx};
  }
};

// The paper's counters, evaluated lazily: a vertex that is a midpoint of the level-l cubes holding
// it is dropped only when every one of them merged. Along an axis where the coordinate is an odd
// multiple of L/2 one cube holds it; otherwise the cubes on both sides (only one at a side of the
// extended cube), giving 4/2/1 inside, 2/1/1 on a side and 1/1/1 on an edge.
// tz = number of trailing zero bits of each coordinate (64 for 0), precomputed per axis.
bool dropped(const OctreeMerges& om, const std::int64_t c[3], const int tz[3]) {
  int t = std::min({tz[0], tz[1], tz[2]});
  if (t >= om.levels) return false;  // a corner of the root cube
  const int l = t + 1;
  const std::int64_t L = std::int64_t{1} << l, S = om.size;
  std::int64_t cand[3][2];
  int nc[3];
  for (int a = 0; a < 3; ++a) {
    if (tz[a] == t) {  // an odd multiple of L/2: inside one cube along this axis
      cand[a][0] = c[a] / L;
      nc[a] = 1;
    } else {
      nc[a] = 0;
      if (c[a] / L - 1 >= 0) cand[a][nc[a]++] = c[a] / L - 1;
      if (c[a] / L < S / L) cand[a][nc[a]++] = c[a] / L;
    }
  }
  for (int i = 0; i < nc[0]; ++i)
    for (int j = 0; j < nc[1]; ++j)
      for (int k = 0; k < nc[2]; ++k)
        if (!om.is_merged(l, cand[0][i], cand[1][j], cand[2][k])) return false;
  return true;
}

}  // namespace

std::vector<std::int64_t> reconstruction_analysis(const Volume& vol, double max_error, OctreeMerges* merges, const Progress& progress) {
  return reconstruction_analysis(vol, value_range(vol), max_error, merges, progress);
}

std::vector<std::int64_t> reconstruction_analysis(const Volume& vol, const ValueRange& range, double max_error, OctreeMerges* merges,
                                                  const Progress& progress) {
  if (!(max_error >= 0) || !std::isfinite(max_error))
    throw OptionError("max_error", fmt::format("must be a non-negative number, got {}", max_error));
  OctreeMerges local;
  OctreeMerges& om = merges ? *merges : local;
  om = OctreeMerges{};
  const double bound = max_error + error_tolerance(range, max_error);
  std::vector<std::int64_t> forced;
  visit_values(vol, [&]<class T>(std::span<const T> vals) {
    Octree<T> tree(vol, vals, bound, om, progress);
    tree.run();
    forced.assign(tree.forced.begin(), tree.forced.end());
  });
  // Kept set: every voxel not dropped by its counters (in index order, slice by slice), merged
  // with the forced clipped corners. 7/8 of the voxels have an odd coordinate, so they are
  // midpoints of atomic cubes: for those a row needs only, per atomic cube along x, whether all
  // its cubes across y and z merged (computed once per row); the rest go through dropped().
  const Dims d = vol.dims;
  const std::int64_t plane = d[0] * d[1];
  std::sort(forced.begin(), forced.end());
  forced.erase(std::unique(forced.begin(), forced.end()), forced.end());
  auto ctz = [](std::int64_t c) { return c == 0 ? 64 : std::countr_zero(static_cast<std::uint64_t>(c)); };
  std::vector<int> tzx(static_cast<std::size_t>(d[0]));
  for (std::int64_t x = 0; x < d[0]; ++x) tzx[static_cast<std::size_t>(x)] = ctz(x);
  const std::int64_t half = om.size / 2;  // atomic cubes per axis of the extended cube
  const Dims n1 = om.counts[0];
  // Atomic cubes holding coordinate c along one axis as a level-1 midpoint (see dropped()).
  auto atomic_cubes = [&](std::int64_t c, std::int64_t out[2]) {
    if (c & 1) {
      out[0] = c >> 1;
      return 1;
    }
    int k = 0;
    if (c / 2 - 1 >= 0) out[k++] = c / 2 - 1;
    if (c / 2 < half) out[k++] = c / 2;
    return k;
  };
  std::vector<std::vector<std::int64_t>> per_slice(static_cast<std::size_t>(d[2]));
  tbb::parallel_for(std::int64_t{0}, d[2], [&](std::int64_t z) {
    auto& out = per_slice[static_cast<std::size_t>(z)];
    std::vector<std::uint8_t> row_merged(static_cast<std::size_t>(n1[0]));
    int tz[3] = {0, 0, ctz(z)};
    std::int64_t c[3] = {0, 0, z}, zc[2], yc[2];
    const int nz = atomic_cubes(z, zc);
    const std::uint8_t* m1 = om.merged[0].data();
    for (std::int64_t y = 0; y < d[1]; ++y) {
      tz[1] = ctz(y);
      c[1] = y;
      const int ny = atomic_cubes(y, yc);
      for (std::int64_t cx = 0; cx < n1[0]; ++cx) {
        std::uint8_t all = 1;
        for (int j = 0; j < ny; ++j)
          for (int k = 0; k < nz; ++k) all &= m1[cx + n1[0] * (yc[j] + n1[1] * zc[k])];
        row_merged[static_cast<std::size_t>(cx)] = all;
      }
      const bool yz_odd = ((y | z) & 1) != 0;
      const std::int64_t base = d[0] * (y + d[1] * z);
      for (std::int64_t x = 0; x < d[0]; ++x) {
        bool drop;
        if (x & 1) {
          drop = row_merged[static_cast<std::size_t>(x >> 1)];
        } else if (yz_odd) {
          drop = (x / 2 - 1 < 0 || row_merged[static_cast<std::size_t>(x / 2 - 1)]) &&
                 (x / 2 >= half || row_merged[static_cast<std::size_t>(x / 2)]);
        } else {
          tz[0] = tzx[static_cast<std::size_t>(x)];
          c[0] = x;
          drop = dropped(om, c, tz);
        }
        if (!drop) out.push_back(base + x);
      }
    }
    // This slice's forced corners (few) merged in.
    auto f0 = std::lower_bound(forced.begin(), forced.end(), z * plane);
    auto f1 = std::lower_bound(f0, forced.end(), (z + 1) * plane);
    if (f0 != f1) {
      std::vector<std::int64_t> both;
      both.reserve(out.size() + static_cast<std::size_t>(f1 - f0));
      std::set_union(out.begin(), out.end(), f0, f1, std::back_inserter(both));
      out.swap(both);
    }
  });
  std::vector<std::size_t> offset(per_slice.size() + 1, 0);
  for (std::size_t z = 0; z < per_slice.size(); ++z) offset[z + 1] = offset[z] + per_slice[z].size();
  std::vector<std::int64_t> kept(offset.back());
  tbb::parallel_for(std::size_t{0}, per_slice.size(), [&](std::size_t z) {
    std::copy(per_slice[z].begin(), per_slice[z].end(), kept.begin() + static_cast<std::ptrdiff_t>(offset[z]));
    std::vector<std::int64_t>().swap(per_slice[z]);
  });
  report(progress, "reduce: reconstruction", 1.0);
  return kept;
}

double verify_reconstruction(const Volume& vol, const ReduceResult& r) {
  const OctreeMerges& om = r.octree;
  if (om.levels == 0) throw std::logic_error("verify_reconstruction: the result has no octree (structural method)");
  const Dims d = vol.dims;
  std::vector<std::uint8_t> kept_mask(static_cast<std::size_t>(vol.voxel_count()), 0);
  for (auto i : r.kept) kept_mask[static_cast<std::size_t>(i)] = 1;
  const Dims n1 = om.counts[0];
  std::vector<double> worst(static_cast<std::size_t>(n1[2]), 0.0);
  std::atomic<bool> missing{false};
  // Each atomic cube: find its leaf (the largest merged ancestor), then check the atomic cube's
  // voxels against the leaf's trilinear interpolation. Unmerged atomic cubes keep all their
  // voxels, so they are reproduced exactly and need no check beyond being kept.
  tbb::parallel_for(std::int64_t{0}, n1[2], [&](std::int64_t cz) {
    double w = 0;
    for (std::int64_t cy = 0; cy < n1[1]; ++cy)
      for (std::int64_t cx = 0; cx < n1[0]; ++cx) {
        std::int64_t alo[3] = {2 * cx, 2 * cy, 2 * cz}, ahi[3];
        for (int a = 0; a < 3; ++a) ahi[a] = std::min(alo[a] + 2, d[a] - 1);
        int leaf = 0;
        for (int l = 1; l <= om.levels; ++l)
          if (om.is_merged(l, cx >> (l - 1), cy >> (l - 1), cz >> (l - 1)))
            leaf = l;
          else
            break;
        if (leaf == 0) {
          for (std::int64_t z = alo[2]; z <= ahi[2]; ++z)
            for (std::int64_t y = alo[1]; y <= ahi[1]; ++y)
              for (std::int64_t x = alo[0]; x <= ahi[0]; ++x)
                if (!kept_mask[static_cast<std::size_t>(vol.index(x, y, z))]) missing = true;
          continue;
        }
        const std::int64_t L = std::int64_t{1} << leaf;
        std::int64_t lo[3] = {(cx >> (leaf - 1)) * L, (cy >> (leaf - 1)) * L, (cz >> (leaf - 1)) * L}, hi[3];
        for (int a = 0; a < 3; ++a) hi[a] = std::min(lo[a] + L, d[a] - 1);
        double c[8];
        for (int i = 0; i < 8; ++i) {
          std::int64_t idx = vol.index(i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2]);
          if (!kept_mask[static_cast<std::size_t>(idx)]) missing = true;
          c[i] = vol.at(idx);
        }
        for (std::int64_t z = alo[2]; z <= ahi[2]; ++z)
          for (std::int64_t y = alo[1]; y <= ahi[1]; ++y)
            for (std::int64_t x = alo[0]; x <= ahi[0]; ++x) {
              double t[3];
              const std::int64_t p[3] = {x, y, z};
              for (int a = 0; a < 3; ++a)
                t[a] = hi[a] > lo[a] ? static_cast<double>(p[a] - lo[a]) / static_cast<double>(hi[a] - lo[a]) : 0.0;
              double rec = 0;
              for (int i = 0; i < 8; ++i) rec += c[i] * (i & 1 ? t[0] : 1 - t[0]) * (i & 2 ? t[1] : 1 - t[1]) * (i & 4 ? t[2] : 1 - t[2]);
              w = std::max(w, std::abs(vol.at(x, y, z) - rec));
            }
      }
    worst[static_cast<std::size_t>(cz)] = w;
  });
  if (missing) throw std::logic_error("verify_reconstruction: a leaf corner or a voxel of an unmerged cube is not kept");
  return *std::max_element(worst.begin(), worst.end());
}

}  // namespace adaptiso
