// Volume model: element types, allocation with size checks, value range, histogram.
#include "adaptiso/volume.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <unistd.h>

#include <fmt/format.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

namespace adaptiso {

std::size_t scalar_size(ScalarType t) {
  switch (t) {
    case ScalarType::u8:
    case ScalarType::i8:
      return 1;
    case ScalarType::u16:
    case ScalarType::i16:
      return 2;
    case ScalarType::u32:
    case ScalarType::i32:
    case ScalarType::f32:
      return 4;
    case ScalarType::f64:
      return 8;
  }
  return 8;
}

std::string_view scalar_name(ScalarType t) {
  switch (t) {
    case ScalarType::u8:
      return "uint8";
    case ScalarType::i8:
      return "int8";
    case ScalarType::u16:
      return "uint16";
    case ScalarType::i16:
      return "int16";
    case ScalarType::u32:
      return "uint32";
    case ScalarType::i32:
      return "int32";
    case ScalarType::f32:
      return "float32";
    case ScalarType::f64:
      return "float64";
  }
  return "?";
}

std::optional<ScalarType> parse_scalar_type(std::string_view n) {
  struct Alias {
    std::string_view name;
    ScalarType t;
  };
  static constexpr Alias aliases[] = {{"uint8", ScalarType::u8},
                                      {"uchar", ScalarType::u8},
                                      {"unsigned char", ScalarType::u8},
                                      {"u8", ScalarType::u8},
                                      {"int8", ScalarType::i8},
                                      {"char", ScalarType::i8},
                                      {"signed char", ScalarType::i8},
                                      {"i8", ScalarType::i8},
                                      {"uint16", ScalarType::u16},
                                      {"ushort", ScalarType::u16},
                                      {"unsigned short", ScalarType::u16},
                                      {"u16", ScalarType::u16},
                                      {"int16", ScalarType::i16},
                                      {"short", ScalarType::i16},
                                      {"i16", ScalarType::i16},
                                      {"uint32", ScalarType::u32},
                                      {"uint", ScalarType::u32},
                                      {"unsigned int", ScalarType::u32},
                                      {"u32", ScalarType::u32},
                                      {"int32", ScalarType::i32},
                                      {"int", ScalarType::i32},
                                      {"i32", ScalarType::i32},
                                      {"float32", ScalarType::f32},
                                      {"float", ScalarType::f32},
                                      {"f32", ScalarType::f32},
                                      {"float64", ScalarType::f64},
                                      {"double", ScalarType::f64},
                                      {"f64", ScalarType::f64}};
  for (const auto& a : aliases)
    if (a.name == n) return a.t;
  return std::nullopt;
}

double Volume::at(std::int64_t linear) const {
  return visit_values(*this, [&](auto vals) { return static_cast<double>(vals[linear]); });
}
double Volume::at(std::int64_t i, std::int64_t j, std::int64_t k) const { return at(index(i, j, k)); }

void Volume::set(std::int64_t linear, double v) {
  visit_values(*this, [&]<class T>(std::span<const T>) {
    T* p = reinterpret_cast<T*>(bytes.data()) + linear;
    if constexpr (std::is_integral_v<T>) {
      double r = std::isnan(v) ? 0.0 : std::round(v);  // a cast of NaN to an integer is undefined
      r = std::clamp(r, static_cast<double>(std::numeric_limits<T>::lowest()), static_cast<double>(std::numeric_limits<T>::max()));
      *p = static_cast<T>(r);
    } else {
      *p = static_cast<T>(v);
    }
  });
}

Vec3 Volume::grid_to_world(const Vec3& g) const { return adaptiso::grid_to_world(origin, direction, g); }

Vec3 world_to_grid(const Vec3& origin, const std::array<double, 9>& d, const Vec3& w) {
  Vec3 r{w[0] - origin[0], w[1] - origin[1], w[2] - origin[2]};
  double c00 = d[4] * d[8] - d[5] * d[7], c01 = d[5] * d[6] - d[3] * d[8], c02 = d[3] * d[7] - d[4] * d[6];
  double det = d[0] * c00 + d[1] * c01 + d[2] * c02;
  double inv[9] = {c00, d[2] * d[7] - d[1] * d[8], d[1] * d[5] - d[2] * d[4], c01, d[0] * d[8] - d[2] * d[6], d[2] * d[3] - d[0] * d[5],
                   c02, d[1] * d[6] - d[0] * d[7], d[0] * d[4] - d[1] * d[3]};
  Vec3 g{};
  for (int a = 0; a < 3; ++a) g[a] = (inv[3 * a] * r[0] + inv[3 * a + 1] * r[1] + inv[3 * a + 2] * r[2]) / det;
  return g;
}

Vec3 Volume::world_to_voxel(const Vec3& w) const {
  const Vec3 g = world_to_grid(origin, direction, w);
  return {g[0] / spacing[0], g[1] / spacing[1], g[2] / spacing[2]};
}

bool Volume::is_oblique() const {
  static constexpr std::array<double, 9> id{1, 0, 0, 0, 1, 0, 0, 0, 1};
  for (int a = 0; a < 9; ++a)
    if (std::abs(direction[a] - id[a]) > 1e-9) return true;
  return false;
}

std::size_t checked_volume_bytes(Dims dims, std::size_t element_size, const std::string& what) {
  for (int a = 0; a < 3; ++a)
    if (dims[a] <= 0) throw InputError(fmt::format("{}: dimensions {}x{}x{} must all be positive", what, dims[0], dims[1], dims[2]));
  const std::uint64_t limit = [] {
    long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
    return pages > 0 && page > 0 ? static_cast<std::uint64_t>(pages) * static_cast<std::uint64_t>(page) : std::uint64_t{1} << 40;
  }();
  std::uint64_t bytes = element_size;
  for (int a = 0; a < 3; ++a) {
    if (static_cast<std::uint64_t>(dims[a]) > limit / bytes)
      throw InputError(
          fmt::format("{}: dimensions {}x{}x{} are absurd (more bytes than this machine's memory)", what, dims[0], dims[1], dims[2]));
    bytes *= static_cast<std::uint64_t>(dims[a]);
  }
  return static_cast<std::size_t>(bytes);
}

Volume make_volume(Dims dims, ScalarType type) {
  Volume v;
  std::size_t n = checked_volume_bytes(dims, scalar_size(type), "volume");
  v.dims = dims;
  v.type = type;
  v.bytes.assign(n, 0);
  return v;
}

namespace {

// Odd reflection about the last voxel: 2·last − inner, within the value range (which lies within
// the type's).
template <class T>
T reflected(T last, T inner, const ValueRange& range) {
  return static_cast<T>(std::clamp(2 * static_cast<double>(last) - static_cast<double>(inner), range.min, range.max));
}

}  // namespace

Volume pad_volume(const Volume& v, const Dims& dims, const ValueRange& range) {
  for (int a = 0; a < 3; ++a)
    if (dims[a] < v.dims[a] || v.dims[a] < 1) throw std::invalid_argument("pad_volume: the dims are smaller than the volume's");
  if (!(range.min <= range.max)) throw std::invalid_argument("pad_volume: an empty value range");
  Volume out = make_volume(dims, v.type);
  out.spacing = v.spacing;
  out.origin = v.origin;
  out.direction = v.direction;
  const Dims n = v.dims;
  visit_values(v, [&]<class T>(std::span<const T> in) {
    std::span<T> o = out.values<T>();
    // Index x mirrored about the last voxel (at the first, for a padding longer than the volume).
    auto mirror = [](std::int64_t x, std::int64_t count) { return std::max<std::int64_t>(2 * (count - 1) - x, 0); };
    // The volume's rows, each extended in x; then the rows past its last y, then the slices past
    // its last z, each reflected from the padded rows and slices before it.
    tbb::parallel_for(std::int64_t{0}, n[2], [&](std::int64_t z) {
      for (std::int64_t y = 0; y < n[1]; ++y) {
        const T* from = &in[static_cast<std::size_t>(v.index(0, y, z))];
        T* to = &o[static_cast<std::size_t>(out.index(0, y, z))];
        std::copy(from, from + n[0], to);
        for (std::int64_t x = n[0]; x < dims[0]; ++x) to[x] = reflected(to[n[0] - 1], to[mirror(x, n[0])], range);
      }
      for (std::int64_t y = n[1]; y < dims[1]; ++y) {
        T* to = &o[static_cast<std::size_t>(out.index(0, y, z))];
        const T* last = &o[static_cast<std::size_t>(out.index(0, n[1] - 1, z))];
        const T* inner = &o[static_cast<std::size_t>(out.index(0, mirror(y, n[1]), z))];
        for (std::int64_t x = 0; x < dims[0]; ++x) to[x] = reflected(last[x], inner[x], range);
      }
    });
    const auto slice = static_cast<std::size_t>(dims[0] * dims[1]);
    for (std::int64_t z = n[2]; z < dims[2]; ++z) {
      T* to = &o[static_cast<std::size_t>(z) * slice];
      const T* last = &o[static_cast<std::size_t>(n[2] - 1) * slice];
      const T* inner = &o[static_cast<std::size_t>(mirror(z, n[2])) * slice];
      for (std::size_t i = 0; i < slice; ++i) to[i] = reflected(last[i], inner[i], range);
    }
  });
  return out;
}

ValueRange value_range(const Volume& v) {
  return visit_values(v, [&]<class T>(std::span<const T> vals) {
    using MM = std::pair<T, T>;
    if (vals.empty()) return ValueRange{};
    MM mm = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, vals.size(), 1 << 16), MM{vals[0], vals[0]},
        [&](const tbb::blocked_range<std::size_t>& r, MM acc) {
          T lo = acc.first, hi = acc.second;
          for (std::size_t i = r.begin(); i < r.end(); ++i) {
            lo = std::min(lo, vals[i]);
            hi = std::max(hi, vals[i]);
          }
          return MM{lo, hi};
        },
        [](MM a, MM b) {
          return MM{std::min(a.first, b.first), std::max(a.second, b.second)};
        });
    return ValueRange{static_cast<double>(mm.first), static_cast<double>(mm.second)};
  });
}

