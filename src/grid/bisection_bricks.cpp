// The bisection grid's error hierarchy brick by brick (bisection_bricks.hpp): the brick step runs
// the shared hierarchy (error_hierarchy.hpp) on one brick's window of the global lattice and hands
// up its seam diamonds; the combine step evaluates those, finest scale first, and the coarse scales
// over the whole box, with the same operations as the whole-volume run (bisection_errors.cpp).
//
// The combine step keeps every seam diamond as a record (global voxel, the brick's united
// children, δ, gradient), sorted by scale, kind and voxel, so a parent finds a seam child by binary
// search; the coarse scales' diamonds are records too, their δ and gradient from the voxels at
// multiples of B.
#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cstring>
#include <mutex>

#include "adaptiso/bisection_bricks.hpp"
#include "adaptiso/error.hpp"
#include "grid/error_hierarchy.hpp"
#include "grid/traversal.hpp"
#include "volume/boxes.hpp"

namespace adaptiso {

namespace detail {
namespace {

Coord coord_of(std::int64_t voxel, const Lattice& lat) {
  const std::int64_t nx = lat.X[0] + std::int64_t{1}, ny = lat.X[1] + std::int64_t{1};
  return {static_cast<std::int32_t>(voxel % nx), static_cast<std::int32_t>(voxel / nx % ny), static_cast<std::int32_t>(voxel / (nx * ny))};
}
Coord to_coord(const Dims& d) {
  return {static_cast<std::int32_t>(d[0]), static_cast<std::int32_t>(d[1]), static_cast<std::int32_t>(d[2])};
}

// The combine step's records: one per diamond it evaluates.
struct Records {
  std::vector<std::int64_t> voxel;
  std::vector<double> lo, hi, g, delta, gradient;
  void reserve(std::size_t n) { voxel.reserve(n), lo.reserve(n), hi.reserve(n), g.reserve(n), delta.reserve(n), gradient.reserve(n); }
  void add(std::int64_t v, double l, double h, double gg, double d, double gr) {
    voxel.push_back(v), lo.push_back(l), hi.push_back(h), g.push_back(gg), delta.push_back(d), gradient.push_back(gr);
  }
};

template <bool kDisplacement>
class Combine {
public:
  Combine(const Lattice& lat, const Seams& seams, const ErrorCodes& codes, BisectionErrors& e, const Displacement& disp)
      : lat_(lat), seams_(seams), codes_(codes), dcodes_(disp.codes), e_(e), disp_(disp) {}

  void run(Records& r, const Progress& progress) {
    // Sorted by scale, kind (edges, faces, cubes: the order of evaluation) and voxel.
    const std::size_t n = r.voxel.size();
    group_.resize(n);
    order_.resize(n);
    tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) {
      const Diamond d = classify(coord_of(r.voxel[i], lat_), lat_.k);
      group_[i] = static_cast<std::uint16_t>(group(d.s, d.kind));
      order_[i] = i;
    });
    tbb::parallel_sort(order_.begin(), order_.end(), [&](std::size_t a, std::size_t b) {
      return group_[a] != group_[b] ? group_[a] < group_[b] : r.voxel[a] < r.voxel[b];
    });
    keys_.resize(n);
    for (std::size_t i = 0; i < n; ++i) keys_[i] = r.voxel[order_[i]];
    begin_.assign(static_cast<std::size_t>(group(lat_.k, DiamondKind::edge)) + 1, n);
    for (std::size_t i = n; i-- > 0;) begin_[group_[order_[i]]] = i;
    for (std::size_t gi = begin_.size() - 1; gi-- > 0;) begin_[gi] = std::min(begin_[gi], begin_[gi + 1]);
    bound_.assign(n, Bound{});
    for (int s = 0; s < lat_.k; ++s) {
      for (DiamondKind kind : {DiamondKind::edge, DiamondKind::face, DiamondKind::cube}) {
        const int gi = group(s, kind);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(begin_[gi], begin_[gi + 1], 256), [&](const auto& range) {
          for (std::size_t i = range.begin(); i < range.end(); ++i) evaluate(r, i);
        });
      }
      report(progress, "error hierarchy (combine)", static_cast<double>(s + 1) / lat_.k);
    }
  }

private:
  const Lattice& lat_;
  const Seams& seams_;
  CodeTable codes_, dcodes_;
  BisectionErrors& e_;
  const Displacement& disp_;
  std::vector<std::uint16_t> group_;
  std::vector<std::size_t> order_, begin_;
  std::vector<std::int64_t> keys_;  // sorted records' voxels
  std::vector<Bound> bound_;        // per sorted record, as its parents read it

