// adaptiso view: prepare (or load) a grid and serve the interactive viewer page (README "Viewer").
#include <fmt/format.h>

#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <thread>

#include "adaptiso/grid_file.hpp"
#include "adaptiso/view_server.hpp"
#include "cli_common.hpp"
#include "pipeline.hpp"

#ifndef ADAPTISO_WEB_DIR
#define ADAPTISO_WEB_DIR "web"
#endif

namespace adaptiso::cli {

void add_view(CLI::App& app) {
  auto* cmd = app.add_subcommand("view", "Serve the interactive viewer for a volume (prepared on the fly) or a grid file (.adg)");
  auto in = std::make_shared<VolumeInput>();
  auto rf = std::make_shared<ReduceFlags>();
  auto pf = std::make_shared<PipelineFlags>();
  auto out = std::make_shared<OutputFlags>();
  auto opt = std::make_shared<ViewOptions>();
  in->add(cmd);
  rf->add(cmd);
  pf->add(cmd);
  out->add(cmd);
  cmd->add_option("--host", opt->host, "Address to listen on (default 127.0.0.1: reach it through an SSH tunnel)")->capture_default_str();
  cmd->add_option("--port", opt->port, "Port (0: any free port)")->capture_default_str()->check(CLI::Range(0, 65535));
  cmd->add_option("--web", opt->web_dir, "Folder of the viewer page (default: the source tree's web/, or $ADAPTISO_WEB)");
  cmd->callback([=] {
    ViewOptions o = *opt;
    if (o.web_dir.empty()) o.web_dir = std::getenv("ADAPTISO_WEB") ? std::getenv("ADAPTISO_WEB") : ADAPTISO_WEB_DIR;
    const bool is_grid = std::filesystem::path(in->path).extension() == ".adg";
    std::shared_ptr<const Volume> volume;
    std::shared_ptr<TetGrid> grid;
    std::shared_ptr<IntervalTree> index;
    nlohmann::json facts;
    // Read the input before serving, so an unreadable file fails at once with exit code 2.
    if (is_grid) {
      index = std::make_shared<IntervalTree>();
      std::string meta;
      grid = std::make_shared<TetGrid>(load_grid(in->path, &meta, index.get()));
      auto m = nlohmann::json::parse(meta, nullptr, false);
      if (!m.is_discarded() && m.contains("prepare")) facts = m["prepare"];
    } else {
      volume = std::make_shared<const Volume>(in->load());
    }
    ViewServer server(o);
    if (volume) server.set_volume(volume);
    if (grid) server.set_grid(grid, index, facts);
    const int port = server.bind();
    const std::string host = o.host == "0.0.0.0" ? "localhost" : o.host;
    std::cout << fmt::format("adaptiso view: serving http://{}:{}/  (Ctrl-C to stop)\n", host, port);
    if (o.host == "127.0.0.1" || o.host == "localhost")
      std::cout << fmt::format("from another machine: ssh -L {0}:localhost:{0} <this host>, then open http://localhost:{0}/\n", port);
    std::cout.flush();
    std::thread prep;
    if (volume) {
      prep = std::thread([&, volume] {
        try {
          TerminalProgress tp(!out->quiet && !out->json);
          auto term = tp.callback();
          Prepared p = prepare_grid(*volume, in->path, *rf, *pf, [&](std::string_view stage, double f) {
            server.set_progress(std::string(stage), f);
            if (term) term(stage, f);
          });
          tp.finish();
          auto g = std::make_shared<TetGrid>(std::move(p.grid));
          auto idx = std::make_shared<IntervalTree>(std::move(p.index));
          server.set_grid(g, idx, p.stats);
          if (!out->quiet)
            std::cout << fmt::format("ready: {} kept vertices, {} tetrahedra\n", g->vertex_count(), g->tet_count()) << std::flush;
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
