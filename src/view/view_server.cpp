// The viewer's HTTP server (see view_server.hpp; docs/API.md specifies the API). Handlers only
// parse parameters, ask the sessions (view/sessions.hpp: extractors, levels, memory) or the
// library, and encode the answer; the connection handling is view/http.hpp's.
#include "adaptiso/view_server.hpp"

#include <fmt/format.h>
#include <httplib.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>

#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/marching_cubes.hpp"
#include "adaptiso/mesh_codec.hpp"
#include "adaptiso/mesh_io.hpp"
#include "adaptiso/number.hpp"
#include "adaptiso/simplify.hpp"
#include "adaptiso/wireframe.hpp"
#include "view/http.hpp"
#include "view/memory_budget.hpp"
#include "view/request.hpp"
#include "view/running_queries.hpp"
#include "view/sessions.hpp"

namespace adaptiso {
namespace fs = std::filesystem;

std::string encode_mesh(const Mesh& m) {
  const std::uint32_t V = static_cast<std::uint32_t>(m.vertex_count()), T = static_cast<std::uint32_t>(m.triangle_count());
  std::string out(8 + 24 * std::size_t{V} + 12 * std::size_t{T}, '\0');
  char* p = out.data();
  std::memcpy(p, &V, 4);
  std::memcpy(p + 4, &T, 4);
  if (V) std::memcpy(p + 8, m.positions.data(), 12 * std::size_t{V});
  if (V && m.normals.size() == V) std::memcpy(p + 8 + 12 * std::size_t{V}, m.normals.data(), 12 * std::size_t{V});
  if (T) std::memcpy(p + 8 + 24 * std::size_t{V}, m.triangles.data(), 12 * std::size_t{T});
  return out;
}

namespace {

using detail::BadRequest;
using detail::client_id;
using detail::compact_format;
using detail::export_format;
using detail::parse_flag;
using detail::parse_iso;
using detail::parse_optional;
using detail::Sessions;

// The grid is not there yet (or its preparation failed): 503 with the message and Retry-After.
struct NotReady : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The page's files: web_root/served.txt lists them (one relative path a line, # comments); the
// page itself is always among them. Nothing else in the folder is served (web/node_modules
// holds test tooling).
std::set<std::string> read_served_files(const fs::path& root) {
  std::set<std::string> files{"index.html"};
  std::ifstream list(root / "served.txt");
  for (std::string line; std::getline(list, line);) {
    line = line.substr(0, line.find('#'));
    while (!line.empty() && std::isspace(static_cast<unsigned char>(line.back()))) line.pop_back();
    while (!line.empty() && std::isspace(static_cast<unsigned char>(line.front()))) line.erase(0, 1);
    if (line.empty() || line.find("..") != std::string::npos || line.front() == '/') continue;
    files.insert(line);
  }
  return files;
}

const char* content_type(const fs::path& p) {
  const std::string e = p.extension().string();
  if (e == ".html") return "text/html; charset=utf-8";
  if (e == ".js" || e == ".mjs") return "text/javascript; charset=utf-8";
  if (e == ".css") return "text/css; charset=utf-8";
  if (e == ".json" || e == ".map") return "application/json";
  if (e == ".png") return "image/png";
  if (e == ".svg") return "image/svg+xml";
  if (e == ".ico") return "image/x-icon";
  return nullptr;
}

// u32 N, f32 positions[3N] (world), f32 values[N]: the vertices in the volume's box (a padded
// lattice's copies past the far faces are not the volume's voxels; export's points file skips them too).
std::string encode_points(const TetGrid& grid) {
  const std::uint32_t N = static_cast<std::uint32_t>(grid.volume_vertex_count());
  std::string out(4 + 16 * std::size_t{N}, '\0');
  std::memcpy(out.data(), &N, 4);
  std::size_t k = 0;
  for (std::uint32_t v = 0; v < grid.vertex_count(); ++v) {
    if (!grid.in_volume_box(v)) continue;
    const Vec3 w = grid.world_position(v);
    float rec[3] = {static_cast<float>(w[0]), static_cast<float>(w[1]), static_cast<float>(w[2])};
    const float value = static_cast<float>(grid.values[v]);
    std::memcpy(out.data() + 4 + 12 * k, rec, 12);
    std::memcpy(out.data() + 4 + 12 * std::size_t{N} + 4 * k, &value, 4);
    ++k;
  }
  return out;
}

// u32 V, u32 E, f32 positions[3V], u32 pairs[2E]
std::string encode_wireframe(const Wireframe& w) {
  const std::uint32_t V = static_cast<std::uint32_t>(w.positions.size()), E = static_cast<std::uint32_t>(w.edges.size());
  std::string out(8 + 12 * std::size_t{V} + 8 * std::size_t{E}, '\0');
  std::memcpy(out.data(), &V, 4);
  std::memcpy(out.data() + 4, &E, 4);
  if (V) std::memcpy(out.data() + 8, w.positions.data(), 12 * std::size_t{V});
  if (E) std::memcpy(out.data() + 8 + 12 * std::size_t{V}, w.edges.data(), 8 * std::size_t{E});
  return out;
}

nlohmann::json histogram_json(const Histogram& h, const char* of) {
  return {{"min", h.min}, {"max", h.max}, {"counts", h.counts}, {"of", of}};
}

constexpr int kHistogramBins = 128;

// The histogram of the grid's vertex values inside the volume's box: a padded lattice's copies of
// the last slices would count those slices again (tet_grid.hpp).
Histogram vertex_histogram(const TetGrid& grid) {
  const ValueRange range{grid.source.min, grid.source.max};
  if (!grid.source.padded()) return histogram(grid.values, range, kHistogramBins);
  std::vector<double> inside;
  for (std::uint32_t v = 0; v < grid.vertex_count(); ++v)
    if (grid.in_volume_box(v)) inside.push_back(grid.values[v]);
  return histogram(inside, range, kHistogramBins);
}

constexpr std::size_t kMaxWireframeEdges = 20'000'000;
// Memory of an export beyond its surface: the copy, the simplification's working set and the file
// (bytes per triangle; simplify_mesh's quadrics and heap dominate).
constexpr std::uint64_t kExportBytesPerTriangle = 150;
// A distance query's peak (measured 162–196 bytes per triangle of its answer on the chest CT) and
// the full-resolution marching cubes' (65–91), each with its plain answer.
constexpr std::uint64_t kDistanceBytesPerTriangle = 200 + 24, kReferenceBytesPerTriangle = 100 + 24;

std::string seconds_text(double s) { return fmt::format("{:.6f}", s); }

// Every route of the API, registered in this order with their handlers (Impl::routes): docs/API.md specifies
// each (tests/view/test_view_server.cpp checks both ways).
constexpr const char* kApiRoutes[] = {"/api/info", "/api/surface", "/api/reference", "/api/export", "/api/points", "/api/tetrahedra"};

// distance= and what goes with it: collapse= (rounds of edge collapses) and min_piece= (voxels).
struct Within {
  double distance;
  int collapse;
  std::optional<double> min_piece;
};
}  // namespace

struct ViewServer::Impl {
  explicit Impl(ViewOptions o);