  static int group(int s, DiamondKind kind) { return 3 * s + (kind == DiamondKind::edge ? 0 : kind == DiamondKind::face ? 1 : 2); }
  std::int64_t index(const Coord& c) const { return c[0] + lat_.nx * c[1] + lat_.nxy * c[2]; }

  Bound seam_bound(const Diamond& d) const {
    const int gi = group(d.s, d.kind);
    const auto first = keys_.begin() + static_cast<std::ptrdiff_t>(begin_[gi]),
               last = keys_.begin() + static_cast<std::ptrdiff_t>(begin_[gi + 1]);
    const auto it = std::lower_bound(first, last, index(d.c));
    return bound_[static_cast<std::size_t>(it - keys_.begin())];
  }

  void evaluate(const Records& r, std::size_t sorted) {
    const std::size_t i = order_[sorted];
    const Diamond d = classify(coord_of(r.voxel[i], lat_), lat_.k);
    const Bound b = diamond_bound(
        d, lat_,
        [&](const Coord& c) {
          if (!lat_.in_box(c)) return outside_bound(c, lat_);
          const Diamond child = classify(c, lat_.k);
          return seams_.seam(child) ? seam_bound(child) : Bound{};  // the others: in the record
        },
        [&](const Diamond&) {
          return std::array{r.delta[i], r.gradient[i]};
        },
        Bound{r.lo[i], r.hi[i], r.g[i]});
    // As the whole-volume run keeps it: the finest edges and faces in double, the rest as stored.
    bound_[sorted] = d.h == 1 && d.kind != DiamondKind::cube ? b : StoredBound(b).get();
    const auto [c, m] = saturated_codes<kDisplacement>(d, b, lat_.S, codes_, dcodes_, disp_, [&](const Coord& x, bool displacement) {
      if (!lat_.in_box(x)) return outside_code(x, lat_);
      return (displacement ? e_.displacement_code : e_.code)[static_cast<std::size_t>(index(x))];
    });
    e_.code[static_cast<std::size_t>(index(d.c))] = c;
    if constexpr (kDisplacement) e_.displacement_code[static_cast<std::size_t>(index(d.c))] = m;
  }
};

}  // namespace
}  // namespace detail

VoxelBox BrickGrid::covers(std::int64_t n) const {
  const Dims b = brick(n);
  VoxelBox box;
  for (int a = 0; a < 3; ++a) {
    box.lo[a] = b[a] * side;
    box.hi[a] = std::min(box.lo[a] + side, dims[a] - 1);
  }
  return box;
}

VoxelBox BrickGrid::owns(std::int64_t n) const {
  VoxelBox box = covers(n);
  const Dims b = brick(n);
  for (int a = 0; a < 3; ++a)
    if (b[a] + 1 < count[a]) box.hi[a] -= 1;
  return box;
}

VoxelBox BrickGrid::reads(std::int64_t n, bool displacement) const {
  VoxelBox box = covers(n);
  if (displacement)
    for (int a = 0; a < 3; ++a) box.lo[a] = std::max<std::int64_t>(box.lo[a] - 1, 0);
  return box;
}

void check_brick_side(std::int64_t brick_side) {
  if (brick_side < 2 || !std::has_single_bit(static_cast<std::uint64_t>(brick_side)))
    throw OptionError("brick_side", fmt::format("{} is not a power of two of at least 2", brick_side));
}

BrickGrid brick_grid(const Dims& dims, std::int64_t brick_side) {
  check_brick_side(brick_side);
  const detail::Lattice lat = detail::make_lattice(dims);
  BrickGrid g;
  g.dims = dims;
  g.side = std::min<std::int64_t>(brick_side, lat.S);
  for (int a = 0; a < 3; ++a) g.count[a] = (lat.X[a] + g.side - 1) / g.side;
  return g;
}

std::uint64_t BrickErrors::bytes_exchanged() const {
  auto bytes = [](const auto& v) { return static_cast<std::uint64_t>(v.size() * sizeof(v[0])); };
  return bytes(seam_voxel) + bytes(seam_lo) + bytes(seam_hi) + bytes(seam_delta) + bytes(seam_g) + bytes(seam_gradient) +
         bytes(coarse_voxel) + bytes(coarse_value) + bytes(coarse_gradient);
}

