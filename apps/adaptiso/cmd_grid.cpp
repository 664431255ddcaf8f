// adaptiso prepare / adaptiso export: build, save and convert the tetrahedral grid (§2.2–2.3).
#include <fmt/format.h>

#include <filesystem>
#include <iostream>

#include "adaptiso/gradients.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/interval_tree.hpp"
#include "adaptiso/point_cloud.hpp"
#include "adaptiso/tetrahedralize.hpp"
#include "cli_common.hpp"
#include "pipeline.hpp"
#include "reduce_options.hpp"

namespace adaptiso::cli {

void add_prepare(CLI::App& app) {
  auto* cmd = app.add_subcommand("prepare", "Reduce, tetrahedralize, compute gradients and the extraction index; save the grid (.adg)");
  auto in = std::make_shared<VolumeInput>();
  auto rf = std::make_shared<ReduceFlags>();
  auto pf = std::make_shared<PipelineFlags>();
  auto out = std::make_shared<OutputFlags>();
  auto output = std::make_shared<std::string>();
  in->add(cmd);
  rf->add(cmd);
  pf->add(cmd);
  out->add(cmd);
  cmd->add_option("-o,--output", *output, "Grid file (.adg)")->required();
  cmd->callback([=] {
    auto t_all = Clock::now();
    Volume v = in->load();
    double t_load = seconds_since(t_all);
    TerminalProgress tp(!out->quiet && !out->json);
    Prepared p = prepare_grid(v, in->path, *rf, *pf, tp.callback());
    tp.finish();
    nlohmann::json j = p.stats;
    j["seconds"]["load"] = t_load;
    auto t0 = Clock::now();
    save_grid(p.grid, *output, nlohmann::json{{"prepare", j}}.dump(), &p.index);
    j["seconds"]["save"] = seconds_since(t0);
    j["seconds"]["total"] = seconds_since(t_all);
    j["output"] = *output;
    j["bytes"] = std::filesystem::file_size(*output);
    if (out->json) return print_json(j);
    if (out->quiet) return;
    const auto& s = j["seconds"];
    std::cout << fmt::format("kept {} of {} voxels, {} tetrahedra; piecewise-linear error max {:.6g} rms {:.6g} (bound {:.6g})\n",
                             p.grid.vertex_count(), v.voxel_count(), p.grid.tet_count(), j["pl_max_error"].get<double>(),
                             j["pl_rms_error"].get<double>(), j["max_error"].get<double>())
              << fmt::format("reduce {:.3f} s, tetrahedralize {:.3f} s, gradients {:.3f} s, index {:.3f} s\nwrote {}\n",
                             s["reduce"].get<double>(), s["tetrahedralize"].get<double>(), s["gradients"].get<double>(),
                             s["index"].get<double>(), *output);
  });
}

void add_export(CLI::App& app) {
  auto* cmd = app.add_subcommand("export", "Write a grid (.adg) as VTK UnstructuredGrid (.vtu) or its vertices as PLY");
  auto input = std::make_shared<std::string>();
  auto output = std::make_shared<std::string>();
  auto out = std::make_shared<OutputFlags>();
  cmd->add_option("GRID", *input, "Grid file (.adg)")->required();
  cmd->add_option("-o,--output", *output, "Output .vtu or .ply")->required();
  out->add(cmd);
  cmd->callback([=] {
    auto t0 = Clock::now();
    TetGrid g = load_grid(*input);
    double t_load = seconds_since(t0);
    std::string ext = std::filesystem::path(*output).extension().string();
    if (ext == ".vtu") {
      write_vtu(g, *output);
    } else if (ext == ".ply") {
      write_points_ply(*output, g);
    } else {
      throw InputError(fmt::format("{}: unknown output type '{}' (use .vtu or .ply)", *output, ext));
    }
    nlohmann::json j = {{"vertices", g.vertex_count()}, {"tetrahedra", g.tet_count()}, {"seconds", {{"load", t_load}, {"total", seconds_since(t0)}}}, {"output", *output}};
    if (out->json) print_json(j);
    else if (!out->quiet) std::cout << fmt::format("wrote {} ({} vertices, {} tetrahedra)\n", *output, g.vertex_count(), g.tet_count());
  });
}

}  // namespace adaptiso::cli
