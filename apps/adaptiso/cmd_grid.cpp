// adaptiso prepare / adaptiso export: build, save and convert the tetrahedral grid (§2.2–2.3).
#include <fmt/format.h>

#include <filesystem>
#include <iostream>

#include "adaptiso/grid_file.hpp"
#include "adaptiso/point_cloud.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/prepare_to_file.hpp"
#include "cli_common.hpp"
#include "options.hpp"

namespace adaptiso::cli {

void add_prepare(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "prepare", "Build the tetrahedral grid (bisection or Delaunay), its vertex gradients and the extraction index; save it (.adg)");
  auto in = std::make_shared<VolumeInput>();
  auto pf = std::make_shared<PrepareFlags>();
  auto out = std::make_shared<OutputFlags>();
  auto output = std::make_shared<std::string>();
  in->add(cmd);
  pf->add(cmd);
  out->add(cmd);
  cmd->add_option("-o,--output", *output, "Grid file (.adg)")->required();
  cmd->callback([=] {
    const PrepareOptions options = pf->options(in->path);  // a typo fails before the volume is read
    refuse_same_file(in->path, *output, "-o");
    auto t_all = Clock::now();
    Volume v = in->load();
    const double t_load = seconds_since(t_all);
    TerminalProgress tp(!out->quiet && !out->json);
    // Written as it is made: the voxels go before the index, the grid's positions and gradients
    // once they are on disk (the peak within the file plus 2.5 volumes).
    const PrepareStats st = prepare_to_file(std::move(v), options, *output, tp.callback());
    tp.finish();
    nlohmann::json j = nlohmann::json::parse(to_json(st));
    j["seconds"]["load"] = t_load;
    j["seconds"]["total"] = seconds_since(t_all);
    j["output"] = *output;
    j["bytes"] = std::filesystem::file_size(*output);
    if (out->json) return print_json(j);
    if (out->quiet) return;
    std::string stages;
    for (const auto& stage : st.stages) stages += fmt::format("{}{} {:.3f} s", stages.empty() ? "" : ", ", stage.name, stage.seconds);
    std::cout << fmt::format("kept {} of {} voxels, {} tetrahedra; {}\n{}\nwrote {}\n", st.kept, st.voxels, st.tetrahedra,
                             error_summary(st), stages, *output);
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
    const std::string ext = std::filesystem::path(*output).extension().string();
    if (ext != ".vtu" && ext != ".ply") throw InputError(fmt::format("{}: unknown output type '{}' (use .vtu or .ply)", *output, ext));
    auto t0 = Clock::now();
    const PreparedGrid p = load_grid(*input);
    const TetGrid& grid = p.grid;
    const double t_load = seconds_since(t0);
    if (ext == ".vtu")
      write_vtu(grid, *output);
    else
      write_points_ply(*output, grid);
    nlohmann::json j = {{"vertices", grid.vertex_count()},
                        {"tetrahedra", grid.tet_count()},
                        {"seconds", {{"load", t_load}, {"total", seconds_since(t0)}}},
                        {"output", *output}};
    if (out->json)
      print_json(j);
    else if (!out->quiet)
      std::cout << fmt::format("wrote {} ({} vertices, {} tetrahedra)\n", *output, grid.vertex_count(), grid.tet_count());
  });
}

}  // namespace adaptiso::cli