BrickErrors bisection_brick_errors(const BrickGrid& bricks, std::int64_t brick, const Volume& region, const ValueRange& range,
                                   bool displacement) {
  using namespace detail;
  const Lattice lat = make_lattice(bricks.dims);
  if (brick < 0 || brick >= bricks.size()) throw InputError(fmt::format("brick {} of {}", brick, bricks.size()));
  const VoxelBox covers = bricks.covers(brick), owns = bricks.owns(brick), reads = bricks.reads(brick, displacement);
  if (region.dims != reads.dims())
    throw InputError(fmt::format("brick {}: a region of {} x {} x {} voxels, not {} x {} x {}", brick, region.dims[0], region.dims[1],
                                 region.dims[2], reads.dims()[0], reads.dims()[1], reads.dims()[2]));
  const Window w{to_coord(covers.lo), to_coord(covers.hi), to_coord(reads.lo), region.dims[0], region.dims[0] * region.dims[1]};
  BrickErrors out;
  out.brick = brick;
  const auto n = static_cast<std::size_t>(region.voxel_count());
  std::vector<std::uint8_t> code(n, 0), dcode;
  const HierarchyCodes hc = hierarchy_codes(range, displacement);
  Displacement disp = hc.displacement;
  if (displacement) {
    dcode.assign(n, 0);
    disp.code = &dcode;
  }
  Seams::Out seam_out;
  Seams seams{static_cast<std::int32_t>(bricks.side), lat.X, to_coord(owns.hi), &seam_out};
  const auto B = bricks.side;
  const Progress silent;  // named: the hierarchy keeps a reference (a temporary here died before run(), ASan)
  visit_values(region, [&]<class T>(std::span<const T> values) {
    auto run = [&]<bool kDisplacement>() {
      ErrorHierarchy<T, kDisplacement, true> hierarchy(lat, w, values.data(), hc.codes, code, disp, silent, &seams);
      hierarchy.run();
      // The coarse points: the owned voxels at multiples of B.
      for (std::int64_t z = (owns.lo[2] + B - 1) / B * B; z <= owns.hi[2]; z += B)
        for (std::int64_t y = (owns.lo[1] + B - 1) / B * B; y <= owns.hi[1]; y += B)
          for (std::int64_t x = (owns.lo[0] + B - 1) / B * B; x <= owns.hi[0]; x += B) {
            const Coord c = to_coord({x, y, z});
            out.coarse_voxel.push_back(lat.index(c));
            out.coarse_value.push_back(hierarchy.value(c));
            if (kDisplacement) out.coarse_gradient.push_back(hierarchy.gradient(c));
          }
    };
    if (displacement)
      run.template operator()<true>();
    else
      run.template operator()<false>();
  });
  out.seam_voxel = std::move(seam_out.voxel);
  out.seam_lo = std::move(seam_out.lo);
  out.seam_hi = std::move(seam_out.hi);
  out.seam_delta = std::move(seam_out.delta);
  out.seam_g = std::move(seam_out.g);
  out.seam_gradient = std::move(seam_out.gradient);
  // The owned voxels' codes, cut out of the window.
  const VoxelBox inner{{owns.lo[0] - reads.lo[0], owns.lo[1] - reads.lo[1], owns.lo[2] - reads.lo[2]},
                       {owns.hi[0] - reads.lo[0], owns.hi[1] - reads.lo[1], owns.hi[2] - reads.lo[2]}};
  const auto owned = static_cast<std::size_t>(owns.voxel_count());
  out.code.resize(owned);
  copy_box(code.data(), region.dims, inner, 1, out.code.data());
  if (displacement) {
    out.displacement_code.resize(owned);
    copy_box(dcode.data(), region.dims, inner, 1, out.displacement_code.data());
  }
  return out;
}

