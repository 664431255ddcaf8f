// adaptiso extract / adaptiso run: iso-surfaces from a grid file, or from a volume in one go (§2.4).
#include <fmt/format.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <filesystem>
#include <iostream>
#include <numeric>
#include <optional>

#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/marching_cubes.hpp"
#include "adaptiso/memory.hpp"
#include "adaptiso/mesh_io.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/simplify.hpp"
#include "adaptiso/surface_distance.hpp"
#include "cli_common.hpp"
#include "options.hpp"
#include "ranks.hpp"

namespace adaptiso::cli {
namespace {

// "surface.ply" with several iso-values → "surface-<token>.ply" per value.
std::string output_name(const std::string& path, const std::string& token, bool several) {
  if (!several) return path;
  std::filesystem::path p(path);
  return (p.parent_path() / (p.stem().string() + "-" + token + p.extension().string())).string();
}

// --iso, -o, --simplify and --measure of the commands that write iso-surface meshes (extract,
// run, mc).
struct MeshOutputFlags {
  std::vector<std::string> isos;  // as typed: they also name the outputs
  std::string output;
  double simplify = 0;  // voxels of the smallest spacing; 0: off
  bool measure = false;
  bool checked = false;
  void add(CLI::App* app) {
    auto* s = app->add_option("--simplify", simplify,
                              "Simplify each mesh so that it moves about this far (voxels of the smallest spacing; meshoptimizer's error "
                              "estimate, borders locked, kept vertices unmoved)")
                  ->check(non_negative_number());
    app->add_flag("--checked", checked,
                  "With --simplify: check each region's result both ways (vertices and triangle centres within the distance) and "
                  "simplify smaller regions where it fails; slower, more triangles on noisy surfaces")
        ->needs(s);
    app->add_flag("--measure", measure, "With --simplify: measure the distance between the simplified and the extracted surface");
    app->add_option("--iso", isos, "Iso-value(s), comma-separated; data units, or fractions of the range with --relative")
        ->required()
        ->delimiter(',');
    app->add_option("-o,--output", output,
                    "Mesh file (.ply .obj .stl .glb); with several iso-values each name gets -<iso> before the extension")
        ->required();
  }
  // Refuses an unknown mesh type, or a mesh written over the input (or over `other`, another
  // output), before any long work.
  void check(const std::string& input, const std::string& other = "", const std::string& other_option = "") const {
    if (!is_mesh_file_name(output))
      throw InputError(fmt::format("{}: unknown mesh type '{}' (use .ply, .obj, .stl or .glb)", output,
                                   std::filesystem::path(output).extension().string()));
    for (std::size_t i = 0; i < isos.size(); ++i) {
      refuse_same_file(input, path(i), "-o");
      if (!other.empty()) refuse_same_file(path(i), other, other_option);
    }
  }
  std::vector<double> values(bool relative, const ValueRange& range, const std::string& source) const {
    return parse_iso_values(isos, relative, range, source);
  }
  std::string path(std::size_t i) const { return output_name(output, isos[i], isos.size() > 1); }

