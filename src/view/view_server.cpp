// The viewer's HTTP server (see view_server.hpp). Handlers only parse parameters, call the
// library and encode the answer; the work (extraction, wireframes, histograms) is library code.
#include "adaptiso/view_server.hpp"
#include "view/elastic_pool.hpp"
#include "view/request.hpp"
#include "view/sessions.hpp"

#include <fmt/format.h>
#include <httplib.h>

#include <unistd.h>
#include <algorithm>
#include <atomic>
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
#include <thread>

#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/levels_of_detail.hpp"
#include "adaptiso/marching_cubes.hpp"
#include "adaptiso/mesh_codec.hpp"
#include "adaptiso/mesh_io.hpp"
#include "adaptiso/number.hpp"
#include "adaptiso/simplify.hpp"
#include "adaptiso/wireframe.hpp"

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
using detail::parse_iso;
using detail::parse_optional;

// The grid is not there yet (or its preparation failed): 503 with the message.
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

// u32 N, f32 positions[3N] (world), f32 values[N]
std::string encode_points(const TetGrid& grid) {
  const std::uint32_t N = static_cast<std::uint32_t>(grid.vertex_count());
  std::string out(4 + 16 * std::size_t{N}, '\0');
  std::memcpy(out.data(), &N, 4);
  for (std::uint32_t i = 0; i < N; ++i) {
    const Vec3 w = grid.world_position(i);
    float rec[3] = {static_cast<float>(w[0]), static_cast<float>(w[1]), static_cast<float>(w[2])};
    const float value = static_cast<float>(grid.values[i]);
    std::memcpy(out.data() + 4 + 12 * std::size_t{i}, rec, 12);
    std::memcpy(out.data() + 4 + 12 * std::size_t{N} + 4 * std::size_t{i}, &value, 4);
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

// The grid being served and its levels of detail, taken together (set_grid replaces both).
struct Served {
  std::shared_ptr<const PreparedGrid> grid;
  std::shared_ptr<LevelsOfDetail> levels;       // bisection grids only
  std::shared_ptr<const HierarchyQuery> query;  // bisection grids only: surfaces within a distance
  // The coarsest level within error= (the prepared grid without it, or without levels).
  std::size_t level_for(const std::optional<double>& error) const { return levels && error ? levels->level_for_error(*error) : 0; }
  std::shared_ptr<const PreparedGrid> at(std::size_t level) const { return level ? levels->grid(level) : grid; }
};

// The host name of a Host header ("name", "name:port", "[v6]:port").
std::string host_name(const std::string& header) {
  if (!header.empty() && header[0] == '[') return header.substr(0, header.find(']') + 1);
  return header.substr(0, header.find(':'));
}

bool is_ip_literal(const std::string& name) {
  if (name.size() > 2 && name.front() == '[' && name.back() == ']') return true;  // IPv6
  return !name.empty() &&
         std::all_of(name.begin(), name.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)) || c == '.'; });
}

constexpr int kHistogramBins = 128;
constexpr std::size_t kMaxWireframeEdges = 20'000'000;

}  // namespace

struct ViewServer::Impl {
  ViewOptions opt;
  httplib::Server http;
  fs::path web_root;
  std::set<std::string> served;  // the page's files (web_root/served.txt), relative to web_root

  std::mutex state_mutex;  // guards everything below
  std::string stage = "starting", failure;
  double fraction = 0;
  std::shared_ptr<const PreparedGrid> grid;
  // Bisection grids: coarser grids for dragging by an error bound, built in the background once a
  // page asks for one (error= or budget=; a page asking for distances never does, and building
  // them took the bunny 22 s of CPU), and the queries for surfaces within a distance.
  std::shared_ptr<LevelsOfDetail> levels;
  bool levels_started = false;
  std::shared_ptr<const HierarchyQuery> query;
  std::shared_ptr<const Volume> volume;
  nlohmann::json histogram;

  std::thread level_builder;
  std::atomic<bool> stop_building{false};
  std::unique_ptr<detail::Sessions> sessions;  // the pages' extractors and the follower (sessions.hpp)

  std::mutex builder_mutex;  // guards level_builder
  void build_levels(std::shared_ptr<LevelsOfDetail> lod);
  void need_levels();
  Served served_now();  // throws NotReady while preparing
  std::shared_ptr<const PreparedGrid> ready() { return served_now().grid; }