BisectionErrors bisection_combine_bricks(const BrickGrid& bricks, std::vector<BrickErrors> results, const ValueRange& range,
                                         bool displacement, const Progress& progress) {
  using namespace detail;
  const Lattice lat = make_lattice(bricks.dims);
  if (static_cast<std::int64_t>(results.size()) != bricks.size())
    throw InputError(fmt::format("{} brick results for {} bricks", results.size(), bricks.size()));
  std::vector<std::uint8_t> seen(results.size(), 0);
  for (const auto& r : results) {
    if (r.brick < 0 || r.brick >= bricks.size() || seen[static_cast<std::size_t>(r.brick)]++)
      throw InputError(fmt::format("brick {} given twice or out of range", r.brick));
    if (r.displacement_code.empty() == displacement)
      throw InputError(fmt::format("brick {} computed {} the displacement criterion", r.brick, displacement ? "without" : "with"));
  }
  const HierarchyCodes hc = hierarchy_codes(range, displacement);
  BisectionErrors e;
  e.root_size = lat.S;
  e.codes = hc.codes;
  const auto voxels = static_cast<std::size_t>(bricks.dims[0] * bricks.dims[1] * bricks.dims[2]);
  assign_big(e.code, voxels, std::uint8_t{0});
  Displacement disp = hc.displacement;
  if (displacement) {
    e.displacement_codes = hc.displacement.codes;
    assign_big(e.displacement_code, voxels, std::uint8_t{0});
    disp.code = &e.displacement_code;
  }
  // The bricks' own codes.
  tbb::parallel_for(std::size_t{0}, results.size(), [&](std::size_t i) {
    const BrickErrors& r = results[i];
    const VoxelBox owns = bricks.owns(r.brick);
    const Dims n = owns.dims();
    if (r.code.size() != static_cast<std::size_t>(n[0] * n[1] * n[2]))
      throw InputError(fmt::format("brick {}: {} codes for {} voxels", r.brick, r.code.size(), n[0] * n[1] * n[2]));
    for (std::int64_t z = 0; z < n[2]; ++z)
      for (std::int64_t y = 0; y < n[1]; ++y) {
        const auto from = static_cast<std::size_t>(n[0] * (y + n[1] * z));
        const auto to = static_cast<std::size_t>(lat.index(
            {static_cast<std::int32_t>(owns.lo[0]), static_cast<std::int32_t>(owns.lo[1] + y), static_cast<std::int32_t>(owns.lo[2] + z)}));
        std::copy_n(r.code.begin() + static_cast<std::ptrdiff_t>(from), n[0], e.code.begin() + static_cast<std::ptrdiff_t>(to));
        if (displacement)
          std::copy_n(r.displacement_code.begin() + static_cast<std::ptrdiff_t>(from), n[0],
                      e.displacement_code.begin() + static_cast<std::ptrdiff_t>(to));
      }
  });
  // The seam diamonds' records, then the coarse scales' from the voxels at multiples of B.
  Records rec;
  std::vector<double> coarse_value, coarse_gradient;
  const std::int64_t B = bricks.side;
  const Dims cn{lat.X[0] / B + 1, lat.X[1] / B + 1, lat.X[2] / B + 1};
  const auto coarse_index = [&](const Coord& c) { return static_cast<std::size_t>(c[0] / B + cn[0] * (c[1] / B + cn[1] * (c[2] / B))); };
  coarse_value.assign(static_cast<std::size_t>(cn[0] * cn[1] * cn[2]), 0.0);
  std::size_t seam_count = 0;
  for (const auto& r : results) seam_count += r.seam_voxel.size();
  std::size_t coarse_count = 0;  // the coarse scales' diamonds: fewer than 8 per coarse point
  for (std::int64_t step = B; step < lat.S; step *= 2)
    coarse_count += 8 * static_cast<std::size_t>((lat.X[0] / step + 1) * (lat.X[1] / step + 1) * (lat.X[2] / step + 1));
  rec.reserve(seam_count + coarse_count);
  coarse_gradient.assign(coarse_value.size(), kInf);
  for (auto& r : results) {
    const std::size_t m = r.seam_voxel.size();
    if (r.seam_lo.size() != m || r.seam_hi.size() != m || r.seam_delta.size() != m ||
        (displacement && (r.seam_g.size() != m || r.seam_gradient.size() != m)) || r.coarse_value.size() != r.coarse_voxel.size() ||
        (displacement && r.coarse_gradient.size() != r.coarse_voxel.size()))
      throw InputError(fmt::format("brick {}: arrays of different lengths", r.brick));
    for (std::size_t i = 0; i < m; ++i)
      rec.add(r.seam_voxel[i], r.seam_lo[i], r.seam_hi[i], displacement ? r.seam_g[i] : kInf, r.seam_delta[i],
              displacement ? r.seam_gradient[i] : kInf);
    for (std::size_t i = 0; i < r.coarse_voxel.size(); ++i) {
      const std::size_t at = coarse_index(coord_of(r.coarse_voxel[i], lat));
      coarse_value[at] = r.coarse_value[i];
      if (displacement) coarse_gradient[at] = r.coarse_gradient[i];
    }
    r = BrickErrors{};  // consumed
  }
  for (std::int32_t h = static_cast<std::int32_t>(B); h < lat.S; h *= 2)
    for (DiamondKind kind : {DiamondKind::edge, DiamondKind::face, DiamondKind::cube})
      for (int axis = 0; axis < (kind == DiamondKind::cube ? 1 : 3); ++axis) {
        const Sublattice sub(lat, kind, axis, h);
        for (std::int64_t k = 0; k < sub.n[2]; ++k)
          for (std::int64_t j = 0; j < sub.n[1]; ++j)
            for (std::int64_t i = 0; i < sub.n[0]; ++i) {
              const Diamond d = classify(sub.at(i, j, k), lat.k);
              if (!d.valid) continue;
              double delta = 0, gradient = kInf;
              const Placement where = placement(d, lat);
              if (!where.forced && where.any_inside) {
                const auto [p, q] = refinement_edge(d);
                delta = 0.5 * (coarse_value[coarse_index(p)] + coarse_value[coarse_index(q)]) - coarse_value[coarse_index(d.c)];
                gradient = coarse_gradient[coarse_index(d.c)];
              }
              rec.add(lat.index(d.c), 0, 0, kInf, delta, gradient);
            }
      }
  const Seams seams{static_cast<std::int32_t>(B), lat.X, {}, nullptr};
  if (displacement)
    Combine<true>(lat, seams, hc.codes, e, disp).run(rec, progress);
  else
    Combine<false>(lat, seams, hc.codes, e, disp).run(rec, progress);
  return e;
}

