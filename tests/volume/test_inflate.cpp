// inflate_exact: libdeflate decodes a whole stream, zlib diagnoses one it refuses. Both paths must
// give the same answers as zlib alone did: the bytes, bytes after the stream ignored, and the
// messages for a stream that is too long, cut short or corrupt.
#include <gtest/gtest.h>

#include <random>
#include <string>
#include <vector>

#include "adaptiso/error.hpp"
#include "test_util.hpp"
#include "volume/io_util.hpp"

namespace {

std::string sample(std::size_t n) {
  std::mt19937 rng(7);
  std::string s(n, '\0');
  for (std::size_t i = 0; i < n; ++i) s[i] = static_cast<char>(i % 97 < 60 ? i % 13 : rng() & 0xff);  // compressible, not trivially
  return s;
}

std::string inflate(const std::string& z, std::size_t expected, bool allow_trailing = false) {
  std::string out(expected, '\0');
  adaptiso::detail::inflate_exact(reinterpret_cast<const unsigned char*>(z.data()), z.size(), reinterpret_cast<unsigned char*>(out.data()),
                                  expected, "t", allow_trailing);
  return out;
}

std::string refusal(const std::string& z, std::size_t expected) {
  try {
    inflate(z, expected);
  } catch (const adaptiso::InputError& e) {
    return e.what();
  }
  return "accepted";
}

}  // namespace

TEST(InflateExact, GzipAndZlibStreamsDecodeToTheirBytesAndBytesAfterTheStreamAreIgnored) {
  for (std::size_t n : {std::size_t{0}, std::size_t{1}, std::size_t{1000}, std::size_t{3} << 20}) {
    const std::string s = sample(n);
    for (bool gzip : {true, false}) {
      const std::string z = testutil::compress(s, gzip);
      EXPECT_EQ(inflate(z, n), s) << n << (gzip ? " gzip" : " zlib");
      EXPECT_EQ(inflate(z + "trailing bytes", n), s) << n << (gzip ? " gzip" : " zlib");
    }
  }
}

TEST(InflateExact, AStreamLongerThanExpectedIsRefusedUnlessTrailingOutputIsAllowed) {
  const std::string s = sample(5000);
  for (bool gzip : {true, false}) {
    const std::string z = testutil::compress(s, gzip);
    EXPECT_NE(refusal(z, 4000).find("more than the expected 4000 bytes"), std::string::npos) << refusal(z, 4000);
    EXPECT_EQ(inflate(z, 4000, /*allow_trailing=*/true), s.substr(0, 4000));
  }
}

TEST(InflateExact, AShortCutOrCorruptStreamIsRefusedWithZlibsDiagnosis) {
  const std::string s = sample(100000);
  for (bool gzip : {true, false}) {
    const std::string z = testutil::compress(s, gzip);
    EXPECT_NE(refusal(z, 200000).find("holds 100000 bytes, expected 200000"), std::string::npos) << refusal(z, 200000);
    EXPECT_NE(refusal(z.substr(0, z.size() / 2), 100000).find("cut short"), std::string::npos);
    std::string bad = z;
    bad[bad.size() / 2] = static_cast<char>(bad[bad.size() / 2] ^ 0x55);
    EXPECT_NE(refusal(bad, 100000).find("t: compressed"), std::string::npos) << refusal(bad, 100000);
  }
}
