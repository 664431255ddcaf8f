// One libFuzzer target per volume format, chosen at compile time (FUZZ_FORMAT, see
// CMakeLists.txt): the input becomes a file of that format and goes through read_volume.
#include <zlib.h>

#include <string>

#include "adaptiso/volume_io.hpp"
#include "fuzz_util.hpp"

namespace {

// gzip of `in`, so the fuzzer mutates what is inside the stream and not only the stream.
std::string gzip(std::string_view in) {
  z_stream zs{};
  deflateInit2(&zs, 1, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY);
  std::string out(deflateBound(&zs, in.size()), '\0');
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in.data()));
  zs.avail_in = static_cast<uInt>(in.size());
  zs.next_out = reinterpret_cast<Bytef*>(out.data());
  zs.avail_out = static_cast<uInt>(out.size());
  deflate(&zs, Z_FINISH);
  out.resize(zs.total_out);
  deflateEnd(&zs);
  return out;
}

std::string input_file(std::string_view in) {
  using fuzz::write;
  const std::string format = FUZZ_FORMAT;
  if (format == "nrrd") return write("v.nrrd", in);
  if (format == "nhdr") {
    auto [header, data] = fuzz::split_at_nul(in);
    write("data.raw", data);
    write("data.raw.gz", gzip(data));
    write("s1.raw", data);
    write("s2.raw", data);
    return write("v.nhdr", header);
  }
  if (format == "nifti") return write("v.nii", in);
  if (format == "nifti_gz") {
    // First byte even: the rest is the .nii inside a sound gzip stream; odd: the stream itself.
    if (in.empty()) return write("v.nii.gz", in);
    return write("v.nii.gz", (in[0] & 1) ? std::string(in.substr(1)) : gzip(in.substr(1)));
  }
  if (format == "metaimage") {
    auto [header, data] = fuzz::split_at_nul(in);
    if (data.empty()) return write("v.mha", in);
    write("data.raw", data);
    write("s1.raw", data);
    write("s2.raw", data);
    return write("v.mhd", header);
  }
  if (format == "vti") return write("v.vti", in);
  if (format == "vtk") return write("v.vtk", in);
  if (format == "dicom") return write("v.dcm", in);
  __builtin_trap();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = input_file(fuzz::as_view(data, size));
  fuzz::expect_input_error_or_success([&] { adaptiso::read_volume(path); });
  return 0;
}