double from_fraction(const ValueRange& range, double fraction, FractionOf kind, std::string_view what) {
  const double width = fraction * (range.max - range.min);
  const double x = kind == FractionOf::value ? range.min + width : width;
  if (!std::isfinite(x)) throw InputError(fmt::format("{}: the value range [{:g}, {:g}] is too wide to scale", what, range.min, range.max));
  return x;
}

double error_tolerance(const Volume& v, double bound) { return error_tolerance(value_range(v), bound); }

double error_tolerance(const ValueRange& r, double bound) {
  double mag = std::max({std::abs(r.min), std::abs(r.max), std::abs(bound), 1e-300});
  return 16 * std::numeric_limits<double>::epsilon() * mag;
}

namespace {

// Counts of `vals` in `bins` equal bins over r (values outside r land in the end bins).
template <class T>
std::vector<std::uint64_t> bin_counts(std::span<const T> vals, const ValueRange& r, int bins) {
  using Counts = std::vector<std::uint64_t>;
  const double w = (r.max - r.min) / bins;
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, vals.size(), 1 << 16), Counts(static_cast<std::size_t>(bins), 0),
      [&](const tbb::blocked_range<std::size_t>& rg, Counts c) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
          const int b = w > 0 ? static_cast<int>((static_cast<double>(vals[i]) - r.min) / w) : 0;
          c[static_cast<std::size_t>(std::clamp(b, 0, bins - 1))]++;
        }
        return c;
      },
      [](Counts a, const Counts& b) {
        for (std::size_t i = 0; i < a.size(); ++i) a[i] += b[i];
        return a;
      });
}

