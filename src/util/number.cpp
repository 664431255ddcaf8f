// Parsing user-typed numbers (see number.hpp).
#include "adaptiso/number.hpp"

#include <fmt/format.h>

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>

#include "adaptiso/error.hpp"

namespace adaptiso {
namespace {

// A decimal number as people type it: [+-] digits [. digits] [e|E [+-] digits], with digits on at
// least one side of the point. strtod alone also takes hexadecimal ("0x10" is 16, "0x1p4" too),
// "inf", "nan" and "infinity", which nobody means by an iso-value or a spacing.
bool is_decimal(std::string_view s) {
  std::size_t i = 0;
  auto digits = [&] {
    const std::size_t from = i;
    while (i < s.size() && std::isdigit(static_cast<unsigned char>(s[i]))) ++i;
    return i > from;
  };
  if (i < s.size() && (s[i] == '+' || s[i] == '-')) ++i;
  bool mantissa = digits();
  if (i < s.size() && s[i] == '.') {
    ++i;
    mantissa = digits() || mantissa;
  }
  if (!mantissa) return false;
  if (i < s.size() && (s[i] == 'e' || s[i] == 'E')) {
    ++i;
    if (i < s.size() && (s[i] == '+' || s[i] == '-')) ++i;
    if (!digits()) return false;
  }
  return i == s.size();
}

// The words for non-finite values that file formats write ("nan", "inf", "-Infinity"): a file's
// list keeps them for the reader to refuse by name (a NaN spacing), where a user's number cannot.
bool is_non_finite_word(std::string_view s) {
  if (!s.empty() && (s[0] == '+' || s[0] == '-')) s.remove_prefix(1);
  std::string w(s);
  for (char& c : w) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return w == "nan" || w == "inf" || w == "infinity";
}

}  // namespace

std::optional<double> parse_finite(const std::string& s) {
  if (!is_decimal(s)) return std::nullopt;
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
    if (end != tok.c_str() + tok.size() || tok.empty() || !(is_decimal(tok) || is_non_finite_word(tok)))
      throw InputError(fmt::format("{}: '{}' is not a number", what, tok.substr(0, 40)));
    out.push_back(v);
    i = j;
  }
  if (expected >= 0 && static_cast<int>(out.size()) != expected)
    throw InputError(fmt::format("{}: expected {} numbers, found {}", what, expected, out.size()));
  return out;
}

}  // namespace adaptiso