  void routes();
  bool host_allowed(const httplib::Request& req) const;
  void info(const httplib::Request& req, httplib::Response& res);
  void surface(const httplib::Request& req, httplib::Response& res);
  void surface_within(const httplib::Request& req, httplib::Response& res, const Served& s, double iso, double distance, bool compact);
  void reference(const httplib::Request& req, httplib::Response& res);
  void download(const httplib::Request& req, httplib::Response& res);
  void points(const httplib::Request& req, httplib::Response& res);
  void tetrahedra(const httplib::Request& req, httplib::Response& res);
  void serve_static(const httplib::Request& req, httplib::Response& res);
};

Served ViewServer::Impl::served_now() {
  std::lock_guard lock(state_mutex);
  if (!grid)
    throw NotReady(failure.empty() ? fmt::format("the grid is not ready yet ({} {:.0f} %)", stage, fraction * 100)
                                   : "preparation failed: " + failure);
  return {grid, levels, query};
}

// The levels of detail are built from the first request that needs them.
void ViewServer::Impl::need_levels() {
  std::shared_ptr<LevelsOfDetail> lod;
  {
    std::lock_guard lock(state_mutex);
    if (levels_started || !levels) return;
    levels_started = true;
    lod = levels;
  }
  std::lock_guard lock(builder_mutex);
  build_levels(lod);
}

ViewServer::ViewServer(ViewOptions options) : impl_(std::make_unique<Impl>()) {
  impl_->opt = std::move(options);
  std::error_code ec;
  impl_->web_root = fs::weakly_canonical(impl_->opt.web_dir, ec);
  if (ec || !fs::is_regular_file(impl_->web_root / "index.html"))
    throw OptionError("web_dir", fmt::format("{}: the viewer page is not there (no index.html)", impl_->opt.web_dir));
  impl_->served = read_served_files(impl_->web_root);
  impl_->sessions = std::make_unique<detail::Sessions>(impl_->opt.max_clients);
  impl_->routes();
}

ViewServer::~ViewServer() {
  stop();
  impl_->stop_building = true;
  if (impl_->level_builder.joinable()) impl_->level_builder.join();
}

// Coarser grids for dragging, coarsest first, while the page already shows the prepared one.
void ViewServer::Impl::build_levels(std::shared_ptr<LevelsOfDetail> lod) {
  stop_building = true;
  if (level_builder.joinable()) level_builder.join();
  stop_building = false;
  if (!lod) return;
  level_builder = std::thread([this, lod] {
    try {
      lod->build(&stop_building);
    } catch (const std::exception& e) {  // out of memory, most likely: the page keeps the levels it has
      std::cerr << "adaptiso view: levels of detail stopped: " << e.what() << "\n";
    }
  });
}

