// The PLY reader (compare's inputs).
#include "adaptiso/mesh_io.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = fuzz::write("m.ply", fuzz::as_view(data, size));
  fuzz::expect_input_error_or_success([&] { adaptiso::read_ply(path); });
  return 0;
}
