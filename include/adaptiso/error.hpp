// adaptiso/error.hpp — the two kinds of failure the library reports.
//
// InputError: the input (a file, a parameter, a request) cannot be used; the message is one line
// that names the file or parameter and what is wrong. The CLI turns it into exit code 2.
// Any other exception is an internal failure (exit code 1).
#pragma once
#include <stdexcept>
#include <string>

namespace adaptiso {

class InputError : public std::runtime_error {
public:
  explicit InputError(const std::string& what) : std::runtime_error(what) {}
};

}  // namespace adaptiso