// Pages reach a local server through DNS rebinding (a name that resolves to 127.0.0.1): only the
// names and addresses the server listens on are accepted, and IP literals when it listens on all
// interfaces, with the machine's own name.
bool ViewServer::Impl::host_allowed(const httplib::Request& req) const {
  if (!req.has_header("Host")) return true;  // HTTP/1.0 clients
  std::string name = host_name(req.get_header_value("Host"));
  for (auto& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (name == "localhost" || name == "127.0.0.1" || name == "[::1]" || name == opt.host) return true;
  if (opt.host == "0.0.0.0" || opt.host == "::") {
    char machine[256] = {};
    gethostname(machine, sizeof machine - 1);
    return is_ip_literal(name) || name == machine;
  }
  return false;
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

void ViewServer::set_progress(const std::string& stage, double fraction) {
  std::lock_guard lock(impl_->state_mutex);
  impl_->stage = stage;
  impl_->fraction = fraction;
}
void ViewServer::set_failed(const std::string& message) {
  std::lock_guard lock(impl_->state_mutex);
  impl_->failure = message;
}
void ViewServer::set_grid(std::shared_ptr<const PreparedGrid> g) {
  nlohmann::json hist;
  {
    std::lock_guard lock(impl_->state_mutex);
    if (impl_->volume) hist = impl_->histogram;
  }
  if (hist.is_null())  // no volume: the histogram of the grid's vertex values
    hist = histogram_json(histogram(g->grid.values, {g->grid.source.min, g->grid.source.max}, kHistogramBins), "vertices");
  auto lod = g->hierarchy ? std::make_shared<LevelsOfDetail>(g) : nullptr;
  auto query = g->hierarchy ? std::make_shared<const HierarchyQuery>(g) : nullptr;
  {
    std::lock_guard lock(impl_->builder_mutex);
    impl_->build_levels(nullptr);  // stops the last grid's
  }
  std::lock_guard lock(impl_->state_mutex);
  impl_->levels = lod;
  impl_->levels_started = false;
  impl_->query = query;
  impl_->sessions->clear();  // a client's Extractor keeps its own grid alive; new requests start on this one
  impl_->histogram = hist;
  impl_->grid = std::move(g);
  impl_->stage = "ready";
  impl_->fraction = 1;
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
      j.update({{"dims", s.dims},
                {"spacing", s.spacing},
                {"origin", s.origin},
                {"direction", s.direction},
                {"min", s.min},
                {"max", s.max},
                {"type", s.type},
                {"kept", grid->grid.vertex_count()},
                {"tetrahedra", grid->grid.tet_count()},
                {"histogram", histogram},
                {"reference", volume != nullptr},
                {"reduction", {{"method", s.method}, {"max_error", s.max_error}, {"threshold", s.threshold}}},
                {"source", fs::path(s.file).filename().string()},  // the file's name: never where it lies
                {"facts", nlohmann::json::parse(to_json(grid->stats))}});
      // The error of the prepared surface, and the coarser levels offered while dragging.
      const auto& st = grid->stats;
      j["error_bound"] = surface_error(st);
      j["error_guaranteed"] = st.error_bound >= 0;
      nlohmann::json ladder = nlohmann::json::array();
      if (levels)
        for (std::size_t k = 0; k < levels->size(); ++k)
          ladder.push_back({{"bound", levels->bound(k)}, {"built", levels->grid(k) != nullptr}, {"cell_floor", levels->cell_floor(k)}});
      j["levels"] = ladder;
      j["distance"] = query != nullptr;  // surfaces within a distance (voxels) can be asked for
    }
  }
  res.set_content(j.dump(), "application/json");
}

void ViewServer::Impl::surface(const httplib::Request& req, httplib::Response& res) {
  const double iso = parse_iso(req.params);
  const std::string id = client_id(req.params);
  const auto error = parse_optional(req.params, "error");
  const auto budget = parse_optional(req.params, "budget");
  const auto distance = parse_optional(req.params, "distance");
  const bool compact = compact_format(req.params);
  const Served s = served_now();
  if (distance) {
    if (error || budget) throw BadRequest("distance= cannot be combined with error= or budget=");
    return surface_within(req, res, s, iso, *distance, compact);
  }
  if (error || budget) need_levels();
  // The level shown when the slider rests: the coarsest within error=; while dragging, as fine as
  // the triangle budget allows but no finer.
  const std::size_t rest = s.level_for(error);
  const std::size_t level =
      s.levels && budget ? s.levels->level_for_budget(static_cast<std::size_t>(std::min(*budget, 4e9)), rest, iso) : rest;
  const auto grid = s.at(level);
  auto slot = sessions->slot(id, level);
  const auto queued = std::chrono::steady_clock::now();
  // One extraction at a time per page and level; others run freely. The follower yields to this
  // request (or finishes, when it is extracting this very surface), and its jobs for the level
  // queued before it are dropped.
  const auto lock = slot->lock_for_page(iso, grid.get());
  // Time spent behind this level's other work (the follower's current stage, or its extraction of
  // this surface), reported apart.
  const double wait = std::chrono::duration<double>(std::chrono::steady_clock::now() - queued).count();
  ExtractStats st;
  slot->at(grid, iso, &st);
  if (s.levels) s.levels->record(level, st.triangles, iso);
  if (level != rest) sessions->follow(id, rest, s.at(rest), iso);
  const Extractor* ex = slot->extractor.get();
  const auto t0 = std::chrono::steady_clock::now();
  // After incremental steps the mesh's triangles are in an order of its history's making, which
  // the codecs compress to nearly twice the bytes (the chest at rest: 8.7 bytes a triangle
  // against 4.9): sent in the fresh march's order. A fresh march's surface is in it already, and
  // goes as it is rather than copied through the identity.
  std::string body;
  if (!compact)
    body = encode_mesh(ex->mesh());
  else if (ex->last_was_incremental())
    body = encode_mesh_compact(ex->mesh(), ex->triangles_in_march_order());
  else
    body = encode_mesh_compact(ex->mesh());
  const double encode = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  res.set_header("X-Extract-Seconds", fmt::format("{:.6f}", st.sweep_seconds + st.march_seconds));
  res.set_header("X-Encode-Seconds", fmt::format("{:.6f}", encode));
  res.set_header("X-Wait-Seconds", fmt::format("{:.6f}", wait));
  res.set_header("X-Triangles", std::to_string(st.triangles));
  res.set_header("X-Vertices", std::to_string(st.vertices));
  res.set_header("X-Active-Tetrahedra", std::to_string(st.active));
  res.set_header("X-Incremental", st.incremental ? "1" : "0");
  res.set_header("X-In-Range", st.in_range ? "1" : "0");
  res.set_header("X-Level", std::to_string(level));
  // The error of what is returned: guaranteed (bisection) or measured (Delaunay), data units; on
  // a floored level, of the tetrahedra this surface cuts.
  res.set_header("X-Error-Bound", fmt::format("{:.17g}", surface_error_bound(*grid, ex->active())));
  res.set_header("X-Error-Guaranteed", grid->stats.error_bound >= 0 ? "1" : "0");
  res.set_header("X-Encoding", compact ? "compact" : "plain");
  res.set_header("Cache-Control", "no-store");
  res.set_content(std::move(body), "application/octet-stream");
}