  ViewOptions opt;
  detail::HttpServer http;
  fs::path web_root;
  std::set<std::string> served;  // the page's files (web_root/served.txt), relative to web_root
  Sessions sessions;
  detail::RunningQueries running;  // each page's distance query: the page's next one cancels it

  std::mutex state_mutex;  // guards everything below
  std::string stage = "starting", failure;
  double fraction = 0;
  std::shared_ptr<const PreparedGrid> grid;
  std::shared_ptr<const HierarchyQuery> query;                // bisection grids only: surfaces within a distance
  std::function<std::shared_ptr<const PreparedGrid>()> rest;  // a grid loaded in part: the whole of it
  std::string rest_failed;                                    // what reading it said, when it failed
  std::mutex rest_mutex;                                      // held while the rest is read
  std::shared_ptr<const Volume> volume;
  nlohmann::json histogram;

  struct Served {
    std::shared_ptr<const PreparedGrid> grid;
    std::shared_ptr<const HierarchyQuery> query;
  };
  Served served_now();    // throws NotReady while preparing
  Served served_whole();  // with the grid's tetrahedra, read now if it was loaded in part
  void install(std::shared_ptr<const PreparedGrid> g, std::function<std::shared_ptr<const PreparedGrid>()> rest);

  using Handler = void (Impl::*)(const httplib::Request&, httplib::Response&);
  void routes();
  httplib::Server::HandlerResponse admit(const httplib::Request& req, httplib::Response& res) const;
  bool host_allowed(const httplib::Request& req) const;
  void info(const httplib::Request& req, httplib::Response& res);
  void surface(const httplib::Request& req, httplib::Response& res);
  Mesh surface_within(const Served& s, double iso, const Within& within, DistanceQueryStats* stats,
                      const std::atomic<bool>* cancel = nullptr, int* process = nullptr);
  void reference(const httplib::Request& req, httplib::Response& res);
  void download(const httplib::Request& req, httplib::Response& res);
  void points(const httplib::Request& req, httplib::Response& res);
  void tetrahedra(const httplib::Request& req, httplib::Response& res);
  void serve_static(const httplib::Request& req, httplib::Response& res);
};

namespace {

// distance=, and collapse= and min_piece=, which go with it only.
std::optional<Within> parse_within(const detail::QueryParams& params) {
  const int rounds = detail::parse_rounds(params, "collapse", kDefaultCollapseRounds, kMaxCollapseRounds);
  const auto distance = detail::parse_optional(params, "distance");
  const auto min_piece = detail::parse_optional(params, "min_piece");
  if (!distance) {
    if (params.count("collapse")) throw detail::BadRequest("collapse= needs distance=");
    if (min_piece) throw detail::BadRequest("min_piece= needs distance=");
    return std::nullopt;
  }
  return Within{*distance, rounds, min_piece};
}

detail::SessionOptions session_options(const ViewOptions& o) {
  detail::SessionOptions s;
  s.max_clients = o.max_clients;
  s.memory_budget = o.memory_budget ? o.memory_budget : detail::default_memory_budget();
  s.idle_seconds = o.idle_seconds;
  return s;
}

}  // namespace

ViewServer::Impl::Impl(ViewOptions o) : opt(std::move(o)), sessions(session_options(opt)) {
  if (!opt.memory_budget) opt.memory_budget = detail::default_memory_budget();
}

ViewServer::Impl::Served ViewServer::Impl::served_now() {
  std::lock_guard lock(state_mutex);
  if (!grid)
    throw NotReady(failure.empty() ? fmt::format("the grid is not ready yet ({} {:.0f} %)", stage, fraction * 100)
                                   : "preparation failed: " + failure);
  return {grid, query};
}

ViewServer::ViewServer(ViewOptions options) {
  if (!(options.idle_seconds > 0) || !(options.thread_idle_seconds > 0))
    throw OptionError("idle_seconds", "idle times must be positive numbers of seconds");
  std::error_code ec;
  const fs::path root = fs::weakly_canonical(options.web_dir, ec);
  if (ec || !fs::is_regular_file(root / "index.html"))
    throw OptionError("web_dir", fmt::format("{}: the viewer page is not there (no index.html)", options.web_dir));
  impl_ = std::make_unique<Impl>(std::move(options));
  impl_->web_root = root;
  impl_->served = read_served_files(root);
  impl_->routes();
}

ViewServer::~ViewServer() { stop(); }

// Pages reach a local server through DNS rebinding (a name that resolves to 127.0.0.1): only the
// names and addresses the server listens on are accepted, and IP literals when it listens on all
// interfaces, with the machine's own name.
bool ViewServer::Impl::host_allowed(const httplib::Request& req) const {
  if (!req.has_header("Host")) return true;  // HTTP/1.0 clients
  std::string name = detail::host_name(req.get_header_value("Host"));
  for (auto& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (name == "localhost" || name == "127.0.0.1" || name == "[::1]" || name == opt.host) return true;
  if (opt.host == "0.0.0.0" || opt.host == "::") {
    char machine[256] = {};
    gethostname(machine, sizeof machine - 1);
    return detail::is_ip_literal(name) || name == machine;
  }
  return false;
}

// Before routing (and before any body is read): who may ask, and how.
httplib::Server::HandlerResponse ViewServer::Impl::admit(const httplib::Request& req, httplib::Response& res) const {
  auto refuse = [&](int status, const std::string& text) {
    res.status = status;
    res.set_content(text + "\n", "text/plain");
    return httplib::Server::HandlerResponse::Handled;
  };
  if (!host_allowed(req)) return refuse(403, "host not allowed (the viewer answers only to the names and addresses it listens on)");
  if (req.method != "GET" && req.method != "HEAD") {
    res.set_header("Allow", "GET, HEAD");
    return refuse(405, "only GET is served");
  }
  if (req.path.rfind("/api/", 0) == 0) {
    const std::string origin = req.get_header_value("Origin");
    switch (detail::check_origin(origin, req.get_header_value("Sec-Fetch-Site"), req.get_header_value("Host"), opt.allowed_origins)) {
      case detail::OriginVerdict::refused:
        return refuse(403, fmt::format("cross-origin request{} refused: start the viewer with --allow-origin ORIGIN to let a web page "
                                       "of another origin use its API",
                                       origin.empty() ? "" : " from " + origin.substr(0, 100)));
      case detail::OriginVerdict::allowed:
        if (!origin.empty()) {
          res.set_header("Access-Control-Allow-Origin", origin);
          // The answers' headers a page of that origin may read (fetch hides the others).
          res.set_header("Access-Control-Expose-Headers",
                         "X-Extract-Seconds, X-Encode-Seconds, X-Wait-Seconds, X-Triangles, X-Vertices, X-Active-Tetrahedra, "
                         "X-Incremental, X-In-Range, X-Level, X-Distance, X-Rank, X-Error-Bound, X-Error-Guaranteed, X-Encoding, "
                         "X-Triangles-Before, X-Simplify-Seconds, X-Tetrahedra, Content-Disposition, Retry-After");
        }
        break;
      case detail::OriginVerdict::same_origin:
        break;
    }
    res.set_header("Vary", "Origin");
  }
  return httplib::Server::HandlerResponse::Unhandled;
}

int ViewServer::bind() {
  auto& s = impl_->http;
  int port = impl_->opt.port;
  if (port == 0)
    port = s.bind_to_any_port(impl_->opt.host);
  else if (!s.bind_to_port(impl_->opt.host, port))
    port = -1;
  if (port < 0)
    throw InputError(fmt::format("cannot listen on {}:{} (in use, or not an address of this machine)", impl_->opt.host, impl_->opt.port));
  return port;
}

void ViewServer::listen() { impl_->http.listen_after_bind(); }
void ViewServer::stop() {
  if (impl_ && impl_->http.is_running()) impl_->http.stop();
}

std::uint64_t ViewServer::memory_budget() const { return impl_->opt.memory_budget; }

void ViewServer::set_progress(const std::string& stage, double fraction) {
  std::lock_guard lock(impl_->state_mutex);
  impl_->stage = stage;
  impl_->fraction = fraction;
}
void ViewServer::set_failed(const std::string& message) {
  std::lock_guard lock(impl_->state_mutex);
  impl_->failure = message;
}
void ViewServer::set_grid(std::shared_ptr<const PreparedGrid> g, std::function<std::shared_ptr<const PreparedGrid>()> rest) {
  std::lock_guard loading(impl_->rest_mutex);  // a rest being read is of the grid this one replaces
  impl_->install(std::move(g), std::move(rest));
}

void ViewServer::Impl::install(std::shared_ptr<const PreparedGrid> g, std::function<std::shared_ptr<const PreparedGrid>()> whole) {
  nlohmann::json hist;
  {
    std::lock_guard lock(state_mutex);
    if (volume) hist = histogram;
  }
  if (hist.is_null())  // no volume: the histogram of the grid's vertex values
    hist = histogram_json(vertex_histogram(g->grid), "vertices");
  auto q = g->hierarchy ? std::make_shared<const HierarchyQuery>(g) : nullptr;
  sessions.set_grid(g);
  std::lock_guard lock(state_mutex);
  query = q;
  histogram = hist;
  grid = std::move(g);
  rest = loaded_in_part(*grid) ? std::move(whole) : nullptr;
  rest_failed.clear();
  stage = "ready";
  fraction = 1;
}

// The routes that walk the tetrahedra (an error level's extractor, the wireframe) read them here
// the first time, while the others go on being served from the part loaded.
ViewServer::Impl::Served ViewServer::Impl::served_whole() {
  if (Served s = served_now(); !loaded_in_part(*s.grid)) return s;
  std::lock_guard loading(rest_mutex);
  const Served s = served_now();
  if (!loaded_in_part(*s.grid)) return s;  // read while this request waited
  std::function<std::shared_ptr<const PreparedGrid>()> read;
  {
    std::lock_guard lock(state_mutex);
    if (!rest_failed.empty()) throw InputError(rest_failed);
    read = rest;
  }
  if (!read) throw std::logic_error("a grid loaded in part was served without the means to read the rest");
  std::shared_ptr<const PreparedGrid> whole;
  try {
    whole = read();
  } catch (const InputError& e) {  // asked again, the same answer without reading again
    std::lock_guard lock(state_mutex);
    rest_failed = e.what();
    throw;
  }
  install(std::move(whole), nullptr);
  return served_now();
}
void ViewServer::set_volume(std::shared_ptr<const Volume> v) {
  const nlohmann::json hist = histogram_json(histogram(*v, kHistogramBins), "voxels");
  std::lock_guard lock(impl_->state_mutex);
  impl_->volume = std::move(v);
  impl_->histogram = hist;
}

void ViewServer::Impl::info(const httplib::Request&, httplib::Response& res) {
  nlohmann::json j;
  {
    std::lock_guard lock(state_mutex);
    j = {{"state", grid ? "ready" : failure.empty() ? "preparing" : "failed"}, {"stage", stage}, {"progress", fraction}};
    if (!failure.empty()) j["error"] = failure;
    if (grid) {
      const auto& s = grid->grid.source;
      j.update({{"dims", s.volume_box()},  // the volume's: a padded lattice's surfaces are clipped to it
                {"spacing", s.spacing},
                {"origin", s.origin},
                {"direction", s.direction},
                {"min", s.min},
                {"max", s.max},
                {"type", s.type},
                {"kept", grid->grid.volume_vertex_count()},
                {"tetrahedra", tetrahedron_count(*grid)},
                {"histogram", histogram},
                {"reference", volume != nullptr},
                {"reduction", {{"method", s.method}, {"max_error", s.max_error}, {"threshold", s.threshold}}},
                {"source", fs::path(s.file).filename().string()},  // the file's name: never where it lies
                {"facts", nlohmann::json::parse(to_json(grid->stats))}});
      // The error of the prepared surface, and the coarser levels offered while dragging.
      const auto& st = grid->stats;
      j["error_bound"] = surface_error(st);
      j["error_guaranteed"] = st.error_bound >= 0;
      j["distance"] = query != nullptr;  // surfaces within a distance (voxels) can be asked for
    }
  }
  if (j.contains("kept")) {
    nlohmann::json ladder = nlohmann::json::array();
    for (const auto& l : sessions.levels()) ladder.push_back({{"bound", l.bound}, {"built", l.built}, {"cell_floor", l.cell_floor}});
    j["levels"] = ladder;
  }
  j["ranks"] = opt.ranks;
  const auto m = sessions.memory();
  j["memory"] = {
      {"budget", m.budget},   {"resident", m.resident},         {"extractors", m.extractors}, {"extractors_bytes", m.extractors_bytes},
      {"clients", m.clients}, {"levels_built", m.levels_built}, {"evicted", m.evicted},       {"refused", m.refused}};
  res.set_content(j.dump(), "application/json");
}

void ViewServer::Impl::surface(const httplib::Request& req, httplib::Response& res) {
  const double iso = parse_iso(req.params);
  const std::string id = client_id(req.params);
  const auto error = parse_optional(req.params, "error");
  const auto budget = parse_optional(req.params, "budget");
  const auto distance = parse_within(req.params);
  const bool compact = compact_format(req.params);
  const Served s = distance ? served_now() : served_whole();
  auto common_headers = [&](const std::string& body_encoding) {
    res.set_header("X-Encoding", body_encoding);
    res.set_header("Cache-Control", "no-store");
  };
  if (distance) {
    if (error || budget) throw BadRequest("distance= cannot be combined with error= or budget=");
    DistanceQueryStats st;
    // A page's previous query, if still running, is dropped. Requests without client= share the
    // name "default" (scripts, several at once): they cancel nothing.
    std::optional<detail::RunningQueries::Ticket> ticket;
    if (req.params.count("client")) ticket.emplace(running, id);
    int process = 0;
    const Mesh mesh = surface_within(s, iso, *distance, &st, ticket ? ticket->cancel() : nullptr, &process);
    const auto t0 = std::chrono::steady_clock::now();
    std::string body = compact ? encode_mesh_compact(mesh) : encode_mesh(mesh);
    const double encode = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    res.set_header("X-Extract-Seconds", seconds_text(st.refine_seconds + st.walk_seconds + st.march_seconds + st.collapse_seconds));
    res.set_header("X-Encode-Seconds", seconds_text(encode));
    res.set_header("X-Wait-Seconds", "0");
    res.set_header("X-Triangles", std::to_string(st.triangles));
    res.set_header("X-Vertices", std::to_string(st.vertices));
    res.set_header("X-Active-Tetrahedra", std::to_string(st.tetrahedra));
    res.set_header("X-Incremental", "0");
    res.set_header("X-In-Range", st.in_range ? "1" : "0");
    res.set_header("X-Level", "0");
    res.set_header("X-Distance", fmt::format("{:.17g}", distance->distance));
    res.set_header("X-Min-Piece", fmt::format("{:.17g}", st.min_piece));
    res.set_header("X-Specks", std::to_string(st.specks));
    res.set_header("X-Rank", std::to_string(process));
    // The vertices lie on the grid's own surface, whose error bound this is.
    res.set_header("X-Error-Bound", fmt::format("{:.17g}", surface_error(s.grid->stats)));
    res.set_header("X-Error-Guaranteed", s.grid->stats.error_bound >= 0 ? "1" : "0");
    common_headers(compact ? "compact" : "plain");
    res.set_content(std::move(body), "application/octet-stream");
    return;
  }
  const auto surface = sessions.surface(id, iso, error, budget);
  const Extractor& ex = surface.extractor();
  const ExtractStats& st = surface.stats();
  const auto t0 = std::chrono::steady_clock::now();
  // After incremental steps the mesh's triangles are in an order of its history's making, which
  // the codecs compress to nearly twice the bytes (the chest at rest: 8.7 bytes a triangle
  // against 4.9): sent in the fresh march's order. A fresh march's surface is in it already, and
  // goes as it is rather than copied through the identity.
  std::string body;
  if (!compact)
    body = encode_mesh(ex.mesh());
  else if (ex.last_was_incremental())
    body = encode_mesh_compact(ex.mesh(), ex.triangles_in_march_order());
  else
    body = encode_mesh_compact(ex.mesh());
  const double encode = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  res.set_header("X-Extract-Seconds", seconds_text(st.sweep_seconds + st.march_seconds));
  res.set_header("X-Encode-Seconds", seconds_text(encode));
  res.set_header("X-Wait-Seconds", seconds_text(surface.wait_seconds()));
  res.set_header("X-Triangles", std::to_string(st.triangles));
  res.set_header("X-Vertices", std::to_string(st.vertices));
  res.set_header("X-Active-Tetrahedra", std::to_string(st.active));
  res.set_header("X-Incremental", st.incremental ? "1" : "0");
  res.set_header("X-In-Range", st.in_range ? "1" : "0");
  res.set_header("X-Level", std::to_string(surface.level()));
  // The error of what is returned: guaranteed (bisection) or measured (Delaunay), data units; on
  // a floored level, of the tetrahedra this surface cuts.
  res.set_header("X-Error-Bound", fmt::format("{:.17g}", surface_error_bound(surface.grid(), ex.active())));
  res.set_header("X-Error-Guaranteed", surface.grid().stats.error_bound >= 0 ? "1" : "0");
  common_headers(compact ? "compact" : "plain");
  res.set_content(std::move(body), "application/octet-stream");
}

// The surface within distance= voxels of the grid's (a bisection grid's hierarchy query): one
// stateless query, no page state; its memory reserved for the time of the query.
Mesh ViewServer::Impl::surface_within(const Served& s, double iso, const Within& within, DistanceQueryStats* stats,
                                      const std::atomic<bool>* cancel, int* process) {
  if (!s.query) throw BadRequest("distance= needs a bisection grid (this one keeps no hierarchy)");
  if (!(within.distance >= 0) || !std::isfinite(within.distance)) throw BadRequest("distance must be a non-negative number of voxels");
  if (within.min_piece && (!(*within.min_piece >= 0) || !std::isfinite(*within.min_piece)))
    throw BadRequest("min_piece must be a non-negative number of voxels");
  const std::size_t expected = sessions.expected_triangles(Sessions::Transient::distance, iso, tetrahedron_count(*s.grid) / 8);
  const auto room = sessions.reserve(kDistanceBytesPerTriangle * expected);
  DistanceQueryStats own;
  if (!stats) stats = &own;
  int made_by = 0;
  Mesh mesh = opt.distance_surfaces
                  ? opt.distance_surfaces(*s.query, iso, within.distance, within.collapse, within.min_piece, stats, cancel, &made_by)
                  : s.query->extract_within(iso, within.distance, stats, within.collapse, cancel, {}, within.min_piece);
  if (process) *process = made_by;
  // The peak follows the marched triangles, collapses or not: those are what the next estimate counts.
  sessions.record_triangles(Sessions::Transient::distance, iso, stats->triangles + 2 * stats->collapsed);
  return mesh;
}

// The surface at rest (iso, error or distance), simplified to simplify= voxels (checked=1: each
// region's result checked, simplify.hpp), as a .glb or .ply file.
void ViewServer::Impl::download(const httplib::Request& req, httplib::Response& res) {
  const double iso = parse_iso(req.params);
  const std::string id = client_id(req.params);
  const auto error = parse_optional(req.params, "error");
  const double distance = parse_optional(req.params, "simplify").value_or(0);
  SimplifyOptions how;
  how.checked = parse_flag(req.params, "checked");
  const auto within = parse_within(req.params);
  const std::string format = export_format(req.params);
  const Served s = within ? served_now() : served_whole();
  if (within && error) throw BadRequest("distance= cannot be combined with error=");
  Mesh mesh;
  double error_bound = surface_error(s.grid->stats);
  if (within) {
    mesh = surface_within(s, iso, *within, nullptr);
  } else {
    const auto surface = sessions.surface(id, iso, error, std::nullopt);  // the level's lock, until copied
    mesh = surface.extractor().mesh();
    error_bound = surface_error(surface.grid().stats);
  }
  const auto room = sessions.reserve(kExportBytesPerTriangle * mesh.triangle_count());
  const Vec3& sp = s.grid->grid.source.spacing;  // the same on every level
  SimplifyStats st;
  const Mesh simplified = simplify_mesh(mesh, distance * std::min({sp[0], sp[1], sp[2]}), &st, how);
  const std::string name = fmt::format("adaptiso-{:.6g}.{}", iso, format);
  res.set_header("Content-Disposition", fmt::format("attachment; filename=\"{}\"", name));
  res.set_header("X-Triangles", std::to_string(st.triangles_after));
  res.set_header("X-Triangles-Before", std::to_string(st.triangles_before));
  res.set_header("X-Simplify-Seconds", seconds_text(st.seconds));
  res.set_header("X-Simplify-Checked", how.checked ? "1" : "0");
  res.set_header("X-Error-Bound", fmt::format("{:.17g}", error_bound));
  res.set_content(mesh_file_bytes(simplified, name), format == "glb" ? "model/gltf-binary" : "application/octet-stream");
}

void ViewServer::Impl::reference(const httplib::Request& req, httplib::Response& res) {
  const double iso = parse_iso(req.params);
  std::shared_ptr<const Volume> v;
  {
    std::lock_guard lock(state_mutex);
    v = volume;
  }
  if (!v) {
    res.status = 404;
    res.set_content("no volume loaded (the viewer was started on a grid file): no full-resolution reference\n", "text/plain");
    return;
  }
  const std::size_t expected =
      sessions.expected_triangles(Sessions::Transient::reference, iso, static_cast<std::size_t>(v->voxel_count() / 16));
  const auto room = sessions.reserve(kReferenceBytesPerTriangle * expected);
  const auto t0 = std::chrono::steady_clock::now();
  const Mesh m = marching_cubes(*v, iso);
  sessions.record_triangles(Sessions::Transient::reference, iso, m.triangle_count());
  res.set_header("X-Extract-Seconds", seconds_text(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()));
  res.set_header("X-Triangles", std::to_string(m.triangle_count()));
  res.set_header("X-Vertices", std::to_string(m.vertex_count()));
  res.set_content(encode_mesh(m), "application/octet-stream");
}

void ViewServer::Impl::points(const httplib::Request&, httplib::Response& res) {
  const auto g = served_now().grid;
  const auto room = sessions.reserve(16 * std::uint64_t{g->grid.vertex_count()});
  res.set_content(encode_points(g->grid), "application/octet-stream");
}

void ViewServer::Impl::tetrahedra(const httplib::Request& req, httplib::Response& res) {
  const auto p = served_whole().grid;
  const TetGrid& grid = p->grid;
  std::vector<std::uint32_t> tets;
  if (req.has_param("iso")) {
    query_active(p->index, grid, parse_iso(req.params), tets);
  } else {
    if (grid.tet_count() * 3 > kMaxWireframeEdges)
      throw BadRequest("the grid has too many edges to send; give iso= for the active tetrahedra");
    tets.resize(grid.tet_count());
    for (std::size_t t = 0; t < tets.size(); ++t) tets[t] = static_cast<std::uint32_t>(t);
  }
  // At most 6 edges a tetrahedron (8 bytes each, with the wireframe's own bookkeeping) and 4
  // corners (12 bytes each).
  const auto room = sessions.reserve(std::min<std::uint64_t>(tets.size() * 6, kMaxWireframeEdges) * 16 + tets.size() * 48);
  Wireframe w;
  try {
    w = tetrahedra_wireframe(grid, tets, kMaxWireframeEdges);
  } catch (const InputError& e) {
    throw BadRequest(e.what());
  }
  res.set_header("X-Tetrahedra", std::to_string(tets.size()));
  res.set_content(encode_wireframe(w), "application/octet-stream");
}

void ViewServer::Impl::routes() {
  // Maps the failures of a handler to answers: a bad request 400, a grid not ready 503, a request
  // the memory budget cannot hold now 503 with Retry-After, a bad input met by the library 400,
  // anything else is a bug: 500, and logged. An allocation that fails is answered like a request
  // that cannot fit, after dropping what is idle: it was a 500 that lasted (issue 41).
  auto guarded = [this](Handler fn) {
    return [this, fn](const httplib::Request& req, httplib::Response& res) {
      auto answer = [&](int status, const std::string& text) {
        res.status = status;
        res.set_content(text + "\n", "text/plain");
      };
      try {
        (this->*fn)(req, res);
      } catch (const BadRequest& e) {
        answer(400, e.what());
      } catch (const NotReady& e) {
        res.set_header("Retry-After", "1");
        answer(503, e.what());
      } catch (const detail::OverBudget& e) {
        res.set_header("Retry-After", "1");
        answer(503, e.what());
      } catch (const InputError& e) {
        answer(400, e.what());
      } catch (const ExtractCancelled&) {  // the page asked for another surface meanwhile, and dropped this one
        answer(409, "cancelled: the page asked for another surface");
      } catch (const std::bad_alloc&) {
        sessions.relieve();
        res.set_header("Retry-After", "1");
        answer(503, "out of memory: retry in a moment");
        std::cerr << "adaptiso view: out of memory answering " << req.path << "\n";
      } catch (const std::exception& e) {
        answer(500, std::string("internal error: ") + e.what());
        std::cerr << "adaptiso view: internal error answering " << req.path << ": " << e.what() << "\n";
      }
    };
  };
  const auto idle = std::chrono::milliseconds(static_cast<long long>(std::min(opt.thread_idle_seconds, 1e6) * 1000));
  http.new_task_queue = [idle] { return new detail::ElasticPool(256, idle, 4); };
  http.set_tcp_nodelay(true);  // small answers on a kept-alive connection were held back 40 ms (Nagle)
  // SO_REUSEADDR only (a restarted viewer binds its port at once), not httplib's SO_REUSEPORT too:
  // with it a second viewer on a port in use bound it silently and the kernel split the
  // connections between the two, so a page got some surfaces of the other's grid.
  http.set_socket_options([](socket_t sock) {
    const int yes = 1;
    setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
  });
  http.set_read_timeout(5, 0);
  http.set_keep_alive_timeout(5);
  http.set_keep_alive_max_count(1000);  // the page asks for a surface per slider step on one connection
  http.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) { return admit(req, res); });
  constexpr Handler handlers[] = {&Impl::info, &Impl::surface, &Impl::reference, &Impl::download, &Impl::points, &Impl::tetrahedra};
  static_assert(std::size(handlers) == std::size(kApiRoutes));
  for (std::size_t k = 0; k < std::size(kApiRoutes); ++k) http.Get(kApiRoutes[k], guarded(handlers[k]));
  http.Get("/api/.*", [](const httplib::Request& req, httplib::Response& res) {
    res.status = 404;
    res.set_content(fmt::format("unknown API route {}\n", req.path.substr(0, 80)), "text/plain");
  });
  http.Get("/.*", [this](const httplib::Request& req, httplib::Response& res) { serve_static(req, res); });
}

