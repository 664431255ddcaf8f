// Structural analysis — Lürig & Ertl §2.1, "structural analysis": keep voxels whose gradient
// magnitude exceeds a threshold and is a local maximum along the gradient direction (non-maximum
// suppression as in Canny's edge detector, extended to 3D).
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.1, "structural analysis".
// - Canny. A computational approach to edge detection. IEEE TPAMI, 1986 (non-maximum suppression,
//   the derivative-of-Gaussian operator).
//
// Central differences are evaluated on the fly (no gradient field is stored; a voxel below the
// threshold costs six reads). The Canny operator convolves the volume with the partial derivatives
// of a 3D Gaussian (separable: one 1D pass per axis), which needs three float fields of the
// volume's size; border values are replicated.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <fmt/format.h>
#include <cmath>

#include "adaptiso/reduce.hpp"
#include "util/progress_counter.hpp"

namespace adaptiso {
namespace {

using Grad = std::array<double, 3>;

// Rounds a gradient direction to one of the 26 neighbour offsets.
inline void rounded_direction(const Grad& g, double mag, int d[3]) {
  for (int a = 0; a < 3; ++a) d[a] = static_cast<int>(std::lround(g[a] / mag));
}

template <class GradFn>
std::vector<std::int64_t> suppress(const Dims& dm, double threshold, GradFn grad, const Progress& progress) {
  std::vector<std::vector<std::int64_t>> per_slice(static_cast<std::size_t>(dm[2]));
  detail::ProgressCounter done(progress, "reduce: structural", static_cast<std::uint64_t>(dm[2]));
  tbb::parallel_for(std::int64_t{0}, dm[2], [&](std::int64_t z) {
    auto& out = per_slice[static_cast<std::size_t>(z)];
    for (std::int64_t y = 0; y < dm[1]; ++y)
      for (std::int64_t x = 0; x < dm[0]; ++x) {
        Grad g = grad(x, y, z);
        double m = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
        if (!(m > threshold) || m == 0) continue;
        int d[3];
        rounded_direction(g, m, d);
        bool strictly = false, ok = true;
        for (int s = -1; s <= 1 && ok; s += 2) {
          std::int64_t nx = x + s * d[0], ny = y + s * d[1], nz = z + s * d[2];
          if (nx < 0 || ny < 0 || nz < 0 || nx >= dm[0] || ny >= dm[1] || nz >= dm[2]) continue;
          Grad h = grad(nx, ny, nz);
          double mn = std::sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
          if (mn > m)
            ok = false;
          else if (mn < m)
            strictly = true;
        }
        if (ok && strictly) out.push_back(x + dm[0] * (y + dm[1] * z));
      }
    done.advance(1);
  });
  std::vector<std::int64_t> kept;
  for (auto& s : per_slice) kept.insert(kept.end(), s.begin(), s.end());
  return kept;
}

template <class GradFn>
double max_gradient(const Dims& dm, GradFn grad) {
  return tbb::parallel_reduce(
      tbb::blocked_range<std::int64_t>(0, dm[2]), 0.0,
      [&](const tbb::blocked_range<std::int64_t>& r, double best) {
        for (std::int64_t z = r.begin(); z < r.end(); ++z)
          for (std::int64_t y = 0; y < dm[1]; ++y)
            for (std::int64_t x = 0; x < dm[0]; ++x) {
              Grad g = grad(x, y, z);
              best = std::max(best, std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]));
            }
        return best;
      },
      [](double a, double b) { return std::max(a, b); });
}

// One separable 1D convolution pass along `axis` with replicated borders.
void convolve_axis(const std::vector<float>& in, std::vector<float>& out, const Dims& d, int axis, const std::vector<double>& k) {
  const int r = static_cast<int>(k.size() / 2);
  const std::int64_t stride = axis == 0 ? 1 : axis == 1 ? d[0] : d[0] * d[1];
  const std::int64_t n = d[axis];
  out.resize(in.size());
  tbb::parallel_for(std::int64_t{0}, d[2], [&](std::int64_t z) {
    for (std::int64_t y = 0; y < d[1]; ++y)
      for (std::int64_t x = 0; x < d[0]; ++x) {
        const std::int64_t p[3] = {x, y, z};
        const std::int64_t base = x + d[0] * (y + d[1] * z) - p[axis] * stride;
        double s = 0;
        for (int t = -r; t <= r; ++t) {
          std::int64_t q = std::clamp<std::int64_t>(p[axis] - t, 0, n - 1);
          s += k[static_cast<std::size_t>(t + r)] * in[static_cast<std::size_t>(base + q * stride)];
        }
        out[static_cast<std::size_t>(x + d[0] * (y + d[1] * z))] = static_cast<float>(s);
      }
  });
}

}  // namespace

