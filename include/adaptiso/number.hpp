// adaptiso/number.hpp — parsing numbers typed by a user (command line, URL parameter, header field).
#pragma once
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace adaptiso {

// The whole string as a finite decimal number, or nothing ("1e999", "nan", "12x", "0x10", " 1", ""
// are nothing). Subnormal numbers such as 1e-320 are finite and accepted.
std::optional<double> parse_finite(const std::string& s);

// Numbers separated by whitespace or commas; throws InputError naming `what` when a token is not
// a decimal number (nan, inf and infinity are kept, for the caller to refuse by name; hexadecimal
// is not a number) or the count differs from `expected` (expected < 0: any count).
std::vector<double> parse_number_list(std::string_view s, int expected, const std::string& what);

}  // namespace adaptiso