RegionSource region_source(const Volume& v) {
  return [&v](const VoxelBox& box) {
    for (int a = 0; a < 3; ++a)
      if (box.lo[a] < 0 || box.hi[a] >= v.dims[a] || box.lo[a] > box.hi[a])
        throw InputError(fmt::format("a region [{}, {}] outside the volume's {} voxels along axis {}", box.lo[a], box.hi[a], v.dims[a], a));
    return detail::copy_box(v, box);
  };
}

RegionSource padded_source(RegionSource source, const Dims& volume, const ValueRange& range) {
  return [source = std::move(source), volume, range](const VoxelBox& box) {
    // The reflection of the voxels past a far face reaches as far inside: read from there to the
    // face, pad that as pad_volume pads the whole (the same values), keep the box.
    VoxelBox read = box;
    bool past = false;
    for (int a = 0; a < 3; ++a) {
      const std::int64_t last = volume[a] - 1;
      if (box.hi[a] <= last) continue;
      past = true;
      read.lo[a] = std::max<std::int64_t>(0, std::min(box.lo[a], 2 * last - box.hi[a]));
      read.hi[a] = last;
    }
    if (!past) return source(box);
    Dims reach{};
    for (int a = 0; a < 3; ++a) reach[a] = std::max(box.hi[a], read.hi[a]) - read.lo[a] + 1;
    const Volume padded = pad_volume(source(read), reach, range);
    VoxelBox keep;
    for (int a = 0; a < 3; ++a) keep.lo[a] = box.lo[a] - read.lo[a], keep.hi[a] = box.hi[a] - read.lo[a];
    return detail::copy_box(padded, keep);
  };
}

BisectionErrors bisection_errors_bricked(const Dims& dims, const ValueRange& range, std::int64_t brick_side, const RegionSource& source,
                                         bool displacement, const Progress& progress, std::uint64_t* bytes_exchanged) {
  const BrickGrid bricks = brick_grid(dims, brick_side);
  std::vector<BrickErrors> results(static_cast<std::size_t>(bricks.size()));
  std::atomic<std::int64_t> done{0};
  std::mutex report_mutex;
  tbb::parallel_for(std::int64_t{0}, bricks.size(), [&](std::int64_t n) {
    results[static_cast<std::size_t>(n)] = bisection_brick_errors(bricks, n, source(bricks.reads(n, displacement)), range, displacement);
    const std::lock_guard lock(report_mutex);
    report(progress, "error hierarchy (bricks)", static_cast<double>(++done) / static_cast<double>(bricks.size()));
  });
  if (bytes_exchanged) {
    *bytes_exchanged = 0;
    for (const auto& r : results) *bytes_exchanged += r.bytes_exchanged();
  }
  return bisection_combine_bricks(bricks, std::move(results), range, displacement, progress);
}

}  // namespace adaptiso
