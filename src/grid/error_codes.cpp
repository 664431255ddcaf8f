// The hierarchy's one-byte error codes (bisection.hpp: ErrorCodes): 16 steps an octave below the
// scale, rounded up, so a code never stands for less than the error it codes. Used by the error
// hierarchy, the selection and coarsening, the queries, and the prepared grid's floored levels.
#include <algorithm>
#include <cmath>
#include <limits>

#include "adaptiso/bisection.hpp"

namespace adaptiso {

std::uint8_t ErrorCodes::code(double e) const {
  if (!(e > zero)) return 0;
  if (!std::isfinite(e)) return kForced;
  if (e >= scale) return 254;
  int c = static_cast<int>(std::ceil(254 + 16 * std::log2(e / scale)));
  c = std::clamp(c, 1, 254);
  while (c < 254 && error(static_cast<std::uint8_t>(c)) < e) ++c;  // rounding of log2 and exp2
  while (c > 1 && error(static_cast<std::uint8_t>(c - 1)) >= e) --c;
  return static_cast<std::uint8_t>(c);
}

double ErrorCodes::error(std::uint8_t c) const {
  if (c == 0) return zero;
  if (c == kForced) return std::numeric_limits<double>::infinity();
  return scale * std::exp2((static_cast<int>(c) - 254) / 16.0);
}

std::uint8_t ErrorCodes::threshold(double bound) const {
  int c = 0;
  while (c < 254 && error(static_cast<std::uint8_t>(c + 1)) <= bound) ++c;
  return static_cast<std::uint8_t>(c);
}

}  // namespace adaptiso
