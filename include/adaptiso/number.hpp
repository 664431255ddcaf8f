// adaptiso/number.hpp — parsing a number typed by a user (command line, URL parameter).
#pragma once
#include <cmath>
#include <optional>
#include <string>

namespace adaptiso {

// The whole string as a finite double, or nothing ("1e999", "nan", "12x", "" are nothing).
inline std::optional<double> parse_finite(const std::string& s) {
  std::size_t used = 0;
  double x = 0;
  try {
    x = std::stod(s, &used);
  } catch (const std::exception&) {
    return std::nullopt;
  }
  if (s.empty() || used != s.size() || !std::isfinite(x)) return std::nullopt;
  return x;
}

}  // namespace adaptiso
