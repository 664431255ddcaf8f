// adaptiso — adaptive iso-surface generation (Lürig & Ertl). Thin front end: parses options,
// calls the library, maps exceptions to exit codes (2: bad input or usage, 1: internal failure).
#include <fmt/format.h>

#include <iostream>

#include "adaptiso/error.hpp"
#include "adaptiso/version.hpp"
#include "cli_common.hpp"

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
    std::cerr << "adaptiso: " << e.what() << " (see adaptiso --help)\n";
    return 2;
  } catch (const adaptiso::OptionError& e) {
    std::cerr << "adaptiso: " << adaptiso::cli::flag_for(e.option()) << ": " << e.detail() << "\n";
    return 2;
  } catch (const adaptiso::InputError& e) {
    std::cerr << "adaptiso: " << e.what() << "\n";
    return 2;
  } catch (const std::bad_alloc&) {
    std::cerr << "adaptiso: out of memory\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "adaptiso: internal error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
