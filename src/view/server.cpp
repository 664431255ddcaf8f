// The viewer's HTTP server (see view_server.hpp).
#include "adaptiso/view_server.hpp"

#include <httplib.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fmt/format.h>
#include <fstream>
#include <list>
#include <mutex>
#include <unordered_map>

#include "adaptiso/error.hpp"
#include "adaptiso/extract.hpp"
#include "adaptiso/marching_cubes.hpp"
#include "adaptiso/mesh.hpp"
#include "adaptiso/number.hpp"

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

struct BadRequest : std::runtime_error {
  using std::runtime_error::runtime_error;
};

double parse_iso(const httplib::Request& req) {
  if (!req.has_param("iso")) throw BadRequest("missing parameter iso");
  const std::string s = req.get_param_value("iso");
  auto x = parse_finite(s);
  if (!x) throw BadRequest(fmt::format("iso must be a finite number, not '{}'", s.substr(0, 40)));
  return *x;
}

std::string client_id(const httplib::Request& req) {
  if (!req.has_param("client")) return "default";
  std::string c = req.get_param_value("client");
  if (c.empty() || c.size() > 64 || !std::all_of(c.begin(), c.end(), [](char ch) { return std::isalnum(static_cast<unsigned char>(ch)) || ch == '-' || ch == '_'; }))
    throw BadRequest("client must be 1-64 letters, digits, '-' or '_'");
  return c;
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

struct Client {
  std::mutex mutex;
  std::unique_ptr<Extractor> extractor;
};

}  // namespace

struct ViewServer::Impl {
  ViewOptions opt;
  httplib::Server http;
  fs::path web_root;

  std::mutex state_mutex;  // guards everything below
  std::string stage = "starting", failure;
  double fraction = 0;
  std::shared_ptr<const TetGrid> grid;
  std::shared_ptr<const IntervalTree> index;
  std::shared_ptr<const Volume> volume;
  nlohmann::json facts;
  nlohmann::json histogram;
  std::list<std::string> lru;  // most recent first
  std::unordered_map<std::string, std::pair<std::shared_ptr<Client>, std::list<std::string>::iterator>> clients;

  std::shared_ptr<Client> client(const std::string& id) {
    std::lock_guard lock(state_mutex);
    auto it = clients.find(id);
    if (it != clients.end()) {
      lru.splice(lru.begin(), lru, it->second.second);
      return it->second.first;
    }
    while (clients.size() >= opt.max_clients && !lru.empty()) {
      clients.erase(lru.back());
      lru.pop_back();
    }
    lru.push_front(id);
    auto c = std::make_shared<Client>();
    clients[id] = {c, lru.begin()};
    return c;
  }

  // The ready grid, or throws (503) while preparing.
  std::pair<std::shared_ptr<const TetGrid>, std::shared_ptr<const IntervalTree>> ready() {
    std::lock_guard lock(state_mutex);
    if (!grid) throw std::logic_error(failure.empty() ? fmt::format("the grid is not ready yet ({} {:.0f} %)", stage, fraction * 100)
                                                      : "preparation failed: " + failure);
    return {grid, index};
  }

  void routes();
  void serve_static(const httplib::Request& req, httplib::Response& res);
};

ViewServer::ViewServer(ViewOptions options) : impl_(std::make_unique<Impl>()) {
  impl_->opt = std::move(options);
  std::error_code ec;
  impl_->web_root = fs::weakly_canonical(impl_->opt.web_dir, ec);
  if (ec || !fs::is_regular_file(impl_->web_root / "index.html"))
    throw InputError(fmt::format("{}: the viewer page is not there (index.html missing; run scripts/deps.sh or give --web DIR)", impl_->opt.web_dir));
  impl_->routes();
}

ViewServer::~ViewServer() { stop(); }

