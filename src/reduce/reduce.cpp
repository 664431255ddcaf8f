// Vertex reduction front door: resolves relative units, runs the chosen criteria, unites the
// kept sets with the 8 corners of the volume (Lürig & Ertl §2.1).
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.1 (the two criteria united, the corners kept).
#include <fmt/format.h>
#include <algorithm>
#include <cmath>

#include "adaptiso/reduce.hpp"

namespace adaptiso {

std::vector<std::int64_t> volume_corners(const Volume& v) {
  std::vector<std::int64_t> c;
  for (int i = 0; i < 8; ++i) c.push_back(v.index(i & 1 ? v.dims[0] - 1 : 0, i & 2 ? v.dims[1] - 1 : 0, i & 4 ? v.dims[2] - 1 : 0));
  std::sort(c.begin(), c.end());
  c.erase(std::unique(c.begin(), c.end()), c.end());
  return c;
}

ReduceResult reduce(const Volume& v, const ReduceOptions& o, const Progress& progress) { return reduce(v, value_range(v), o, progress); }

ReduceResult reduce(const Volume& v, const ValueRange& range, const ReduceOptions& o, const Progress& progress) {
  if (v.voxel_count() == 0) throw InputError("reduce: the volume is empty");
  ReduceResult r;
  if (!(o.max_error >= 0) || !std::isfinite(o.max_error))
    throw OptionError("max_error", fmt::format("must be a non-negative number, got {}", o.max_error));
  r.max_error = o.relative ? from_fraction(range, o.max_error, FractionOf::width, "max_error") : o.max_error;
  std::vector<std::int64_t> a, b;
  if (o.method != ReduceMethod::structural) {
    a = reconstruction_analysis(v, range, r.max_error, &r.octree, progress);
    r.kept_reconstruction = static_cast<std::int64_t>(a.size());
  }
  if (o.method != ReduceMethod::reconstruction) {
    b = structural_analysis(v, o, &r.threshold, progress);
    r.kept_structural = static_cast<std::int64_t>(b.size());
  }
  auto corners = volume_corners(v);
  std::vector<std::int64_t> ab;
  std::set_union(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(ab));
  std::set_union(ab.begin(), ab.end(), corners.begin(), corners.end(), std::back_inserter(r.kept));
  return r;
}

}  // namespace adaptiso
