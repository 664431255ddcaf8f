// Will a stage's arrays fit? Work that cannot fit in memory is refused before it starts, with an
// estimate, rather than ending in the out-of-memory killer hours later.
#pragma once
#include <cstdint>
#include <string>

namespace adaptiso::detail {

// Memory the system can give this process now (Linux: MemAvailable, and no more than the address
// space `ulimit -v` leaves; elsewhere the physical memory), and no more than the memory limit
// (adaptiso/memory.hpp) leaves beside what the process holds (resident).
std::uint64_t available_memory();

// A memory field of /proc/self/status ("VmHWM", "VmSize", …: kB there) in bytes; 0 where there is
// none (other systems).
std::uint64_t process_status_bytes(const std::string& field);

// Returns the heap's free memory to the system (glibc's malloc_trim; nothing elsewhere): what a
// stage freed in the worker threads' arenas otherwise stays resident beside the next stage's.
void release_free_heap();

// "17 s", "3 min", "2.5 h".
std::string duration_text(double seconds);

// Throws OptionError(option, "<what> needs about X GB, Y GB are available; <advice>") when `bytes`
// exceed the available memory (InputError when no option can help: option empty).
void check_memory(std::uint64_t bytes, const std::string& what, const std::string& option, const std::string& advice);

}  // namespace adaptiso::detail
