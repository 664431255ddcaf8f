// Internal helpers shared by the readers: bounded file reads, inflate to an exact size, byte
// swapping, header-line parsing.
#pragma once
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "adaptiso/number.hpp"
#include "adaptiso/volume.hpp"

namespace adaptiso::detail {

std::uint64_t file_size_or_throw(const std::string& path);
// InputError when a file is shorter than offset + count bytes ("file is truncated: …").
void check_holds(const std::string& path, std::uint64_t offset, std::uint64_t count);
// InputError, before anything is allocated, when `bytes` read or decoded from a file cannot fit in
// the memory available ("<path>: reading it needs about X GB, Y GB are available; …").
void check_fits(const std::string& path, std::uint64_t bytes);
// Reads bytes [offset, offset+count) of a file; InputError if the file is shorter or the bytes
// cannot fit (check_fits).
std::vector<unsigned char> read_bytes(const std::string& path, std::uint64_t offset, std::uint64_t count);
// Reads the whole file, refusing files above max_bytes.
std::string read_text(const std::string& path, std::uint64_t max_bytes);

// zlib or gzip stream (auto-detected) into exactly `expected` bytes; InputError naming `what`
// if the stream is corrupt, ends early (a gzip stream must end with its CRC and length), or holds
// more data than expected (allow_trailing: the rest is decoded, checked and dropped).
void inflate_exact(const unsigned char* src, std::size_t n, unsigned char* dst, std::size_t expected, const std::string& what,
                   bool allow_trailing = false);
// The first (at most) max_out bytes a zlib/gzip stream decodes to; fewer when it ends or breaks.
std::vector<unsigned char> inflate_prefix(const unsigned char* src, std::size_t n, std::size_t max_out);
// The same as inflate_exact for a bzip2 stream.
void bunzip2_exact(const unsigned char* src, std::size_t n, unsigned char* dst, std::size_t expected, const std::string& what);
// Exactly `count` finite numbers separated by whitespace or commas (text-encoded data).
std::vector<double> parse_values(std::string_view text, std::size_t count, const std::string& what);
// The largest number of bytes a deflate stream of `compressed` bytes can expand to.
inline std::uint64_t max_inflated_size(std::uint64_t compressed) { return compressed * 1040 + 1024; }

// The whole number a header field holds; InputError naming `what` when it is not one or lies
// outside [lo, hi] (a cast of 1e300 to an integer would be undefined).
std::int64_t whole_number(double x, double lo, double hi, const std::string& what);

// "name%03d.raw min max [step]" (MetaImage, NRRD): one file per slice. The pattern comes from the
// file, so it is never used as a printf format: exactly one %d (optionally %0Nd, N ≤ 12) is
// accepted, the range must name at most `slices` files, and the names are built by hand.
std::vector<std::string> numbered_files(const std::string& pattern_and_range, std::int64_t slices, const std::string& what);

// What read_volume reads a path as (without raw options): by folder, extension, then the first
// bytes. Throws InputError for a path that does not exist.
enum class VolumeFormat { dicom, archive, nrrd, nifti, metaimage, vti, legacy_vtk, raw_samples, unknown };
VolumeFormat volume_format(const std::string& path);

void byteswap(unsigned char* data, std::size_t element_size, std::size_t count);
bool host_is_little_endian();

std::string trim(std::string_view s);
std::string lower(std::string_view s);

}  // namespace adaptiso::detail
