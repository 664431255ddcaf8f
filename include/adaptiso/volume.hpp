// adaptiso/volume.hpp — a scalar volume on an orthogonal, equidistant grid.
//
// Values are kept in their native type (uint8 … float64), x fastest, then y, then z; the
// algorithms read them through visit_values(), which instantiates each algorithm once per type,
// so no float copy of the volume is ever made (a 512×512×361 int16 CT costs its 189 MB, not 378 MB
// more for a float copy). Values are compared and interpolated in double precision.
//
// Coordinates: a voxel index (i, j, k) maps to the physical point
//     origin + direction · (spacing ⊙ (i, j, k))
// where `direction` is the 3×3 matrix whose columns are the world directions of the index axes
// (identity unless the file records an oblique orientation; the grid is never resampled). The
// pipeline works in the "grid frame" spacing ⊙ (i, j, k), which differs from world coordinates only
// by that rotation and the origin; outputs are transformed to world coordinates when written.
//
// Storage: the volume owns its bytes (readers fill them), or views memory someone else owns (a
// numpy array in the Python module) and keeps that owner alive; writing through values() or set()
// to a view copies it first, so the owner's memory is only ever read.
#pragma once
#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "adaptiso/error.hpp"

namespace adaptiso {

enum class ScalarType : std::uint8_t { u8, i8, u16, i16, u32, i32, f32, f64 };

std::size_t scalar_size(ScalarType t);
// "uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64".
std::string_view scalar_name(ScalarType t);
// Accepts the names above and common aliases (uchar, short, float, double, …).
std::optional<ScalarType> parse_scalar_type(std::string_view name);

using Vec3 = std::array<double, 3>;
using Dims = std::array<std::int64_t, 3>;

// The voxel bytes of a volume: owned (a vector's interface for the readers) or a read-only view of
// memory kept alive by a shared owner.
class VoxelBuffer {
public:
  VoxelBuffer() = default;
  VoxelBuffer(std::vector<unsigned char>&& owned) : own_(std::move(owned)) {}  // NOLINT: readers assign vectors
  // A view of n bytes at data, valid while owner lives.
  static VoxelBuffer view(const unsigned char* data, std::size_t n, std::shared_ptr<const void> owner) {
    VoxelBuffer b;
    b.view_ = data;
    b.view_size_ = n;
    b.owner_ = std::move(owner);
    return b;
  }
  bool is_view() const { return view_ != nullptr; }
  const unsigned char* data() const { return view_ ? view_ : own_.data(); }
  unsigned char* data() {  // copies a view first: the owner's memory is never written
    own();
    return own_.data();
  }
  std::size_t size() const { return view_ ? view_size_ : own_.size(); }
  bool empty() const { return size() == 0; }
  const unsigned char* begin() const { return data(); }
  const unsigned char* end() const { return data() + size(); }
  void assign(std::size_t n, unsigned char x) { drop_view(), own_.assign(n, x); }
  template <class It>
  void assign(It first, It last) {
    drop_view();
    own_.assign(first, last);
  }
  void resize(std::size_t n) { own(), own_.resize(n); }
  void swap(VoxelBuffer& o) noexcept {
    std::swap(own_, o.own_);
    std::swap(view_, o.view_);
    std::swap(view_size_, o.view_size_);
    std::swap(owner_, o.owner_);
  }
  bool operator==(const VoxelBuffer& o) const { return size() == o.size() && std::equal(begin(), end(), o.begin()); }

private:
  void drop_view() {
    view_ = nullptr;
    view_size_ = 0;
    owner_.reset();
  }
  void own() {
    if (!view_) return;
    std::vector<unsigned char> copy(view_, view_ + view_size_);
    drop_view();
    own_.swap(copy);
  }
  std::vector<unsigned char> own_;
  const unsigned char* view_ = nullptr;
  std::size_t view_size_ = 0;
  std::shared_ptr<const void> owner_;
};

struct Volume {
  Dims dims{0, 0, 0};
  Vec3 spacing{1, 1, 1};
  Vec3 origin{0, 0, 0};
  // Row-major 3×3; column a is the world direction of index axis a.
  std::array<double, 9> direction{1, 0, 0, 0, 1, 0, 0, 0, 1};
  ScalarType type = ScalarType::f32;
  VoxelBuffer bytes;  // voxel_count() * scalar_size(type) bytes, native endianness

  std::int64_t voxel_count() const { return dims[0] * dims[1] * dims[2]; }
  std::int64_t index(std::int64_t i, std::int64_t j, std::int64_t k) const { return i + dims[0] * (j + dims[1] * k); }
  // Value at a voxel as double (slow path for tests and tools; algorithms use visit_values).
  double at(std::int64_t i, std::int64_t j, std::int64_t k) const;
  double at(std::int64_t linear) const;
  void set(std::int64_t linear, double v);  // rounds/clamps to the native type

  template <class T>
  std::span<const T> values() const {
    return {reinterpret_cast<const T*>(bytes.data()), static_cast<std::size_t>(voxel_count())};
  }
  template <class T>
  std::span<T> values() {
    return {reinterpret_cast<T*>(bytes.data()), static_cast<std::size_t>(voxel_count())};
  }