std::vector<std::int64_t> structural_analysis(const Volume& vol, const ReduceOptions& o, double* threshold_used, const Progress& progress) {
  if (!(o.threshold >= 0) || !std::isfinite(o.threshold))
    throw OptionError("threshold", fmt::format("must be a non-negative number, got {}", o.threshold));
  const Dims dm = vol.dims;
  if (o.gradient == GradientOperator::central) {
    return visit_values(vol, [&]<class T>(std::span<const T> vals) {
      const T* v = vals.data();
      // Central differences inside, one-sided at the border (the border has one neighbour only).
      auto grad = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
        const std::int64_t p[3] = {x, y, z}, stride[3] = {1, dm[0], dm[0] * dm[1]};
        const std::int64_t i = x + dm[0] * (y + dm[1] * z);
        Grad g{};
        for (int a = 0; a < 3; ++a) {
          if (dm[a] == 1) continue;
          if (p[a] == 0)
            g[a] = static_cast<double>(v[i + stride[a]]) - static_cast<double>(v[i]);
          else if (p[a] == dm[a] - 1)
            g[a] = static_cast<double>(v[i]) - static_cast<double>(v[i - stride[a]]);
          else
            g[a] = 0.5 * (static_cast<double>(v[i + stride[a]]) - static_cast<double>(v[i - stride[a]]));
        }
        return g;
      };
      double t = o.threshold;
      if (o.relative) t *= max_gradient(dm, grad);
      if (threshold_used) *threshold_used = t;
      return suppress(dm, t, grad, progress);
    });
  }
  // Canny: derivative-of-Gaussian kernels, normalised so that a unit ramp has derivative 1.
  if (!(o.sigma > 0) || o.sigma > 100) throw OptionError("sigma", fmt::format("must be in (0, 100], got {}", o.sigma));
  int ks = o.kernel > 0 ? o.kernel : 2 * static_cast<int>(std::ceil(3 * o.sigma)) + 1;
  if (ks % 2 == 0 || ks < 3 || ks > 401) throw OptionError("kernel", fmt::format("must be odd and between 3 and 401, got {}", ks));
  const int r = ks / 2;
  std::vector<double> G(static_cast<std::size_t>(ks)), D(static_cast<std::size_t>(ks));
  double gs = 0, ds = 0;
  for (int t = -r; t <= r; ++t) {
    double g = std::exp(-0.5 * t * t / (o.sigma * o.sigma));
    G[static_cast<std::size_t>(t + r)] = g;
    D[static_cast<std::size_t>(t + r)] = -t * g;
    gs += g;
  }
  for (int t = -r; t <= r; ++t) ds += -t * D[static_cast<std::size_t>(t + r)];  // response to f(x) = x (convolution)
  for (auto& g : G) g /= gs;
  for (auto& x : D) x /= -ds;
  std::vector<float> f(static_cast<std::size_t>(vol.voxel_count()));
  visit_values(vol, [&]<class T>(std::span<const T> vals) {
    tbb::parallel_for(std::size_t{0}, vals.size(), [&](std::size_t i) { f[i] = static_cast<float>(vals[i]); });
  });
  report(progress, "reduce: canny", 0.1);
  std::vector<float> a, b, gx, gy, gz;
  convolve_axis(f, a, dm, 2, G);   // a = Gz * f
  convolve_axis(a, b, dm, 1, G);   // b = Gy Gz f
  convolve_axis(b, gx, dm, 0, D);  // gx = D_x Gy Gz f
  convolve_axis(a, b, dm, 1, D);   // b = D_y Gz f
  convolve_axis(b, gy, dm, 0, G);  // gy = Gx D_y Gz f
  convolve_axis(f, a, dm, 0, G);   // a = Gx f
  convolve_axis(a, b, dm, 1, G);   // b = Gx Gy f
  convolve_axis(b, gz, dm, 2, D);  // gz = Gx Gy D_z f
  report(progress, "reduce: canny", 0.6);
  std::vector<float>().swap(f);
  std::vector<float>().swap(a);
  std::vector<float>().swap(b);
  auto grad = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    std::size_t i = static_cast<std::size_t>(x + dm[0] * (y + dm[1] * z));
    return Grad{gx[i], gy[i], gz[i]};
  };
  double t = o.threshold;
  if (o.relative) t *= max_gradient(dm, grad);
  if (threshold_used) *threshold_used = t;
  return suppress(dm, t, grad, progress);
}

}  // namespace adaptiso
