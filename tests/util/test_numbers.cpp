// Numbers as people type them and as messages print them (issue 41, item 10): decimal only, in the
// command line and the viewer's URL alike; absurd magnitudes printed in a few digits.
#include <gtest/gtest.h>

#include <cfloat>
#include <cstdint>
#include <limits>

#include "adaptiso/error.hpp"
#include "adaptiso/number.hpp"
#include "util/memory.hpp"
#include "view/request.hpp"

using namespace adaptiso;

// strtod read "0x10" as 16 (and "0x1p4", "infinity"): iso=0x10 in the viewer's URL was 16.
TEST(Numbers, HexadecimalIsNoNumberInTheCommandLineOrTheViewer) {
  for (const char* s : {"0x10", "0X10", "0x1p4", "-0x8", "infinity", "nan", "1e", ".", "", " 1", "1 ", "1,5", "+-1"}) {
    EXPECT_FALSE(parse_finite(s)) << s;
    EXPECT_THROW(detail::parse_iso({{"iso", s}}), detail::BadRequest) << s;
  }
  for (auto [s, x] : std::initializer_list<std::pair<const char*, double>>{
           {"16", 16}, {"-2.5", -2.5}, {"+1e3", 1e3}, {".5", 0.5}, {"5.", 5}, {"1E-2", 1e-2}, {"1e-320", 1e-320}}) {
    EXPECT_EQ(parse_finite(s), x) << s;
    EXPECT_EQ(detail::parse_iso({{"iso", s}}), x) << s;
  }
  EXPECT_THROW(detail::parse_optional({{"error", "0x1"}}, "error"), detail::BadRequest);
  // A file's list of numbers: hexadecimal refused too; nan and inf kept for the reader to refuse
  // by name (a NaN spacing).
  EXPECT_THROW(parse_number_list("8 0x10 8", 3, "sizes"), InputError);
  EXPECT_EQ(parse_number_list("1, nan,Inf", 3, "spacings").size(), 3u);
}

// An estimate from absurd counts printed every digit of its magnitude (DBL_MAX has 309).
TEST(Numbers, MessagesPrintAbsurdMagnitudesInAFewDigits) {
  EXPECT_LE(detail::duration_text(DBL_MAX).size(), 12u) << detail::duration_text(DBL_MAX);
  EXPECT_EQ(detail::duration_text(9000), "2.5 h");
  try {
    detail::check_memory(std::numeric_limits<std::uint64_t>::max(), "this work", "", "do less");
    FAIL() << "2^64 bytes fit";
  } catch (const InputError& e) {
    EXPECT_LE(std::string(e.what()).size(), 100u) << e.what();
  }
}