  // Simplifies the mesh when asked, writes it, and returns what the simplification did (JSON; null
  // without --simplify) and the line that tells it.
  // With `staged`, the file is staged there (atomic_file.hpp) for the caller to commit.
  std::pair<nlohmann::json, std::string> write(const Mesh& mesh, const std::string& path, const Vec3& spacing,
                                               std::vector<StagedFile>* staged = nullptr) const {
    auto put = [&](const Mesh& m) {
      if (staged)
        staged->push_back(stage_mesh(m, path));
      else
        write_mesh(m, path);
    };
    if (simplify <= 0) {
      put(mesh);
      return {nullptr, ""};
    }
    const double voxel = std::min({spacing[0], spacing[1], spacing[2]});
    SimplifyStats st;
    SimplifyOptions how;
    how.checked = checked;
    const Mesh simplified = simplify_mesh(mesh, simplify * voxel, &st, how);
    put(simplified);
    nlohmann::json j = {{"distance_voxels", simplify},
                        {"checked", checked},
                        {"triangles_before", st.triangles_before},
                        {"triangles_after", st.triangles_after},
                        {"error_estimate_voxels", st.error / voxel},
                        {"chunks", st.chunks},
                        {"chunks_retried", st.chunks_retried},
                        {"chunks_kept", st.chunks_kept},
                        {"seconds", st.seconds}};
    std::string line = fmt::format("; simplified to {} triangles in {:.3f} s", st.triangles_after, st.seconds);
    if (measure && simplified.triangle_count() > 0) {
      const auto t0 = Clock::now();
      const SurfaceDistance d = surface_distance(simplified, mesh);
      const double mean = 0.5 * (d.a_to_b.mean + d.b_to_a.mean) / voxel;
      j["measured"] = {{"mean_voxels", mean},
                       {"p95_voxels", std::max(d.a_to_b.p95, d.b_to_a.p95) / voxel},
                       {"max_voxels", d.hausdorff() / voxel},
                       {"seconds", seconds_since(t0)}};
      line += fmt::format(", mean distance {:.4g} voxels (max {:.4g})", mean, d.hausdorff() / voxel);
    }
    return {j, line};
  }
};

// The human-readable line for one surface; `how` describes where its triangles came from.
std::string surface_line(double iso, bool in_range, double min, double max, std::size_t triangles, std::size_t vertices,
                         const std::string& how, double seconds, const std::string& path) {
  if (!in_range)
    return fmt::format("iso {:.6g} lies outside the value range [{:.6g}, {:.6g}]: empty mesh, wrote {}\n", iso, min, max, path);
  return fmt::format("iso {:.6g}: {} triangles, {} vertices {} in {:.4f} s; wrote {}\n", iso, triangles, vertices, how, seconds, path);
}
void print_surface(double iso, bool in_range, double min, double max, std::size_t triangles, std::size_t vertices, const std::string& how,
                   double seconds, const std::string& path) {
  std::cout << surface_line(iso, in_range, min, max, triangles, vertices, how, seconds, path);
}

// Where write_all puts the meshes and their lines: in place and on stdout (one process), or staged
// and kept for rank 0 to print (one rank's share of the iso-values under mpirun).
struct Written {
  std::vector<std::size_t> numbers;           // each given iso-value's number among all (empty: 0, 1, 2, …)
  std::vector<StagedFile>* staged = nullptr;  // staged here, not put in place
  std::vector<std::string>* lines = nullptr;  // the lines kept here, not printed
  bool write = true;                          // false: statistics only (a rank helping rank 0 make its surfaces)
};

// Writes one surface per iso-value, whichever way `extract` makes it, and returns the per-value
// statistics. `extract(iso, record)` calls `record(mesh, stats, how, seconds)` once: `stats` holds at
// least iso, in_range, triangles and vertices; `how` says where the triangles came from.
template <class Extract>
nlohmann::json write_all(const PreparedGrid& prepared, const MeshOutputFlags& mesh_out, const std::vector<double>& isos,
                         const OutputFlags& out, const Written& written, Extract extract) {
  const GridSource& source = prepared.grid.source;
  nlohmann::json results = nlohmann::json::array();
  for (std::size_t i = 0; i < isos.size(); ++i) {
    extract(isos[i], [&](const Mesh& mesh, nlohmann::json stats, const std::string& how, double seconds) {
      if (!written.write) return results.push_back(std::move(stats));
      const std::string path = mesh_out.path(written.numbers.empty() ? i : written.numbers[i]);
      const auto t0 = Clock::now();
      const auto [simplified, simplified_how] = mesh_out.write(mesh, path, source.spacing, written.staged);
      stats["write_seconds"] = seconds_since(t0);
      stats["output"] = path;
      if (!simplified.is_null()) stats["simplify"] = simplified;
      if (!out.json && !out.quiet) {
        const std::string line =
            surface_line(stats["iso"].get<double>(), stats["in_range"].get<bool>(), source.min, source.max,
                         stats["triangles"].get<std::size_t>(), stats["vertices"].get<std::size_t>(), how + simplified_how, seconds, path);
        if (written.lines)
          written.lines->push_back(line);
        else
          std::cout << line;
      }
      results.push_back(std::move(stats));
    });
  }
  return results;
}

// Every iso-value with one Extractor (so consecutive values sweep incrementally).
nlohmann::json extract_all(std::shared_ptr<const PreparedGrid> prepared, const MeshOutputFlags& mesh_out, const std::vector<double>& isos,
                           const OutputFlags& out, const Written& written = {}) {
  Extractor ex(prepared);
  return write_all(*prepared, mesh_out, isos, out, written, [&](double iso, auto&& record) {
    const ExtractStats st = ex.extract(iso);
    record(ex.mesh(), nlohmann::json::parse(to_json(st)), fmt::format("from {} active tetrahedra", st.active),
           st.sweep_seconds + st.march_seconds);
  });
}

// Up to this many iso-values, extract scans the tetrahedra for each instead of building the index
// to sweep (the CT bunny: a scan 0.2 s; the index 1.0-1.5 s on load, and 0.8 GB at its peak).
constexpr std::size_t kMostScannedIsoValues = 4;

// Every iso-value by a scan of the tetrahedra (extract_scanned): a grid loaded without its index.
nlohmann::json scan_all(std::shared_ptr<const PreparedGrid> prepared, const MeshOutputFlags& mesh_out, const std::vector<double>& isos,
                        const OutputFlags& out, const Written& written = {}) {
  return write_all(*prepared, mesh_out, isos, out, written, [&](double iso, auto&& record) {
    Mesh mesh;
    const ExtractStats st = extract_scanned(prepared->grid, iso, mesh);
    record(mesh, nlohmann::json::parse(to_json(st)), fmt::format("from {} active tetrahedra", st.active),
           st.sweep_seconds + st.march_seconds);
  });
}

// Every iso-value from the bisection hierarchy at a coarser error (query-time error).
nlohmann::json query_all(std::shared_ptr<const PreparedGrid> prepared, const MeshOutputFlags& mesh_out, const std::vector<double>& isos,
                         double max_error, double max_displacement, const OutputFlags& out, const Written& written = {}) {
  const HierarchyQuery query(prepared);
  return write_all(*prepared, mesh_out, isos, out, written, [&](double iso, auto&& record) {
    HierarchyQueryStats st;
    const Mesh mesh = query.extract(iso, max_error, max_displacement, &st);
    const double seconds = st.walk_seconds + st.march_seconds;
    record(mesh,
           {{"iso", st.iso},
            {"in_range", st.in_range},
            {"triangles", st.triangles},
            {"vertices", st.vertices},
            {"max_error", st.max_error},
            {"error_bound", st.error_bound},
            {"marched_tetrahedra", st.tetrahedra},
            {"visited_tetrahedra", st.visited},
            {"seconds", seconds},
            {"walk_seconds", st.walk_seconds},
            {"march_seconds", st.march_seconds}},
           fmt::format("at error {:.4g} (guaranteed {:.4g})", st.max_error, st.error_bound), seconds);
  });
}

// --distance and --collapse (extract and run).
struct DistanceFlags {
  double distance = -1;
  int collapse = kDefaultCollapseRounds;
  std::optional<double> min_piece;  // unset: the distance
  CLI::Option* option = nullptr;    // --distance, for the options that need it
  bool given() const { return distance >= 0; }
  void add(CLI::App* cmd) {
    auto* d = option =
        cmd->add_option("--distance", distance,
                        "Bisection grids: the fewest triangles within about this distance of the grid's surface (voxels of the "
                        "smallest spacing), refined where this surface needs it")
            ->check(non_negative_number());
    cmd->add_option("--collapse", collapse,
                    fmt::format("With --distance: up to this many rounds of edge collapses after the march, each checked by the same "
                                "tests (a fifth to a quarter fewer triangles a round on the CT and MR scans measured; a round removing "
                                "under a sixteenth is the last); 2 is faster, 0 keeps every triangle inside its tetrahedron (default {})",
                                kDefaultCollapseRounds))
        ->check(CLI::Range(0, kMaxCollapseRounds))
        ->needs(d);
    cmd->add_option("--min-piece", min_piece,
                    "With --distance: drop the surface's pieces whose bounding box has a diagonal under this many voxels (default: "
                    "the distance, a speck of noise; 0 keeps every piece, a small lesion say)")
        ->check(non_negative_number())
        ->needs(d);
  }
};

// A surface within a distance and its statistics, to write_all's `record`.
template <class Record>
void record_within(Record& record, const Mesh& mesh, const DistanceQueryStats& st) {
  const double seconds = st.refine_seconds + st.walk_seconds + st.march_seconds + st.collapse_seconds;
  record(mesh,
         {{"iso", st.iso},
          {"in_range", st.in_range},
          {"triangles", st.triangles},
          {"vertices", st.vertices},
          {"distance_voxels", st.distance},
          {"marched_tetrahedra", st.tetrahedra},
          {"tested_tetrahedra", st.tested},
          {"split_diamonds", st.refined},
          {"closure_diamonds", st.closure},
          {"visited_tetrahedra", st.visited},
          {"seconds", seconds},
          {"refine_seconds", st.refine_seconds},
          {"walk_seconds", st.walk_seconds},
          {"march_seconds", st.march_seconds},
          {"min_piece_voxels", st.min_piece},
          {"specks_dropped", st.specks},
          {"speck_triangles", st.speck_triangles},
          {"collapsed_edges", st.collapsed},
          {"collapse_rounds", st.collapse_rounds},
          {"collapses_probed", st.collapses_probed},
          {"collapses_failed", st.collapses_failed},
          {"collapse_seconds", st.collapse_seconds}},
         fmt::format("within about {:g} voxels of the grid's surface{}", st.distance,
                     st.specks ? fmt::format(" ({} piece{} smaller than {} dropped)", st.specks, st.specks == 1 ? "" : "s",
                                             st.min_piece == st.distance ? "that" : fmt::format("{:g} voxels", st.min_piece))
                               : ""),
         seconds);
}

// Surfaces made by all the processes of a transport (hierarchy_query.hpp), written as `written` says.
struct Together {
  ShareTransport* transport = nullptr;
  std::vector<double> isos;
  Written written;
};

// Every iso-value within a distance of the grid's own surface (surface-adaptive extraction), then
// `together`'s values made together; one query index for both.
nlohmann::json distance_all(std::shared_ptr<const PreparedGrid> prepared, const MeshOutputFlags& mesh_out, const std::vector<double>& isos,
                            const DistanceFlags& flags, const OutputFlags& out, bool show_progress, const Written& written = {},
                            const Together& together = {}) {
  const HierarchyQuery query(prepared);
  auto all = write_all(*prepared, mesh_out, isos, out, written, [&](double iso, auto&& record) {
    DistanceQueryStats st;
    TerminalProgress tp(show_progress);  // eight rounds of collapses on a 512×512×120 MR head: 8 s
    Mesh m = query.extract_within(iso, flags.distance, &st, flags.collapse, nullptr, tp.callback(), flags.min_piece);
    tp.finish();
    record_within(record, m, st);
  });
  for (auto& made : write_all(*prepared, mesh_out, together.isos, out, together.written, [&](double iso, auto&&record) {
         DistanceQueryStats st;
         record_within(record, query.extract_within(*together.transport, iso, flags.distance, &st, flags.collapse, flags.min_piece), st);
       }))
    all.push_back(std::move(made));
  return all;
}

// ---- extract over MPI ranks (issue 38) ----
//
// Under mpirun rank r extracts the iso-values r, r + N, r + 2N, … of the N ranks, loading what
// its route needs as one process would (each reads the whole file; when every rank has a value,
// the load's checks are shared out, load_grid_shared), and stages its meshes (atomic_file.hpp:
// written in full, nothing under their names). Once every rank has staged its own, rank 0 tells
// them to put theirs in place, then prints every rank's lines and statistics in the order of the
// iso-values. Each mesh is the one a single process writes, byte for byte (every route gives the
// same surface; ctest extract_over_mpi_ranks). A rank that fails before then stops the others
// (main: MPI_Abort) and no mesh reaches its name.
//
// Tried and not kept (2026-12-02): surfaces at a distance or a coarser error handed out one at a
// time, in order, as ranks asked (rank 0 serving the others from a thread polling every
// millisecond, under MPI_THREAD_SERIALIZED). The same bytes, but no faster: on the CT bunny at 0.5 voxels, one
// thread a rank, 2 ranks against this in-turn share, 3 alternated pairs each, 8 values 1.02x,
// 15 values 0.97x, 4 values 1.09x (slower). The values cost 0.56-3.2 s each, and greedy in order
// left an expensive one last as often as the turn did. Ordering them by cost would pay, but
// nothing cheap predicts it: the query at 8 voxels ranks them roughly right (its tests) for 5-10 %
// of the time they take at 0.5.
//
// Surfaces at a distance can also be made by all ranks together (hierarchy_query.hpp), at about
// 1.5x one rank's speed over 2 (the CT bunny, one thread a rank: iso 1600.5 at 0.5 voxels 0.42 s
// against 0.63, iso 800 2.79 s against 4.20). Dealt in turn the values go faster while every rank
// has some (8 values: 12.2-13.5 s against 13.3-15.1 made together, 19.3-21.2 in one process, 3
// alternated triples), so by default (--rank-share auto) the first n - n mod N values are dealt in
// turn and the last n mod N made together: no rank waits for want of a value, and one value is
// made 1.5x faster instead of by one rank alone.
struct IsoShare {
  std::vector<std::size_t> mine;    // this rank's iso-values' numbers among all, ascending: its own, then those made together
  std::vector<std::size_t> counts;  // every rank's count of its own
  std::size_t n = 0;                // all the values
  std::size_t dealt = 0;            // values 0 … dealt − 1 are dealt in turn; the others made together
  std::size_t own = 0;              // how many of `mine` are this rank's own (the first)
  std::vector<StagedFile> staged;   // this rank's meshes until every rank's are staged
  std::vector<std::string> lines;   // their lines, for rank 0 to print
};
IsoShare iso_share(std::size_t n, const Ranks& ranks, std::size_t dealt) {
  IsoShare s;
  s.n = n, s.dealt = dealt;
  const auto size = static_cast<std::size_t>(ranks.size()), rank = static_cast<std::size_t>(ranks.rank());
  for (std::size_t r = 0; r < size; ++r) s.counts.push_back(dealt / size + (r < dealt % size));
  for (std::size_t i = rank; i < dealt; i += size) s.mine.push_back(i);
  s.own = s.mine.size();
  for (std::size_t i = dealt; i < n; ++i) s.mine.push_back(i);
  return s;
}

// A failure of this rank's own iso-values (its outputs, its memory) is not one every rank meets:
// told with the rank's number (main.cpp: RankInputError), not left to rank 0.
template <class F>
void as_rank_failure(const Ranks& ranks, F&& f) {
  if (!ranks.distributed() || ranks.root()) return f();
  try {
    f();
  } catch (const InputError& e) {
    throw RankInputError(e.what());
  }
}

std::vector<std::byte> to_bytes(const std::string& s) {
  const auto* b = reinterpret_cast<const std::byte*>(s.data());
  return {b, b + s.size()};
}

// Every rank's staged meshes put in place once all are staged; on rank 0 the statistics of all
// (the one-process JSON, its surfaces in the order of the iso-values, and "ranks") after the
// lines, printed in the same order.
nlohmann::json commit_shares(Ranks& ranks, IsoShare& share, nlohmann::json mine, const OutputFlags& out) {
  mine["peak_bytes"] = peak_resident_bytes();
  mine["lines"] = share.lines;
  const auto all = ranks.gather(to_bytes(mine.dump()));  // every rank staged its meshes by now
  ranks.broadcast(std::uint64_t{1});                     // then: in place, every rank
  for (auto& f : share.staged) f.commit();
  ranks.gather({});  // every rank's are in place before rank 0 says so
  if (!ranks.root()) return nullptr;
  std::vector<nlohmann::json> got;
  nlohmann::json j, per = {{"ranks", ranks.size()}, {"iso_values_per_rank", share.counts}};
  for (const auto& bytes : all) {
    got.push_back(nlohmann::json::parse(std::string(reinterpret_cast<const char*>(bytes.data()), bytes.size())));
    const auto& r = got.back();
    per["peak_bytes_per_rank"].push_back(r["peak_bytes"]);
    per["load_seconds_per_rank"].push_back(r.value("load_seconds", 0.0));
    for (const char* key : {"grid", "vertices", "tetrahedra", "load_seconds"})
      if (!j.contains(key) && r.contains(key)) j[key] = r[key];
  }
  // Iso-value i < dealt is rank i mod N's (i / N)-th; the others, made together, follow each
  // rank's own, written by rank 0 (its lines in the same order).
  j["surfaces"] = nlohmann::json::array();
  const std::size_t N = got.size();
  for (std::size_t i = 0; i < share.n; ++i) {
    const auto& r = i < share.dealt ? got[i % N] : got[0];
    const std::size_t at = i < share.dealt ? i / N : share.counts[0] + (i - share.dealt);
    j["surfaces"].push_back(r["surfaces"][at]);
    if (!out.json && !out.quiet) std::cout << r["lines"][at].get<std::string>();
  }
  per["iso_values_made_together"] = share.n - share.dealt;
  per["bytes_exchanged"] = ranks.bytes_exchanged();
  j["ranks"] = per;
  return j;
}

}  // namespace

void add_extract(CLI::App& app) {
  auto* cmd = app.add_subcommand("extract", "Extract iso-surfaces from a grid file (.adg) into meshes (.ply .obj .stl .glb)");
  auto input = std::make_shared<std::string>();
  auto mesh_out = std::make_shared<MeshOutputFlags>();
  auto relative = std::make_shared<bool>(false);
  auto max_error = std::make_shared<double>(0);
  auto max_displacement = std::make_shared<double>(0);
  auto distance = std::make_shared<DistanceFlags>();
  auto out = std::make_shared<OutputFlags>();
  cmd->add_option("GRID", *input, "Grid file (.adg) written by prepare")->required();
  distance->add(cmd);
  mesh_out->add(cmd);
  cmd->add_flag("--relative", *relative, "Iso-values (and --max-error) as fractions of the value range [min, max]");
  auto* error_opt = cmd->add_option("--max-error", *max_error,
                                    "Bisection grids: extract at this coarser error (at least the prepared one) from the grid's "
                                    "hierarchy, without preparing again")
                        ->check(finite_number());
  auto* displacement_opt =
      cmd->add_option("--max-displacement", *max_displacement, "Bisection grids prepared with it: a coarser displacement bound (voxels)")
          ->check(finite_number());
  out->add(cmd);
  add_memory_limit(cmd);
  auto threads = std::make_shared<int>(0);
  cmd->add_option("--threads", *threads, "Threads this process uses (default: every core)")->check(positive_number());
  auto rank_share = std::make_shared<std::string>("auto");
  cmd->add_option("--rank-share", *rank_share,
                  "Under mpirun with --distance: deal the iso-values out to the ranks in turn (values), make each surface with "
                  "all ranks together (surfaces), or deal out all but the last n mod ranks and make those together (auto)")
      ->check(CLI::IsMember({"auto", "surfaces", "values"}))
      ->capture_default_str()
      ->needs(distance->option);
  cmd->callback([=] {
    mesh_out->check(*input);
    std::optional<tbb::global_control> limit;
    if (*threads > 0) limit.emplace(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(*threads));
    // Given, a bound is used or refused: never ignored.
    const bool query = error_opt->count() > 0 || displacement_opt->count() > 0;
    if (error_opt->count() && !(*max_error >= 0))
      throw OptionError("max_error", fmt::format("must be a non-negative number, got {:.6g}", *max_error));
    if (displacement_opt->count() && !(*max_displacement >= 0))
      throw OptionError("max_displacement", fmt::format("must be a non-negative number, got {:.6g}", *max_displacement));
    if (distance->given() && query)
      throw OptionError("distance", "cannot be combined with --max-error or --max-displacement: give one of them");
    Ranks& ranks = Ranks::world();
    // Only surfaces at a distance can be made together.
    const std::size_t n_values = mesh_out->isos.size(), N = static_cast<std::size_t>(ranks.size());
    const std::size_t dealt = !ranks.distributed() || !distance->given() || *rank_share == "values" ? n_values
                              : *rank_share == "surfaces"                                           ? 0
                                                                                                    : n_values - n_values % N;
    IsoShare share = iso_share(n_values, ranks, dealt);
    const std::vector<std::size_t> own(share.mine.begin(), share.mine.begin() + static_cast<std::ptrdiff_t>(share.own)),
        shared(share.mine.begin() + static_cast<std::ptrdiff_t>(share.own), share.mine.end());
    const Written written{own, ranks.distributed() ? &share.staged : nullptr, ranks.distributed() ? &share.lines : nullptr};
    const Written written_together{shared, written.staged, written.lines, ranks.root()};
    nlohmann::json j;
    if (!share.mine.empty()) {  // a rank with no iso-value to make loads nothing
      auto t0 = Clock::now();
      // The hierarchy's queries walk the hierarchy alone: the tetrahedra stay on disk, no index is
      // built; nor for a few iso-values, which a scan of the tetrahedra finds faster. Every route
      // gives the same surfaces, so a rank chooses by its own share.
      const bool hierarchy_only = distance->given() || query;
      const bool scan = !hierarchy_only && share.mine.size() <= kMostScannedIsoValues;
      std::shared_ptr<const PreparedGrid> p;
      {
        TerminalProgress tp(!out->quiet && !out->json && ranks.root());
        const GridParts parts = hierarchy_only ? GridParts::hierarchy : scan ? GridParts::tetrahedra : GridParts::all;
        // When every rank loads (an iso-value each at least) the same parts (a rank's route follows
        // its own count of values, and the counts differ by one at most), the load's checks are
        // shared out: each walks a share of the hierarchy (grid_file.hpp, load_grid_shared).
        const auto [fewest, most] = std::minmax_element(share.counts.begin(), share.counts.end());
        const bool same_parts = hierarchy_only || (*most <= kMostScannedIsoValues) == (*fewest <= kMostScannedIsoValues);
        const bool together = ranks.distributed() && (*fewest > 0 || share.n > share.dealt) && same_parts;
        p = std::make_shared<const PreparedGrid>(together ? load_grid_shared(*input, parts, ranks, tp.callback())
                                                          : load_grid(*input, parts, tp.callback()));
      }
      const TetGrid& grid = p->grid;
      const double t_load = seconds_since(t0);
      if (*max_displacement > 0 && p->hierarchy->displacement_code.empty())
        throw OptionError("max_displacement",
                          fmt::format("{} was prepared without the displacement criterion (prepare it with --max-displacement)", *input));
      const ValueRange range{grid.source.min, grid.source.max};
      const auto all = mesh_out->values(*relative, range, *input);
      std::vector<double> values, together_values;
      for (std::size_t i : own) values.push_back(all[i]);
      for (std::size_t i : shared) together_values.push_back(all[i]);
      j = {{"grid", *input}, {"vertices", grid.vertex_count()}, {"tetrahedra", tetrahedron_count(*p)}, {"load_seconds", t_load}};
      as_rank_failure(ranks, [&] {
        if (distance->given()) {
          j["surfaces"] = distance_all(p, *mesh_out, values, *distance, *out, !out->quiet && !out->json && ranks.root(), written,
                                       {&ranks, together_values, written_together});
        } else if (query) {
          const double e =
              *relative ? from_fraction(range, *max_error, FractionOf::width, *input + ": --max-error with --relative") : *max_error;
          j["surfaces"] = query_all(p, *mesh_out, values, e, *max_displacement, *out, written);
        } else if (scan) {
          j["surfaces"] = scan_all(p, *mesh_out, values, *out, written);
        } else {
          j["surfaces"] = extract_all(p, *mesh_out, values, *out, written);
        }
      });
    }
    if (ranks.distributed()) j = commit_shares(ranks, share, std::move(j), *out);
    if (out->json && ranks.root()) print_json(j);
  });
}

// prepare() without building the index (run's surfaces need none), its statistics still giving the
// index's depth and size, as prepare_to_file's do.
PreparedGrid unindexed(Volume&& v, const ValueRange& range, const PrepareOptions& options, const Progress& progress) {
  PreparedGrid p = detail::prepare_unindexed(v, range, options, progress, &v);
  detail::set_index_figures(p.stats, interval_tree_shape(p.grid, options.tree_depth));
  return p;
}

void add_run(CLI::App& app) {
  auto* cmd = app.add_subcommand("run", "All stages at once: volume → reduced grid → iso-surface mesh");
  auto in = std::make_shared<VolumeInput>();
  auto pf = std::make_shared<PrepareFlags>();
  auto out = std::make_shared<OutputFlags>();
  auto mesh_out = std::make_shared<MeshOutputFlags>();
  auto save = std::make_shared<std::string>();
  in->add(cmd);
  pf->add(cmd);
  out->add(cmd);
  add_memory_limit(cmd);
  mesh_out->add(cmd);
  cmd->add_option("--save-grid", *save, "Also save the prepared grid (.adg) for later extract or view");
  auto distance = std::make_shared<DistanceFlags>();
  distance->add(cmd);
  cmd->callback([=] {
    mesh_out->check(in->path, *save, "--save-grid");
    if (!save->empty()) refuse_same_file(in->path, *save, "--save-grid");
    auto t_all = Clock::now();
    Volume v = in->load();
    const double t_load = seconds_since(t_all);
    auto range = value_range(v);
    // Parse before the long preprocessing so a typo fails at once.
    const PrepareOptions options = pf->options(in->path);
    if (distance->given() && options.grid != GridKind::bisection)
      throw OptionError("distance", "needs the bisection grid (the Delaunay grid keeps no hierarchy to refine)");
    auto values = mesh_out->values(options.relative, range, in->path);
    TerminalProgress tp(!out->quiet && !out->json);
    // A surface at a distance needs no index, and a few iso-values are found faster by a scan.
    const bool indexed = !distance->given() && mesh_out->isos.size() > kMostScannedIsoValues;
    auto p = std::make_shared<const PreparedGrid>(indexed ? prepare(std::move(v), range, options, tp.callback())  // frees the voxels
                                                          : unindexed(std::move(v), range, options, tp.callback()));
    tp.finish();
    nlohmann::json j = nlohmann::json::parse(to_json(p->stats));
    j["seconds"]["load"] = t_load;
    if (!save->empty()) {
      auto t0 = Clock::now();
      save_grid(*p, *save);
      j["seconds"]["save"] = seconds_since(t0);
      j["grid"] = *save;
    }
    if (!out->json && !out->quiet)
      std::cout << fmt::format("kept {} of {} voxels ({:.2f} %), {} tetrahedra; {}\n", p->stats.kept, p->stats.voxels,
                               100.0 * j["ratio"].get<double>(), p->stats.tetrahedra, error_summary(p->stats));
    j["surfaces"] = distance->given() ? distance_all(p, *mesh_out, values, *distance, *out, !out->quiet && !out->json)
                    : indexed         ? extract_all(p, *mesh_out, values, *out)
                                      : scan_all(p, *mesh_out, values, *out);
    j["seconds"]["total"] = seconds_since(t_all);
    if (out->json) print_json(j);
  });
}

void add_mc(CLI::App& app) {
  auto* cmd = app.add_subcommand("mc", "Full-resolution marching cubes (the reference surface)");
  auto in = std::make_shared<VolumeInput>();
  auto out = std::make_shared<OutputFlags>();
  auto mesh_out = std::make_shared<MeshOutputFlags>();
  auto relative = std::make_shared<bool>(false);
  in->add(cmd);
  out->add(cmd);
  add_memory_limit(cmd);
  mesh_out->add(cmd);
  cmd->add_flag("--relative", *relative, "Iso-values as fractions of the value range [min, max]");
  cmd->callback([=] {
    mesh_out->check(in->path);
    auto t0 = Clock::now();
    Volume v = in->load();
    const double t_load = seconds_since(t0);
    auto range = value_range(v);
    auto values = mesh_out->values(*relative, range, in->path);
    nlohmann::json j = {{"voxels", v.voxel_count()}, {"load_seconds", t_load}, {"surfaces", nlohmann::json::array()}};
    for (std::size_t i = 0; i < values.size(); ++i) {
      auto t1 = Clock::now();
      MarchingCubesStats st;
      Mesh m = marching_cubes(v, values[i], &st);
      const double t_mc = seconds_since(t1);
      const std::string path = mesh_out->path(i);
      const auto [simplified, how] = mesh_out->write(m, path, v.spacing);
      const bool in_range = values[i] >= range.min && values[i] <= range.max;
      j["surfaces"].push_back({{"iso", values[i]},
                               {"in_range", in_range},
                               {"triangles", m.triangle_count()},
                               {"vertices", m.vertex_count()},
                               {"cubes_cut", st.cubes_cut},
                               {"ambiguous_faces", st.ambiguous_faces},
                               {"seconds", t_mc},
                               {"output", path}});
      if (!simplified.is_null()) j["surfaces"].back()["simplify"] = simplified;
      if (!out->json && !out->quiet)
        print_surface(values[i], in_range, range.min, range.max, m.triangle_count(), m.vertex_count(),
                      "(full-resolution marching cubes)" + how, t_mc, path);
    }
    if (out->json) print_json(j);
  });
}

}  // namespace adaptiso::cli