void ViewServer::Impl::serve_static(const httplib::Request& req, httplib::Response& res) {
  auto not_found = [&] {
    res.status = 404;
    res.set_content("not found\n", "text/plain");
  };
  const std::string path = req.path == "/" ? "/index.html" : req.path;
  // Only plain relative names inside the page's folder: no '..', no hidden files, no backslashes.
  if (path.size() > 512 || path.find('\\') != std::string::npos || path.find('\0') != std::string::npos ||
      path.find("/.") != std::string::npos || path.find("//") != std::string::npos)
    return not_found();
  if (!served.count(path.substr(1))) return not_found();  // only what the page loads
  const fs::path file = web_root / path.substr(1);
  std::error_code ec;
  const fs::path real = fs::weakly_canonical(file, ec);
  if (ec || !fs::is_regular_file(real, ec)) return not_found();
  const char* type = content_type(real);
  if (!type) return not_found();
  std::ifstream in(real, std::ios::binary);
  std::string body((std::istreambuf_iterator<char>(in)), {});
  res.set_content(body, type);
}

namespace detail {

std::vector<std::string> api_routes() {
  std::vector<std::string> out;
  for (const char* r : kApiRoutes) out.emplace_back(r);
  return out;
}

}  // namespace detail

}  // namespace adaptiso
