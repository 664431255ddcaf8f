// adaptiso — adaptive iso-surface generation (Lürig & Ertl). Thin front end: parses options,
// calls the library, maps exceptions to exit codes (2: bad input or usage, 1: internal failure).
#include <fmt/format.h>

#include <chrono>
#include <filesystem>
#include <iostream>
#include <string_view>
#include <thread>

#include "adaptiso/error.hpp"
#include "adaptiso/version.hpp"
#include "cli_common.hpp"
#include "ranks.hpp"

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

// The first word that is no option: the command.
std::string_view command_of(int argc, char** argv) {
  for (int i = 1; i < argc; ++i)
    if (argv[i][0] != '-') return argv[i];
  return {};
}

// The message of this rank's failure, left to rank 0 (see tell); empty when told.
std::string left_to_rank_0;

void tell_as_this_rank(const adaptiso::cli::Ranks& ranks, const std::string& message) {
  std::cerr << "adaptiso (rank " << ranks.rank() << "): " << message << "\n";
}

// Prints a failure. Under mpirun a failure every rank meets alike (a usage or input error: every
// rank reads the same options and volume) is told once, by rank 0; others name their rank.
void tell(const std::string& message, bool same_on_every_rank) {
  const adaptiso::cli::Ranks* ranks = adaptiso::cli::Ranks::started();
  if (!ranks || ranks->root())
    std::cerr << "adaptiso: " << message << "\n";
  else if (same_on_every_rank)
    left_to_rank_0 = message;
  else
    tell_as_this_rank(*ranks, message);
}
}  // namespace

int run(int argc, char** argv) {
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
    // Under mpirun: MPI starts here (or a build without it refuses); prepare shares out its bricks
    // and selection, extract its iso-values, view its surfaces within a distance.
    const adaptiso::cli::Ranks& ranks = adaptiso::cli::Ranks::world();
    if (const std::string command(command_of(argc, argv));
        ranks.distributed() && command != "prepare" && command != "extract" && command != "view")
      throw adaptiso::InputError(fmt::format(
          "only 'adaptiso prepare', 'adaptiso extract' and 'adaptiso view' run over MPI ranks; run '{}' without mpirun", command));
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    tell(one_line(e.what()) + " (see adaptiso --help)", true);
    return 2;
  } catch (const adaptiso::cli::RankInputError& e) {
    tell(one_line(e.what()), false);
    return 2;
  } catch (const adaptiso::OptionError& e) {
    tell(adaptiso::cli::flag_for(e.option()) + ": " + one_line(e.detail()), true);
    return 2;
  } catch (const adaptiso::InputError& e) {
    tell(one_line(e.what()), true);
    return 2;
  } catch (const std::filesystem::filesystem_error& e) {
    // The system refused a path the user gave (too long, a loop of links): their input, exit 2.
    tell(one_line(e.path1().string()) + ": " + e.code().message(), true);
    return 2;
  } catch (const std::bad_alloc&) {
    tell("out of memory", false);
    return 1;
  } catch (const std::exception& e) {
    tell("internal error: " + one_line(e.what()), false);
    return 1;
  }
  return 0;
}

int main(int argc, char** argv) {
  const int code = run(argc, argv);
  // A failure on one rank stops the others (they may wait for it in a collective). One that rank
  // 0 meets too gives it time to say so first: the first rank to abort ends every other one. A
  // rank still running after that met it alone (its own memory limit, say): it tells it.
  if (code != 0 && !left_to_rank_0.empty()) {
    std::this_thread::sleep_for(std::chrono::seconds(3));
    tell_as_this_rank(*adaptiso::cli::Ranks::started(), left_to_rank_0);
  }
  if (code != 0) adaptiso::cli::Ranks::abort_if_distributed(code);
  return code;
}
