// Built-in volumes (see synthetic.hpp); the sphere follows Lürig & Ertl §3.
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §3 (the sphere).
#include "adaptiso/synthetic.hpp"
#include "util/memory.hpp"

#include <tbb/parallel_for.h>

#include <fmt/format.h>
#include <cmath>
#include <functional>
#include <numbers>
#include <random>

namespace adaptiso {

std::vector<std::string> synthetic_names() { return {"sphere", "marschner-lobb", "linear", "noise", "torus"}; }

ScalarType synthetic_default_type(const std::string& name) { return name == "sphere" ? ScalarType::i16 : ScalarType::f32; }

Volume make_synthetic(const std::string& name, std::int64_t n, ScalarType type) {
  if (n < 2 || n > 4096) throw OptionError("size", fmt::format("{} must be between 2 and 4096", n));
  const auto bytes = static_cast<std::uint64_t>(n) * n * n * scalar_size(type);
  detail::check_memory(bytes, fmt::format("a {}³ {} volume", n, scalar_name(type)), "size", "give a smaller size");
  Volume v = make_volume({n, n, n}, type);
  const bool is_int = type != ScalarType::f32 && type != ScalarType::f64;
  const double c = (n - 1) / 2.0;
  std::function<double(std::int64_t, std::int64_t, std::int64_t)> f;
  if (name == "sphere") {
    const double R = n / 4.0;
    f = [=](auto i, auto j, auto k) {
      double r = std::sqrt((i - c) * (i - c) + (j - c) * (j - c) + (k - c) * (k - c));
      return r <= R ? 1000.0 : 1000.0 * R / r;
    };
  } else if (name == "marschner-lobb") {
    const double scale = !is_int ? 1.0 : (type == ScalarType::u8 || type == ScalarType::i8) ? 127.0 : 1000.0;
    f = [=](auto i, auto j, auto k) {
      double x = 2.0 * i / (n - 1) - 1, y = 2.0 * j / (n - 1) - 1, z = 2.0 * k / (n - 1) - 1;
      constexpr double fm = 6, alpha = 0.25, pi = std::numbers::pi;
      double r = std::sqrt(x * x + y * y);
      double rho = std::cos(2 * pi * fm * std::cos(pi * r / 2));
      return scale * (1 - std::sin(pi * z / 2) + alpha * (1 + rho)) / (2 * (1 + alpha));
    };
  } else if (name == "linear") {
    f = [](auto i, auto j, auto k) { return 1.0 * i + 2.0 * j + 3.0 * k; };
  } else if (name == "torus") {
    const double Rm = n / 4.0, rm = n / 10.0;
    f = [=](auto i, auto j, auto k) {
      double x = i - c, y = j - c, z = k - c;
      double q = std::sqrt(x * x + y * y) - Rm;
      double d = std::sqrt(q * q + z * z) - rm;  // signed distance to the torus surface
      return 1000.0 / (1.0 + std::exp(d / 1.5));
    };
  } else if (name == "noise") {
    std::mt19937_64 rng(12345);
    std::uniform_real_distribution<double> u(0, 1000);
    for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, u(rng));
    return v;
  } else {
    throw InputError(fmt::format("generate: unknown volume '{}' (known: sphere, marschner-lobb, linear, noise, torus)", name));
  }
  tbb::parallel_for(std::int64_t{0}, n, [&](std::int64_t k) {
    for (std::int64_t j = 0; j < n; ++j)
      for (std::int64_t i = 0; i < n; ++i) v.set(v.index(i, j, k), f(i, j, k));
  });
  return v;
}

}  // namespace adaptiso
