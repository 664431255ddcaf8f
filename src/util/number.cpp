// Parsing user-typed numbers (see number.hpp).
#include "adaptiso/number.hpp"

#include <fmt/format.h>

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>

#include "adaptiso/error.hpp"

namespace adaptiso {

std::optional<double> parse_finite(const std::string& s) {
  if (s.empty() || std::isspace(static_cast<unsigned char>(s[0]))) return std::nullopt;
  // strtod, not stod: stod throws out_of_range for subnormals such as 1e-320, which are finite.
  char* end = nullptr;
  const double x = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size() || !std::isfinite(x)) return std::nullopt;
  return x;
}

std::vector<double> parse_number_list(std::string_view s, int expected, const std::string& what) {
  std::vector<double> out;
  std::size_t i = 0;
  auto separator = [](char c) { return std::isspace(static_cast<unsigned char>(c)) || c == ','; };
  while (i < s.size()) {
    while (i < s.size() && separator(s[i])) ++i;
    if (i >= s.size()) break;
    std::size_t j = i;
    while (j < s.size() && !separator(s[j])) ++j;
    std::string tok(s.substr(i, j - i));
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(tok.c_str(), &end);
    if (end != tok.c_str() + tok.size() || tok.empty()) throw InputError(fmt::format("{}: '{}' is not a number", what, tok.substr(0, 40)));
    out.push_back(v);
    i = j;
  }
  if (expected >= 0 && static_cast<int>(out.size()) != expected)
    throw InputError(fmt::format("{}: expected {} numbers, found {}", what, expected, out.size()));
  return out;
}

}  // namespace adaptiso
