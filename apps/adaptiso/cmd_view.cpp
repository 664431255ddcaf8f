// adaptiso view: prepare (or load) a grid and serve the interactive viewer page (README "Viewer").
#include <fmt/format.h>
#include <unistd.h>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <optional>
#include <thread>

#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/view_server.hpp"
#include "cli_common.hpp"
#include "options.hpp"
#include "ranks.hpp"
#include "view_ranks.hpp"

namespace adaptiso::cli {
namespace {

// The page's folder: --web, else $ADAPTISO_WEB, else share/adaptiso/web beside the executable's
// folder (the installed layout, which the build tree mirrors).
std::string default_web_dir() {
  if (const char* env = std::getenv("ADAPTISO_WEB")) return env;
  std::error_code ec;
  const auto exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return "share/adaptiso/web";
  return (exe.parent_path().parent_path() / "share" / "adaptiso" / "web").string();
}

}  // namespace

void add_view(CLI::App& app) {
  auto* cmd = app.add_subcommand("view", "Serve the interactive viewer for a volume (prepared on the fly) or a grid file (.adg)");
  auto in = std::make_shared<VolumeInput>();
  auto pf = std::make_shared<PrepareFlags>();
  auto out = std::make_shared<OutputFlags>();
  auto opt = std::make_shared<ViewOptions>();
  in->add(cmd);
  pf->add(cmd);
  out->add(cmd);
  cmd->add_option("--host", opt->host, "Address to listen on (default 127.0.0.1: reach it through an SSH tunnel)")->capture_default_str();
  cmd->add_option("--port", opt->port, "Port (0: any free port)")->capture_default_str()->check(CLI::Range(0, 65535));
  cmd->add_option("--web", opt->web_dir, "Folder of the viewer page (default: share/adaptiso/web beside the program, or $ADAPTISO_WEB)");
  auto budget = std::make_shared<std::string>();
  auto* budget_option =
      cmd->add_option("--memory-budget", *budget,
                      "Resident memory the server may hold, grid included, in bytes (4000000000, 4G, 512M); beyond it idle surfaces and "
                      "levels of detail are dropped and requests that cannot fit are answered 503 (default: half of the machine's memory)");
  cmd->add_option("--idle-seconds", opt->idle_seconds,
                  "A page's surface unused this long is dropped, the levels of detail unused 5x as long")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_option("--allow-origin", opt->allowed_origins,
                  "Let web pages of this origin (http://host:port; * for any) use the API; others are refused (repeatable)");
  cmd->callback([=] {
    ViewOptions o = *opt;
    if (budget_option->count() > 0) o.memory_budget = parse_byte_size(*budget, "memory_budget");  // "" too is refused
    if (o.web_dir.empty()) o.web_dir = default_web_dir();
    const bool is_grid = std::filesystem::path(in->path).extension() == ".adg";
    std::shared_ptr<const Volume> volume;
    // Read the input before serving, so an unreadable file fails at once with exit code 2.
    std::shared_ptr<const PreparedGrid> grid;
    std::shared_ptr<const OpenGridFile> file;  // a bisection grid's tetrahedra are read when a route needs them
    std::optional<PrepareOptions> options;     // refused at once too, not in the background
    // Under mpirun every rank loads the grid (its checks shared out); rank 0 serves, the others
    // make the surfaces within a distance it hands them (view_ranks.hpp).
    Ranks& ranks = Ranks::world();
    if (ranks.distributed() && !is_grid)
      throw InputError(
          "'adaptiso view' over MPI ranks serves a grid file (.adg): prepare it first (mpirun -np N adaptiso prepare VOLUME -o "
          "GRID.adg), then view GRID.adg");
    if (ranks.distributed() && !ranks.serialized_threads())
      throw InputError(
          "'adaptiso view' over MPI ranks needs an MPI that lets a rank's threads call it one at a time (MPI_THREAD_SERIALIZED)");
    if (is_grid) {
      ShareTransport* share = ranks.distributed() ? &ranks : nullptr;
      file = std::make_shared<const OpenGridFile>(in->path, share);
      TerminalProgress tp(ranks.root() && !out->quiet && !out->json);
      grid = std::make_shared<const PreparedGrid>(file->load(GridParts::hierarchy_or_all, tp.callback(), share));
    } else {
      options = pf->options(in->path);
      volume = std::make_shared<const Volume>(in->load());
    }
    // The other ranks make surfaces within a distance, which only a bisection grid's hierarchy
    // gives: every rank read the same file, so every rank refuses alike.
    if (ranks.distributed() && !grid->hierarchy)
      throw InputError(
          fmt::format("{}: over MPI ranks 'adaptiso view' serves a bisection grid (this one keeps no hierarchy); run it "
                      "without mpirun",
                      in->path));
    if (!ranks.root()) {
      file.reset();
      const HierarchyQuery query(grid);
      answer_distance_queries(ranks, query);
      return;
    }
    std::optional<RankSurfaces> rank_surfaces;  // outlives the server, which calls its hook
    if (ranks.distributed()) {
      o.distance_surfaces = rank_surfaces.emplace(ranks).hook();
      o.ranks = ranks.size();
    }
    ViewServer server(o);
    if (volume) server.set_volume(volume);
    // Handed over: the server frees the part once it has read the whole, and closes the file.
    if (grid && loaded_in_part(*grid))
      server.set_grid(std::move(grid), [file] { return std::make_shared<const PreparedGrid>(file->load(GridParts::all)); });
    else if (grid)
      server.set_grid(std::move(grid));
    file.reset();
    const int port = server.bind();
    const std::string host = o.host == "0.0.0.0" ? "localhost" : o.host;
    std::cout << fmt::format("adaptiso view: serving http://{}:{}/  (Ctrl-C to stop; memory budget {:.2f} GB)\n", host, port,
                             static_cast<double>(server.memory_budget()) / 1e9);
    if (rank_surfaces)
      std::cout << fmt::format("surfaces within a distance are made by {} (rank 0 when {} busy)\n",
                               ranks.size() == 2 ? "rank 1" : fmt::format("ranks 1 to {}", ranks.size() - 1),
                               ranks.size() == 2 ? "it is" : "all are");
    if (o.host == "127.0.0.1" || o.host == "localhost")
      std::cout << fmt::format("from another machine: ssh -L {0}:localhost:{0} <this host>, then open http://localhost:{0}/\n", port);
    std::cout.flush();
    std::thread prep;
    if (volume) {
      prep = std::thread([&, volume] {
        try {
          TerminalProgress tp(!out->quiet && !out->json);
          auto term = tp.callback();
          auto p = std::make_shared<const PreparedGrid>(prepare(*volume, *options, [&](std::string_view stage, double f) {
            server.set_progress(std::string(stage), f);
            if (term) term(stage, f);
          }));
          tp.finish();
          server.set_grid(p);
          if (!out->quiet)
            std::cout << fmt::format("ready: {} kept vertices, {} tetrahedra\n", p->grid.vertex_count(), p->grid.tet_count()) << std::flush;
        } catch (const OptionError& e) {
          server.set_failed(fmt::format("{}: {}", flag_for(e.option()), e.detail()));
          std::cerr << "adaptiso: preparation failed: " << flag_for(e.option()) << ": " << e.detail() << "\n";
        } catch (const std::exception& e) {
          server.set_failed(e.what());
          std::cerr << "adaptiso: preparation failed: " << e.what() << "\n";
        }
      });
    }
    server.listen();
    if (prep.joinable()) prep.join();
  });
}

}  // namespace adaptiso::cli
