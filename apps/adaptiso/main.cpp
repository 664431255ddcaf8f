// adaptiso — adaptive iso-surface generation (Lürig & Ertl). Thin front end: parses options,
// calls the library, maps exceptions to exit codes (2: bad input or usage, 1: internal failure).
#include <fmt/format.h>

#include <filesystem>
#include <iostream>
#include <string_view>

#include "adaptiso/error.hpp"
#include "adaptiso/version.hpp"
#include "cli_common.hpp"

namespace {
// One line whatever the message quotes: a file name or argument with a newline or escape
// sequence must not split the message or drive the terminal.
std::string one_line(std::string_view s) {
  std::string r;
  r.reserve(s.size());
  for (char c : s) {
    const auto u = static_cast<unsigned char>(c);
    if (c == '\n')
      r += "\\n";
    else if (u < 0x20 || u == 0x7f)
      r += fmt::format("\\x{:02x}", u);
    else
      r += c;
  }
  return r;
}
}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"adaptiso: adaptive iso-surface generation from 3D scalar volumes (Lürig & Ertl)"};
  app.set_version_flag("--version", std::string("adaptiso ") + ADAPTISO_VERSION);
  app.require_subcommand(1);
  adaptiso::cli::add_info(app);
  adaptiso::cli::add_generate(app);
  adaptiso::cli::add_reduce(app);
  adaptiso::cli::add_prepare(app);
  adaptiso::cli::add_export(app);
  adaptiso::cli::add_extract(app);
  adaptiso::cli::add_run(app);
  adaptiso::cli::add_mc(app);
  adaptiso::cli::add_view(app);
  adaptiso::cli::add_compare(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << "adaptiso: " << one_line(e.what()) << " (see adaptiso --help)\n";
    return 2;
  } catch (const adaptiso::OptionError& e) {
    std::cerr << "adaptiso: " << adaptiso::cli::flag_for(e.option()) << ": " << one_line(e.detail()) << "\n";
    return 2;
  } catch (const adaptiso::InputError& e) {
    std::cerr << "adaptiso: " << one_line(e.what()) << "\n";
    return 2;
  } catch (const std::filesystem::filesystem_error& e) {
    // The system refused a path the user gave (too long, a loop of links): their input, exit 2.
    std::cerr << "adaptiso: " << one_line(e.path1().string()) << ": " << e.code().message() << "\n";
    return 2;
  } catch (const std::bad_alloc&) {
    std::cerr << "adaptiso: out of memory\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "adaptiso: internal error: " << one_line(e.what()) << "\n";
    return 1;
  }
  return 0;
}
