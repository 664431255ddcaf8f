// Raw samples with their description from the command line: the first 8 bytes choose the
// dimensions, type, byte order and header bytes (as a user's flags would), the rest is the file.
#include "adaptiso/volume_io.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 8) return 0;
  adaptiso::RawOptions raw;
  raw.dims = {data[0] % 17, data[1] % 17, data[2] % 17};  // 0 included: refused, never divided by
  raw.type = static_cast<adaptiso::ScalarType>(data[3] % 8);
  raw.big_endian = data[4] & 1;
  raw.header_bytes = data[5];
  raw.spacing = {1.0 + data[6] % 3, 1.0, data[7] == 255 ? 0.0 : 1.0};
  const std::string path = fuzz::write("v.raw", fuzz::as_view(data + 8, size - 8));
  fuzz::expect_input_error_or_success([&] { adaptiso::read_raw(path, raw); });
  return 0;
}