void check_bins(int bins) {
  if (bins < 1) throw OptionError("bins", "the number of bins must be positive");
}

}  // namespace

Histogram histogram(const Volume& v, int bins) { return histogram(v, value_range(v), bins); }

Histogram histogram(const Volume& v, const ValueRange& r, int bins) {
  check_bins(bins);
  Histogram h{r.min, r.max, {}};
  h.counts = visit_values(v, [&]<class T>(std::span<const T> vals) { return bin_counts(vals, r, bins); });
  return h;
}

Histogram histogram(std::span<const double> values, const ValueRange& r, int bins) {
  check_bins(bins);
  return {r.min, r.max, bin_counts(values, r, bins)};
}

void check_geometry(const Dims& dims, const Vec3& spacing, const Vec3& origin, const std::array<double, 9>& direction,
                    const std::string& what) {
  for (int a = 0; a < 3; ++a) {
    if (!(spacing[a] >= kMinSpacing && spacing[a] <= kMaxSpacing))
      throw InputError(
          fmt::format("{}: spacing {:.6g} along axis {} is outside [{:g}, {:g}]", what, spacing[a], a, kMinSpacing, kMaxSpacing));
    if (!(std::abs(origin[a]) <= kMaxCoordinate))
      throw InputError(
          fmt::format("{}: origin {:.6g} along axis {} is not a finite coordinate within ±{:g}", what, origin[a], a, kMaxCoordinate));
  }
  for (double d : direction)
    if (!std::isfinite(d)) throw InputError(fmt::format("{}: the direction matrix holds a non-finite entry", what));
  // Columns a and b of the row-major matrix: their dot product must be δ_ab.
  for (int a = 0; a < 3; ++a)
    for (int b = a; b < 3; ++b) {
      const double dot = direction[a] * direction[b] + direction[3 + a] * direction[3 + b] + direction[6 + a] * direction[6 + b];
      if (!(std::abs(dot - (a == b ? 1.0 : 0.0)) <= kDirectionTolerance))
        throw InputError(
            fmt::format("{}: the direction matrix is not orthonormal (columns {} and {}: dot product {:.6g}); adaptiso "
                        "needs a rotation or reflection (resample a sheared volume first)",
                        what, a, b, dot));
    }
  // The box's world coordinates: origin plus each column times the box's extent along its axis.
  for (int r = 0; r < 3; ++r) {
    double reach = std::abs(origin[r]);
    for (int a = 0; a < 3; ++a)
      reach += std::abs(direction[3 * r + a]) * spacing[a] * static_cast<double>(std::max<std::int64_t>(dims[a] - 1, 0));
    if (!(reach <= kMaxCoordinate))
      throw InputError(
          fmt::format("{}: the volume's box reaches world coordinate {:.3g} along axis {}, beyond ±{:g}", what, reach, r, kMaxCoordinate));
  }
}

void check_finite(const Volume& v, const std::string& what) {
  if (v.type != ScalarType::f32 && v.type != ScalarType::f64) return;
  visit_values(v, [&]<class T>(std::span<const T> vals) {
    std::int64_t bad = 0, first = -1;
    for (std::size_t i = 0; i < vals.size(); ++i)
      if (!std::isfinite(static_cast<double>(vals[i]))) {
        if (first < 0) first = static_cast<std::int64_t>(i);
        ++bad;
      }
    if (bad) {
      std::int64_t i = first % v.dims[0], j = (first / v.dims[0]) % v.dims[1], k = first / (v.dims[0] * v.dims[1]);
      throw InputError(
          fmt::format("{}: {} voxel(s) are NaN or Inf (first at voxel {},{},{}); adaptiso needs finite values", what, bad, i, j, k));
    }
  });
}

}  // namespace adaptiso
