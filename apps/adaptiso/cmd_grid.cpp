// adaptiso prepare / adaptiso export: build, save and convert the tetrahedral grid (§2.2–2.3).
#include <fmt/format.h>
#include <tbb/global_control.h>

#include <filesystem>
#include <functional>
#include <iostream>
#include <optional>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/bisection_bricks.hpp"
#include "adaptiso/brick_shares.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/memory.hpp"
#include "adaptiso/point_cloud.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/prepare_to_file.hpp"
#include "adaptiso/volume_regions.hpp"
#include "cli_common.hpp"
#include "distributed.hpp"
#include "options.hpp"

namespace adaptiso::cli {
namespace {

// A rank other than 0 of `mpirun … adaptiso prepare`: its bricks of the error hierarchy, read
// straight from the file where it can be (RegionReader) or else sent by rank 0 (scattered_route),
// handed to rank 0, then its share of the selection (select_shares.hpp); it writes nothing.
// brick_side 0: the default for the lattice and the ranks, as rank 0 chooses it.
void prepare_rank_bricks(Ranks& ranks, const VolumeInput& in, const PrepareOptions& options, std::int64_t brick_side) {
  DistributedStats ignored;
  const bool displacement = options.max_displacement > 0;
  if (scattered_route(RegionReader::route_of(in.path, in.read_options()))) {
    distributed_errors(ranks, {}, {}, {}, {}, brick_side, displacement, true, {}, ignored);
  } else {
    RegionReader reader(in.path, in.read_options());
    const Dims lattice = bisection_lattice_dims(reader.header().dims);  // the lattice rank 0 pads its volume to (prepare.hpp)
    distributed_errors(
        ranks, lattice, reader.header().type, [&](const ValueRange& range) { return reader_source(reader, lattice, range); }, {},
        brick_side, displacement, false, {}, ignored);
  }
  bisection_select_share(ranks);               // then its run of the selection's tetrahedra
  std::uint64_t peak = peak_resident_bytes();  // its peak over both steps, for rank 0's --json
  ranks.send(std::as_bytes(std::span(&peak, 1)));
}

// The error hierarchy in bricks of `side` (over the ranks, 0: the default for the lattice and the
// ranks): over the ranks under mpirun (`scatter`: rank 0 sends the others their regions), else on
// this process. The returned function fills `stats`, which must outlive it.
std::function<BisectionErrors(const Volume&, const ValueRange&, bool, const Progress&)> bricked_errors(Ranks& ranks, std::int64_t side,
                                                                                                       bool scatter,
                                                                                                       DistributedStats& stats) {
  if (ranks.distributed())
    return [&ranks, side, scatter, &stats](const Volume& v, const ValueRange& range, bool displacement, const Progress& progress) {
      return distributed_errors(
          ranks, v.dims, v.type,
          [&v](const ValueRange&) {
            return ReaderSource{region_source(v), {}};
          },
          range, side, displacement, scatter, progress, stats);
    };
  return [side, &stats](const Volume& v, const ValueRange& range, bool displacement, const Progress& progress) {
    const BrickGrid bricks = brick_grid(v.dims, side);
    stats.brick_side = bricks.side;
    stats.bricks = bricks.size();
    stats.bricks_per_rank = {bricks.size()};
    stats.peak_bytes_per_rank = {0};  // filled in at the end
    return bisection_errors_bricked(v.dims, range, side, region_source(v), displacement, progress, &stats.bytes_exchanged);
  };
}

PrepareStats save_prepared_with_index(const Volume& v, const PrepareOptions& options, const std::string& output, const Progress& progress) {
  const PreparedGrid p = prepare(v, options, progress);
  save_grid(p, output, true);
  return p.stats;
}

}  // namespace

void add_prepare(CLI::App& app) {
  auto* cmd = app.add_subcommand("prepare", "Build the tetrahedral grid (bisection or Delaunay) and its vertex gradients; save it (.adg)");
  auto in = std::make_shared<VolumeInput>();
  auto pf = std::make_shared<PrepareFlags>();
  auto out = std::make_shared<OutputFlags>();
  auto output = std::make_shared<std::string>();
  in->add(cmd);
  pf->add(cmd);
  out->add(cmd);
  add_memory_limit(cmd);
  cmd->add_option("-o,--output", *output, "Grid file (.adg)")->required();
  auto brick_side = std::make_shared<std::int64_t>(0);
  cmd->add_option("--brick-side", *brick_side,
                  "Bisection grid: compute the error hierarchy in bricks of this many voxels a side (a power of two >= 2; the same "
                  "grid, byte for byte). Under mpirun the bricks are shared out over the ranks (default there: the largest up to 256 "
                  "leaving 4 bricks a rank)")
      ->check(positive_number());
  auto threads = std::make_shared<int>(0);
  cmd->add_option("--threads", *threads, "Threads this process uses (default: every core)")->check(positive_number());
  // Hidden: a file with its extraction index, as files before version 6 had (the fuzz targets'
  // seeds, so the stored index's checks stay fuzzed); loading builds the index faster otherwise.
  auto store_index = std::make_shared<bool>(false);
  cmd->add_flag("--store-index", *store_index, "Also store the extraction index in the file")->group("");
  cmd->callback([=] {
    PrepareOptions options = pf->options(in->path);  // a typo fails before the volume is read
    refuse_same_file(in->path, *output, "-o");
    std::optional<tbb::global_control> limit;
    if (*threads > 0) limit.emplace(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(*threads));
    Ranks& ranks = Ranks::world();
    const bool bricked = *brick_side > 0 || ranks.distributed();
    if (bricked && options.grid != GridKind::bisection)
      throw InputError(ranks.distributed() ? "only the bisection grid is prepared over MPI ranks (drop --grid delaunay or mpirun)"
                                           : "--brick-side applies to the bisection grid only");
    const std::int64_t side = *brick_side;         // 0 under mpirun: the default, once the lattice is known
    if (*brick_side > 0) check_brick_side(side);   // a bad side fails before the volume is read
    if (ranks.root()) check_output_path(*output);  // and an output that cannot be written (rank 0 writes it)
    auto t_all = Clock::now();
    if (!ranks.root()) return prepare_rank_bricks(ranks, *in, options, side);
    Volume v = in->load();
    const double t_load = seconds_since(t_all);
    DistributedStats dist;
    bool scatter = false;
    if (ranks.distributed()) {
      const char* route = RegionReader::route_of(in->path, in->read_options());  // the headers only
      scatter = scattered_route(route);
      dist.ranks_read = scatter ? "regions sent by rank 0" : route;
    }
    if (bricked) options.error_hierarchy = bricked_errors(ranks, side, scatter, dist);
    if (ranks.distributed()) options.select_share = &ranks;
    const std::uint64_t exchanged_before = ranks.bytes_exchanged();
    TerminalProgress tp(!out->quiet && !out->json);
    // The voxels go once the gradients are made; the file leaves the index out (loading builds it).
    const PrepareStats st = *store_index ? save_prepared_with_index(v, options, *output, tp.callback())
                                         : prepare_to_file(std::move(v), options, *output, tp.callback());
    tp.finish();
    const std::uint64_t exchanged = ranks.bytes_exchanged() - exchanged_before;  // the error hierarchy's and the selection's
    for (int r = 1; r < ranks.size(); ++r) {                                     // the other ranks' peaks, over the selection too
      std::uint64_t peak = 0;
      ranks.receive(r, std::as_writable_bytes(std::span(&peak, 1)));
      dist.peak_bytes_per_rank[static_cast<std::size_t>(r)] = std::max(dist.peak_bytes_per_rank[static_cast<std::size_t>(r)], peak);
    }
    nlohmann::json j = nlohmann::json::parse(to_json(st));
    j["seconds"]["load"] = t_load;
    j["seconds"]["total"] = seconds_since(t_all);
    j["output"] = *output;
    j["bytes"] = std::filesystem::file_size(*output);
    if (bricked) {
      if (!dist.peak_bytes_per_rank.empty()) dist.peak_bytes_per_rank[0] = peak_resident_bytes();
      if (ranks.distributed()) dist.select_bytes_exchanged = exchanged - dist.bytes_exchanged - dist.regions_sent_bytes;
      j["bricks"] = dist.to_json(ranks.size());
    }
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
    // Points need the vertices only: a bisection grid's tetrahedra are then not kept or checked
    // (the CT bunny's default grid: 0.45 GB of its 1.28 GB held). Neither builds the index.
    TerminalProgress tp(!out->quiet && !out->json);
    const PreparedGrid p = load_grid(*input, ext == ".ply" ? GridParts::hierarchy_or_all : GridParts::tetrahedra, tp.callback());
    tp.finish();
    const TetGrid& grid = p.grid;
    const double t_load = seconds_since(t0);
    if (ext == ".vtu")
      write_vtu(grid, *output);
    else
      write_points_ply(*output, grid);
    nlohmann::json j = {{"vertices", grid.vertex_count()},
                        {"tetrahedra", tetrahedron_count(p)},
                        {"seconds", {{"load", t_load}, {"total", seconds_since(t0)}}},
                        {"output", *output}};
    // The volume's voxels among them (the points written; "in_volume" in a .vtu).
    if (grid.source.padded()) j["volume_vertices"] = grid.volume_vertex_count();
    if (out->json)
      print_json(j);
    else if (!out->quiet)
      std::cout << fmt::format("wrote {} ({} vertices, {} tetrahedra)\n", *output, grid.vertex_count(), tetrahedron_count(p));
  });
}

}  // namespace adaptiso::cli
