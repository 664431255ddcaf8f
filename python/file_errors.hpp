// File operations' errors in the Python module: an InputError (a file that cannot be read or
// written) becomes a FileError, which the module translates to OSError (adaptiso.read, load,
// save, prepare given a path); an OptionError (a bad argument) stays a ValueError. A FileError
// needs no GIL to be thrown, so the ranks of prepare(…, comm=…) report it like any other error.
#pragma once
#include <stdexcept>

#include "adaptiso/error.hpp"

namespace adaptiso::python {

struct FileError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

template <class F>
auto file_errors(F&& f) {
  try {
    return f();
  } catch (const OptionError&) {
    throw;
  } catch (const InputError& e) {
    throw FileError(e.what());
  }
}

}  // namespace adaptiso::python