// The surface within distance= voxels of the grid's (a bisection grid's hierarchy query): one
// stateless query, no page state.
void ViewServer::Impl::surface_within(const httplib::Request&, httplib::Response& res, const Served& s, double iso, double distance,
                                      bool compact) {
  if (!s.query) throw BadRequest("distance= needs a bisection grid (this one keeps no hierarchy)");
  if (!(distance >= 0) || !std::isfinite(distance)) throw BadRequest("distance must be a non-negative number of voxels");
  DistanceQueryStats st;
  const Mesh mesh = s.query->extract_within(iso, distance, &st);
  const auto t0 = std::chrono::steady_clock::now();
  std::string body = compact ? encode_mesh_compact(mesh) : encode_mesh(mesh);
  const double encode = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  res.set_header("X-Extract-Seconds", fmt::format("{:.6f}", st.refine_seconds + st.walk_seconds + st.march_seconds));
  res.set_header("X-Encode-Seconds", fmt::format("{:.6f}", encode));
  res.set_header("X-Wait-Seconds", "0");
  res.set_header("X-Triangles", std::to_string(st.triangles));
  res.set_header("X-Vertices", std::to_string(st.vertices));
  res.set_header("X-Active-Tetrahedra", std::to_string(st.tetrahedra));
  res.set_header("X-Incremental", "0");
  res.set_header("X-In-Range", st.in_range ? "1" : "0");
  res.set_header("X-Level", "0");
  res.set_header("X-Distance", fmt::format("{:.17g}", distance));
  // The vertices lie on the grid's own surface, whose error bound this is.
  res.set_header("X-Error-Bound", fmt::format("{:.17g}", surface_error(s.grid->stats)));
  res.set_header("X-Error-Guaranteed", s.grid->stats.error_bound >= 0 ? "1" : "0");
  res.set_header("X-Encoding", compact ? "compact" : "plain");
  res.set_header("Cache-Control", "no-store");
  res.set_content(std::move(body), "application/octet-stream");
}

