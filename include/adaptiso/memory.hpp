// adaptiso/memory.hpp — the most memory a process may hold. Every stage estimates what it will
// allocate before it starts (reading a volume, the error hierarchy, the grid, the index, the
// viewer's surfaces) and refuses work that cannot fit with an InputError or OptionError naming
// the estimate, the memory available and the setting to change, instead of ending in the
// out-of-memory killer. Available is what the system can give now (Linux: MemAvailable, under
// `ulimit -v`), and no more than the limit leaves beside what the process holds (resident).
#pragma once
#include <cstdint>
#include <string>

namespace adaptiso {

// Bytes (0: none but the machine's). Without a call, the environment's ADAPTISO_MEMORY_LIMIT.
void set_memory_limit(std::uint64_t bytes);
std::uint64_t memory_limit();

// Refuses `bytes` more than can be had now: OptionError(option, "<what> needs about X MB, Y MB are
// available; <advice>"), InputError when option is empty (no setting of the work can help).
void require_memory(std::uint64_t bytes, const std::string& what, const std::string& option, const std::string& advice);

// This process's peak resident memory so far, in bytes (getrusage): what the ranks report.
std::uint64_t peak_resident_bytes();

}  // namespace adaptiso
