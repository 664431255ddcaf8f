// adaptiso prepare / adaptiso export: build, save and convert the tetrahedral grid (§2.2–2.3).
#include <fmt/format.h>

#include <filesystem>
#include <iostream>

#include "adaptiso/gradients.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/point_cloud.hpp"
#include "adaptiso/tetrahedralize.hpp"
#include "cli_common.hpp"
#include "reduce_options.hpp"

namespace adaptiso::cli {

void add_prepare(CLI::App& app) {
  auto* cmd = app.add_subcommand("prepare", "Reduce, tetrahedralize and compute gradients; save the grid (.adg)");
  auto in = std::make_shared<VolumeInput>();
  auto rf = std::make_shared<ReduceFlags>();
  auto out = std::make_shared<OutputFlags>();
  auto output = std::make_shared<std::string>();
  auto sequential = std::make_shared<bool>(false);
  in->add(cmd);
  rf->add(cmd);
  out->add(cmd);
  cmd->add_option("-o,--output", *output, "Grid file (.adg)")->required();
  cmd->add_flag("--sequential-delaunay", *sequential, "Use CGAL's sequential triangulation (the parallel one is the default)");
  cmd->callback([=] {
    auto t_all = Clock::now();
    Volume v = in->load();
    double t_load = seconds_since(t_all);
    TerminalProgress tp(!out->quiet && !out->json);
    auto cb = tp.callback();
    ReduceOptions o = rf->options();
    auto t0 = Clock::now();
    ReduceResult r = reduce(v, o, cb);
    double t_reduce = seconds_since(t0);
    TetGrid g;
    auto range = value_range(v);
    g.source = {v.dims, v.spacing, v.origin, v.direction, std::string(scalar_name(v.type)), range.min, range.max,
                rf->method, r.max_error, r.threshold, in->path};
    t0 = Clock::now();
    TetrahedralizeOptions topt;
    topt.parallel = !*sequential;
    tetrahedralize(v, r.kept, g, topt, cb);
    double t_tet = seconds_since(t0);
    t0 = Clock::now();
    {
      VertexRings rings = vertex_rings(g);
      compute_gradients(g, rings, cb);
    }
    double t_grad = seconds_since(t0);
    t0 = Clock::now();
    ReconstructionError pl = piecewise_linear_error(v, g, cb);
    double t_pl = seconds_since(t0);
    tp.finish();
    nlohmann::json j = {{"voxels", v.voxel_count()},
                        {"kept", g.vertex_count()},
                        {"ratio", static_cast<double>(g.vertex_count()) / static_cast<double>(v.voxel_count())},
                        {"tetrahedra", g.tet_count()},
                        {"max_error", r.max_error},
                        {"pl_max_error", pl.max},
                        {"pl_rms_error", pl.rms},
                        {"seconds", {{"load", t_load}, {"reduce", t_reduce}, {"tetrahedralize", t_tet}, {"gradients", t_grad}, {"pl_error", t_pl}}}};
    t0 = Clock::now();
    save_grid(g, *output, nlohmann::json{{"prepare", j}}.dump());
    j["seconds"]["save"] = seconds_since(t0);
    j["seconds"]["total"] = seconds_since(t_all);
    j["output"] = *output;
    j["bytes"] = std::filesystem::file_size(*output);
    if (out->json) return print_json(j);
    if (out->quiet) return;
    std::cout << fmt::format("kept {} of {} voxels, {} tetrahedra; piecewise-linear error max {:.6g} rms {:.6g} (bound {:.6g})\n",
                             g.vertex_count(), v.voxel_count(), g.tet_count(), pl.max, pl.rms, r.max_error)
              << fmt::format("reduce {:.3f} s, tetrahedralize {:.3f} s, gradients {:.3f} s\nwrote {}\n", t_reduce, t_tet, t_grad, *output);
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
      Volume geo;
      geo.dims = g.source.dims;
      geo.spacing = g.source.spacing;
      geo.origin = g.source.origin;
      geo.direction = g.source.direction;
      geo.type = ScalarType::f64;
      // The point cloud writer reads values from a volume; build a sparse stand-in of the vertices.
      std::vector<std::int64_t> kept(g.vertex_count());
      Volume vals = geo;
      vals.bytes.assign(static_cast<std::size_t>(geo.dims[0] * geo.dims[1] * geo.dims[2]) * 8, 0);
      for (std::size_t i = 0; i < g.vertex_count(); ++i) {
        kept[i] = geo.index(g.ijk[i][0], g.ijk[i][1], g.ijk[i][2]);
        vals.set(kept[i], g.values[i]);
      }
      std::sort(kept.begin(), kept.end());
      write_points_ply(*output, vals, kept);
    } else {
      throw InputError(fmt::format("{}: unknown output type '{}' (use .vtu or .ply)", *output, ext));
    }
    nlohmann::json j = {{"vertices", g.vertex_count()}, {"tetrahedra", g.tet_count()}, {"seconds", {{"load", t_load}, {"total", seconds_since(t0)}}}, {"output", *output}};
    if (out->json) print_json(j);
    else if (!out->quiet) std::cout << fmt::format("wrote {} ({} vertices, {} tetrahedra)\n", *output, g.vertex_count(), g.tet_count());
  });
}

}  // namespace adaptiso::cli
