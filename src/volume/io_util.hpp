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
// Reads bytes [offset, offset+count) of a file; InputError if the file is shorter.
std::vector<unsigned char> read_bytes(const std::string& path, std::uint64_t offset, std::uint64_t count);
// Reads the whole file, refusing files above max_bytes.
std::string read_text(const std::string& path, std::uint64_t max_bytes);

// zlib or gzip stream (auto-detected) into exactly `expected` bytes; InputError naming `what`
// if the stream is corrupt, ends early, or holds more data than expected.
void inflate_exact(const unsigned char* src, std::size_t n, unsigned char* dst, std::size_t expected, const std::string& what);
// The largest number of bytes a deflate stream of `compressed` bytes can expand to.
inline std::uint64_t max_inflated_size(std::uint64_t compressed) { return compressed * 1040 + 1024; }

void byteswap(unsigned char* data, std::size_t element_size, std::size_t count);
bool host_is_little_endian();

std::string trim(std::string_view s);
std::string lower(std::string_view s);

}  // namespace adaptiso::detail