int ViewServer::bind() {
  auto& s = impl_->http;
  int port = impl_->opt.port;
  if (port == 0) port = s.bind_to_any_port(impl_->opt.host);
  else if (!s.bind_to_port(impl_->opt.host, port)) port = -1;
  if (port < 0) throw InputError(fmt::format("cannot listen on {}:{} (in use, or not an address of this machine)", impl_->opt.host, impl_->opt.port));
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
void ViewServer::set_grid(std::shared_ptr<const TetGrid> g, std::shared_ptr<const IntervalTree> idx, nlohmann::json facts) {
  nlohmann::json hist;
  {
    std::lock_guard lock(impl_->state_mutex);
    if (impl_->volume) hist = impl_->histogram;
  }
  if (hist.is_null()) {  // no volume: the histogram of the grid's vertex values
    const int bins = 128;
    std::vector<std::uint64_t> counts(bins, 0);
    const double lo = g->source.min, hi = g->source.max, w = hi > lo ? (hi - lo) / bins : 1;
    for (double x : g->values) counts[std::clamp(static_cast<int>((x - lo) / w), 0, bins - 1)]++;
    hist = {{"min", lo}, {"max", hi}, {"counts", counts}, {"of", "vertices"}};
  }
  std::lock_guard lock(impl_->state_mutex);
  impl_->clients.clear();  // extractors refer to the grid they were made for
  impl_->lru.clear();
  impl_->histogram = hist;
  impl_->grid = std::move(g);
  impl_->index = std::move(idx);
  impl_->facts = std::move(facts);
  impl_->stage = "ready";
  impl_->fraction = 1;
}
void ViewServer::set_volume(std::shared_ptr<const Volume> v) {
  auto h = histogram(*v, 128);
  nlohmann::json hist = {{"min", h.min}, {"max", h.max}, {"counts", h.counts}, {"of", "voxels"}};
  std::lock_guard lock(impl_->state_mutex);
  impl_->volume = std::move(v);
  impl_->histogram = hist;
}

void ViewServer::Impl::routes() {
  auto guarded = [this](auto fn) {
    return [this, fn](const httplib::Request& req, httplib::Response& res) {
      try {
        fn(req, res);
      } catch (const BadRequest& e) {
        res.status = 400;
        res.set_content(std::string(e.what()) + "\n", "text/plain");
      } catch (const std::logic_error& e) {  // not ready
        res.status = 503;
        res.set_content(std::string(e.what()) + "\n", "text/plain");
      } catch (const std::bad_alloc&) {
        res.status = 500;
        res.set_content("out of memory\n", "text/plain");
      } catch (const std::exception& e) {
        res.status = 500;
        res.set_content(std::string(e.what()) + "\n", "text/plain");
      }
    };
  };
  http.set_payload_max_length(1 << 16);
  http.Get("/api/info", guarded([this](const httplib::Request&, httplib::Response& res) {
    nlohmann::json j;
    {
      std::lock_guard lock(state_mutex);
      j = {{"state", grid ? "ready" : failure.empty() ? "preparing" : "failed"}, {"stage", stage}, {"progress", fraction}};
      if (!failure.empty()) j["error"] = failure;
      if (grid) {
        const auto& s = grid->source;
        j.update({{"dims", s.dims}, {"spacing", s.spacing}, {"origin", s.origin}, {"direction", s.direction},
                  {"min", s.min}, {"max", s.max}, {"type", s.type}, {"kept", grid->vertex_count()},
                  {"tetrahedra", grid->tet_count()}, {"histogram", histogram}, {"reference", volume != nullptr},
                  {"reduction", {{"method", s.method}, {"max_error", s.max_error}, {"threshold", s.threshold}}},
                  {"source", s.file}, {"facts", facts}});
      }
    }
    res.set_content(j.dump(), "application/json");
  }));
  http.Get("/api/surface", guarded([this](const httplib::Request& req, httplib::Response& res) {
    const double iso = parse_iso(req);
    const std::string id = client_id(req);
    auto [g, idx] = ready();
    auto c = client(id);
    std::lock_guard lock(c->mutex);  // one request at a time per client; other clients run freely
    if (!c->extractor) c->extractor = std::make_unique<Extractor>(*g, *idx);
    // The extractor refers to the grid; keep it alive while it is used (the grid never changes).
    ExtractStats st = c->extractor->extract(iso);
    res.set_header("X-Extract-Seconds", fmt::format("{:.6f}", st.sweep_seconds + st.march_seconds));
    res.set_header("X-Triangles", std::to_string(st.triangles));
    res.set_header("X-Vertices", std::to_string(st.vertices));
    res.set_header("X-Active-Tetrahedra", std::to_string(st.active));
    res.set_header("X-Incremental", c->extractor->last_was_incremental() ? "1" : "0");
    res.set_header("X-In-Range", st.in_range ? "1" : "0");
    res.set_header("Cache-Control", "no-store");
    res.set_content(encode_mesh(c->extractor->mesh()), "application/octet-stream");
  }));
  http.Get("/api/reference", guarded([this](const httplib::Request& req, httplib::Response& res) {
    const double iso = parse_iso(req);
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
    auto t0 = std::chrono::steady_clock::now();
    Mesh m = marching_cubes(*v, iso);
    res.set_header("X-Extract-Seconds", fmt::format("{:.6f}", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()));
    res.set_header("X-Triangles", std::to_string(m.triangle_count()));
    res.set_header("X-Vertices", std::to_string(m.vertex_count()));
    res.set_content(encode_mesh(m), "application/octet-stream");
  }));
  http.Get("/api/points", guarded([this](const httplib::Request&, httplib::Response& res) {
    auto [g, idx] = ready();
    // u32 N, f32 positions[3N] (world), f32 values[N]
    const std::uint32_t N = static_cast<std::uint32_t>(g->vertex_count());
    std::string out(4 + 16 * std::size_t{N}, '\0');
    std::memcpy(out.data(), &N, 4);
    float* pos = reinterpret_cast<float*>(out.data() + 4);
    float* val = pos + 3 * std::size_t{N};
    for (std::uint32_t i = 0; i < N; ++i) {
      Vec3 w = g->world_position(i);
      for (int a = 0; a < 3; ++a) pos[3 * i + a] = static_cast<float>(w[a]);
      val[i] = static_cast<float>(g->values[i]);
    }
    res.set_content(out, "application/octet-stream");
  }));
  http.Get("/api/tetrahedra", guarded([this](const httplib::Request& req, httplib::Response& res) {
    auto [g, idx] = ready();
    constexpr std::size_t kMaxEdges = 20'000'000;
    std::vector<std::uint32_t> tets;
    if (req.has_param("iso")) {
      const double iso = parse_iso(req);
      query_active(*idx, *g, iso, tets);
    } else {
      if (g->tet_count() * 6 / 2 > kMaxEdges) throw BadRequest("the grid has too many edges to send; give iso= for the active tetrahedra");
      tets.resize(g->tet_count());
      for (std::size_t t = 0; t < tets.size(); ++t) tets[t] = static_cast<std::uint32_t>(t);
    }
    std::vector<std::uint64_t> edges;
    edges.reserve(tets.size() * 6);
    for (std::uint32_t t : tets) {
      const auto& q = g->tets[t];
      for (int a = 0; a < 4; ++a)
        for (int b = a + 1; b < 4; ++b) edges.push_back((std::uint64_t{std::min(q[a], q[b])} << 32) | std::max(q[a], q[b]));
    }
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    if (edges.size() > kMaxEdges) throw BadRequest("too many edges to send at this iso-value");
    // Vertices used, renumbered: u32 V, u32 E, f32 positions[3V], u32 pairs[2E]
    std::vector<std::uint32_t> verts;
    verts.reserve(edges.size());
    for (auto e : edges) verts.push_back(static_cast<std::uint32_t>(e >> 32)), verts.push_back(static_cast<std::uint32_t>(e));
    std::sort(verts.begin(), verts.end());
    verts.erase(std::unique(verts.begin(), verts.end()), verts.end());
    const std::uint32_t V = static_cast<std::uint32_t>(verts.size()), E = static_cast<std::uint32_t>(edges.size());
    std::string out(8 + 12 * std::size_t{V} + 8 * std::size_t{E}, '\0');
    std::memcpy(out.data(), &V, 4);
    std::memcpy(out.data() + 4, &E, 4);
    float* pos = reinterpret_cast<float*>(out.data() + 8);
    for (std::uint32_t i = 0; i < V; ++i) {
      Vec3 w = g->world_position(verts[i]);
      for (int a = 0; a < 3; ++a) pos[3 * i + a] = static_cast<float>(w[a]);
    }
    std::uint32_t* pairs = reinterpret_cast<std::uint32_t*>(out.data() + 8 + 12 * std::size_t{V});
    auto local = [&](std::uint32_t v) { return static_cast<std::uint32_t>(std::lower_bound(verts.begin(), verts.end(), v) - verts.begin()); };
    for (std::uint32_t e = 0; e < E; ++e) {
      pairs[2 * e] = local(static_cast<std::uint32_t>(edges[e] >> 32));
      pairs[2 * e + 1] = local(static_cast<std::uint32_t>(edges[e]));
    }
    res.set_header("X-Tetrahedra", std::to_string(tets.size()));
    res.set_content(out, "application/octet-stream");
  }));
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
}

void ViewServer::Impl::serve_static(const httplib::Request& req, httplib::Response& res) {
  auto not_found = [&] {
    res.status = 404;
    res.set_content("not found\n", "text/plain");
  };
  std::string path = req.path == "/" ? "/index.html" : req.path;
  // Only plain relative names inside the page's folder: no '..', no hidden files, no backslashes.
  if (path.size() > 512 || path.find('\\') != std::string::npos || path.find('\0') != std::string::npos ||
      path.find("/.") != std::string::npos || path.find("//") != std::string::npos)
    return not_found();
  const fs::path file = web_root / path.substr(1);
  std::error_code ec;
  const fs::path real = fs::weakly_canonical(file, ec);
  const std::string root = web_root.string() + "/";
  if (ec || real.string().compare(0, root.size(), root) != 0 || !fs::is_regular_file(real, ec)) return not_found();
  const char* type = content_type(real);
  if (!type) return not_found();
  std::ifstream in(real, std::ios::binary);
  std::string body((std::istreambuf_iterator<char>(in)), {});
  res.set_content(body, type);
}

}  // namespace adaptiso
