// adaptiso/atomic_file.hpp — every output is written to a temporary file beside the target and
// renamed over it only when complete, so a failure never leaves a half-written file.
#pragma once
#include <functional>
#include <ostream>
#include <string>

namespace adaptiso {

// Calls write(stream) on a temporary file in the target's folder, flushes, then renames it to
// `path`. On any exception (or a stream error) the temporary file is removed and InputError (for
// an unwritable path) or the original exception propagates.
void write_file_atomically(const std::string& path, const std::function<void(std::ostream&)>& write);

}  // namespace adaptiso