  // Grid frame (spacing ⊙ index) and world coordinates; see the header comment.
  Vec3 grid_position(double i, double j, double k) const { return {i * spacing[0], j * spacing[1], k * spacing[2]}; }
  Vec3 grid_to_world(const Vec3& g) const;
  Vec3 voxel_to_world(double i, double j, double k) const { return grid_to_world(grid_position(i, j, k)); }
  Vec3 world_to_voxel(const Vec3& w) const;
  bool is_oblique() const;
};

// Allocates a zero-filled volume; throws InputError for non-positive dims or absurd sizes
// (product overflow, or more bytes than the machine's memory).
Volume make_volume(Dims dims, ScalarType type);
// Throws InputError when dims are not positive or dims × element size overflows or exceeds memory.
std::size_t checked_volume_bytes(Dims dims, std::size_t element_size, const std::string& what);

// Calls f(std::span<const T>) with the volume's values in their native type.
template <class F>
decltype(auto) visit_values(const Volume& v, F&& f) {
  switch (v.type) {
    case ScalarType::u8:
      return f(v.values<std::uint8_t>());
    case ScalarType::i8:
      return f(v.values<std::int8_t>());
    case ScalarType::u16:
      return f(v.values<std::uint16_t>());
    case ScalarType::i16:
      return f(v.values<std::int16_t>());
    case ScalarType::u32:
      return f(v.values<std::uint32_t>());
    case ScalarType::i32:
      return f(v.values<std::int32_t>());
    case ScalarType::f32:
      return f(v.values<float>());
    case ScalarType::f64:
      break;
  }
  return f(v.values<double>());
}

// origin + direction · g, with direction row-major (its columns are the index axes' directions).
inline Vec3 grid_to_world(const Vec3& origin, const std::array<double, 9>& d, const Vec3& g) {
  return {origin[0] + d[0] * g[0] + d[1] * g[1] + d[2] * g[2], origin[1] + d[3] * g[0] + d[4] * g[1] + d[5] * g[2],
          origin[2] + d[6] * g[0] + d[7] * g[1] + d[8] * g[2]};
}

// Its inverse: the grid-frame position (index ⊙ spacing) of world point w. A general 3×3 inverse:
// files may record directions that are not exactly orthonormal.
Vec3 world_to_grid(const Vec3& origin, const std::array<double, 9>& d, const Vec3& w);

// A box of voxels [lo, hi] per axis (inclusive), in index space.
struct VoxelBox {
  Dims lo{0, 0, 0}, hi{0, 0, 0};
  Dims dims() const { return {hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1}; }
  std::int64_t voxel_count() const {
    const Dims d = dims();
    return d[0] * d[1] * d[2];
  }
};

// The volume extended to `dims` (at least its own along every axis) past its far faces by odd
// reflection about its last slices, axis after axis (x, then y, then z): along x, voxel X − 1 + k
// is 2·v(X − 1) − v(max(X − 1 − k, 0)), clamped to `range` (the volume's value range: a grid's
// values stay within its source's); likewise along y over the padded rows and along z over the
// padded slices. The field goes on with its slope, so a smooth field stays smooth across the face
// (copies of the last slice would put a kink there, which a grid refines). Geometry kept. Throws
// std::invalid_argument for smaller dims. (bisection.hpp: the padded lattice.)
struct ValueRange {
  double min = 0, max = 0;
};
Volume pad_volume(const Volume& v, const Dims& dims, const ValueRange& range);
// Parallel min/max over all voxels.
ValueRange value_range(const Volume& v);

// Relative to data units, the one conversion the command line, the library and Python share: a
// fraction f of the value range as a value in it (FractionOf::value, an iso-value:
// min + f·(max − min)) or as an amount of its width (FractionOf::width, an error bound:
// f·(max − min)). Throws InputError "<what>: the value range [min, max] is too wide to scale"
// when the result is not finite (a range from corrupt metadata, ±1e308, scaled); f itself is
// the caller's to check.
enum class FractionOf { value, width };
double from_fraction(const ValueRange& range, double fraction, FractionOf kind, std::string_view what);

// Rounding allowance used when comparing errors with the bound: a few ulps of the data magnitude,
// so that error 0 means "exact up to floating-point rounding".
double error_tolerance(const Volume& v, double bound);
double error_tolerance(const ValueRange& range, double bound);

struct Histogram {
  double min = 0, max = 0;            // the value range the bins cover
  std::vector<std::uint64_t> counts;  // bin b covers [min + b·w, min + (b+1)·w), the last bin includes max
};
Histogram histogram(const Volume& v, int bins);
Histogram histogram(const Volume& v, const ValueRange& range, int bins);
Histogram histogram(std::span<const double> values, const ValueRange& range, int bins);

// Rejects geometry that cannot give meshes of finite float32 coordinates (every mesh format here
// stores float32): a spacing outside [kMinSpacing, kMaxSpacing], an origin or direction entry that
// is not finite, a direction whose columns are not orthonormal within kDirectionTolerance (normals
// and gradients are turned into the world frame by the direction itself, which only a rotation or
// reflection allows; a sheared acquisition must be resampled first), or a box whose world
// coordinates reach beyond kMaxCoordinate. Throws InputError naming `what`. Every volume read by
// read_volume and given to prepare passes it, and so does every grid file loaded.
inline constexpr double kMinSpacing = 1e-30, kMaxSpacing = 1e30, kMaxCoordinate = 1e30, kDirectionTolerance = 1e-3;
void check_geometry(const Dims& dims, const Vec3& spacing, const Vec3& origin, const std::array<double, 9>& direction,
                    const std::string& what);
inline void check_geometry(const Volume& v, const std::string& what) { check_geometry(v.dims, v.spacing, v.origin, v.direction, what); }

// Rejects NaN and ±Inf values (float types only): throws InputError naming `what`, the count and the
// first offending voxel. adaptiso needs finite values: a NaN has no place on either side of an
// iso-surface, and silently replacing it would invent data.
void check_finite(const Volume& v, const std::string& what);

}  // namespace adaptiso
