// The grid file loader (.adg): the format adaptiso writes itself, read back from any bytes.
#include "adaptiso/grid_file.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = fuzz::write("g.adg", fuzz::as_view(data, size));
  fuzz::expect_input_error_or_success([&] { adaptiso::load_grid(path); });
  return 0;
}
