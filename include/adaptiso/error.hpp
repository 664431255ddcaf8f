// adaptiso/error.hpp — the kinds of failure the library reports.
//
// InputError: the input (a file, a parameter, a request) cannot be used; the message is one line
// that names the file or parameter and what is wrong. The CLI turns it into exit code 2, the
// Python module into ValueError (OSError for files).
// OptionError: an InputError about one option of a library call; `option()` is its name as the
// library spells it (e.g. "max_error"), and the message does not repeat it, so each front end can
// name the option its own way ("--max-error" on the command line, "max_error=" in Python).
// Any other exception is an internal failure (exit code 1).
#pragma once
#include <stdexcept>
#include <string>

namespace adaptiso {

class InputError : public std::runtime_error {
public:
  explicit InputError(const std::string& what) : std::runtime_error(what) {}
};

class OptionError : public InputError {
public:
  OptionError(std::string option, const std::string& what) : InputError(option + ": " + what), option_(std::move(option)), detail_(what) {}
  const std::string& option() const { return option_; }
  const std::string& detail() const { return detail_; }  // the message without the option's name

private:
  std::string option_, detail_;
};

}  // namespace adaptiso