// The surface at rest (iso, error or distance), simplified to simplify= voxels, as a .glb or .ply file.
void ViewServer::Impl::download(const httplib::Request& req, httplib::Response& res) {
  const double iso = parse_iso(req.params);
  const std::string id = client_id(req.params);
  const auto error = parse_optional(req.params, "error");
  const double distance = parse_optional(req.params, "simplify").value_or(0);
  const auto within = parse_optional(req.params, "distance");
  const std::string format = export_format(req.params);
  const Served s = served_now();
  if (within && error) throw BadRequest("distance= cannot be combined with error=");
  if (within && !s.query) throw BadRequest("distance= needs a bisection grid (this one keeps no hierarchy)");
  if (within && (!(*within >= 0) || !std::isfinite(*within))) throw BadRequest("distance must be a non-negative number of voxels");
  if (error) need_levels();
  const std::size_t level = s.level_for(error);
  const auto grid = s.at(level);
  Mesh mesh;
  if (within) {
    mesh = s.query->extract_within(iso, *within);
  } else {
    auto slot = sessions->slot(id, level);
    const auto lock = slot->lock_for_page(iso, grid.get());
    mesh = slot->at(grid, iso);
  }
  const Vec3& sp = grid->grid.source.spacing;
  SimplifyStats st;
  const Mesh simplified = simplify_mesh(mesh, distance * std::min({sp[0], sp[1], sp[2]}), &st);
  const std::string name = fmt::format("adaptiso-{:.6g}.{}", iso, format);
  res.set_header("Content-Disposition", fmt::format("attachment; filename=\"{}\"", name));
  res.set_header("X-Triangles", std::to_string(st.triangles_after));
  res.set_header("X-Triangles-Before", std::to_string(st.triangles_before));
  res.set_header("X-Simplify-Seconds", fmt::format("{:.6f}", st.seconds));
  res.set_header("X-Error-Bound", fmt::format("{:.17g}", surface_error(grid->stats)));
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
  const auto t0 = std::chrono::steady_clock::now();
  const Mesh m = marching_cubes(*v, iso);
  res.set_header("X-Extract-Seconds", fmt::format("{:.6f}", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()));
  res.set_header("X-Triangles", std::to_string(m.triangle_count()));
  res.set_header("X-Vertices", std::to_string(m.vertex_count()));
  res.set_content(encode_mesh(m), "application/octet-stream");
}

void ViewServer::Impl::points(const httplib::Request&, httplib::Response& res) {
  res.set_content(encode_points(ready()->grid), "application/octet-stream");
}

void ViewServer::Impl::tetrahedra(const httplib::Request& req, httplib::Response& res) {
  auto p = ready();
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
  // Maps the failures of a handler to answers: a bad request 400, a grid not ready 503, a bad
  // input met by the library 400, anything else is a bug: 500, and logged.
  auto guarded = [this](void (Impl::*fn)(const httplib::Request&, httplib::Response&)) {
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
        answer(503, e.what());
      } catch (const InputError& e) {
        answer(400, e.what());
      } catch (const std::bad_alloc&) {
        answer(500, "out of memory");
        std::cerr << "adaptiso view: out of memory answering " << req.path << "\n";
      } catch (const std::exception& e) {
        answer(500, std::string("internal error: ") + e.what());
        std::cerr << "adaptiso view: internal error answering " << req.path << ": " << e.what() << "\n";
      }
    };
  };
  http.new_task_queue = [] { return new detail::ElasticPool(256); };
  http.set_tcp_nodelay(true);  // small answers on a kept-alive connection were held back 40 ms (Nagle)
  http.set_read_timeout(5, 0);
  http.set_keep_alive_timeout(5);
  http.set_keep_alive_max_count(1000);  // the page asks for a surface per slider step on one connection
  http.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    if (host_allowed(req)) return httplib::Server::HandlerResponse::Unhandled;
    res.status = 403;
    res.set_content("host not allowed (the viewer answers only to the names and addresses it listens on)\n", "text/plain");
    return httplib::Server::HandlerResponse::Handled;
  });
  http.set_payload_max_length(1 << 16);
  http.Get("/api/info", guarded(&Impl::info));
  http.Get("/api/surface", guarded(&Impl::surface));
  http.Get("/api/reference", guarded(&Impl::reference));
  http.Get("/api/export", guarded(&Impl::download));
  http.Get("/api/points", guarded(&Impl::points));
  http.Get("/api/tetrahedra", guarded(&Impl::tetrahedra));
  http.Get("/api/.*", [](const httplib::Request& req, httplib::Response& res) {
    res.status = 404;
    res.set_content(fmt::format("unknown API route {}\n", req.path.substr(0, 80)), "text/plain");
  });
  http.Get("/.*", [this](const httplib::Request& req, httplib::Response& res) { serve_static(req, res); });
  auto not_allowed = [](const httplib::Request&, httplib::Response& res) {
    res.status = 405;
    res.set_content("only GET is served\n", "text/plain");
  };
  http.Post("/.*", not_allowed);
  http.Put("/.*", not_allowed);
  http.Delete("/.*", not_allowed);
  http.Options("/.*", not_allowed);
  http.Patch("/.*", not_allowed);
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

}  // namespace adaptiso
