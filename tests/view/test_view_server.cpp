// The viewer's HTTP server, in process, through cpp-httplib's client: the API against direct
// library calls, bad requests (400/404/405, path traversal), the preparing state, and many
// concurrent clients. The browser end-to-end test is tests/browser/viewer.test.mjs.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <httplib.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstring>
#include <nlohmann/json.hpp>
#include <thread>

#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/marching_cubes.hpp"
#include "adaptiso/mesh_codec.hpp"
#include "adaptiso/mesh_io.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/view_server.hpp"
#include "server_fixture.hpp"
#include "test_util.hpp"

using namespace adaptiso;
using testutil::RawConnection;
using testutil::Running;
using testutil::seconds_since;

namespace {

struct Fixture {
  std::shared_ptr<Volume> volume;
  std::shared_ptr<const PreparedGrid> grid;
};

Fixture sphere_grid() {
  Fixture f;
  f.volume = std::make_shared<Volume>(make_synthetic("sphere", 24, ScalarType::i16));
  ReduceOptions o;
  o.relative = true;
  o.max_error = 0.05;
  f.grid = testutil::prepared(testutil::build_grid(*f.volume, reduce(*f.volume, o).kept));
  return f;
}

// /api/info once every level of detail is built (they are built in the background), or after 10 s.
// The levels are built once a request asks for one (error= or budget=).
nlohmann::json info_with_levels_built(httplib::Client& c) {
  nlohmann::json info = nlohmann::json::parse(c.Get("/api/info")->body);
  if (info["levels"].size() > 1) c.Get(fmt::format("/api/surface?iso={:.17g}&client=levels&budget=1000", info["min"].get<double>()));
  for (int i = 0; i < 500; ++i) {
    info = nlohmann::json::parse(c.Get("/api/info")->body);
    if (std::all_of(info["levels"].begin(), info["levels"].end(), [](const auto& l) { return l["built"].template get<bool>(); })) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return info;
}

std::uint32_t triangles_in(const std::string& body) {
  std::uint32_t vt[2];
  EXPECT_GE(body.size(), 8u);
  std::memcpy(vt, body.data(), 8);
  EXPECT_EQ(body.size(), 8 + 24 * std::size_t{vt[0]} + 12 * std::size_t{vt[1]});
  return vt[1];
}

// The triangles of an encoded mesh as corner positions and normals, sorted: equal for two
// encodings of the same surface whatever their vertex numbering and triangle order (an
// Extractor's depend on its history, and the server may have dropped a client's state in between).
std::vector<std::array<float, 18>> corners(const std::string& body) {
  std::uint32_t vt[2];
  std::memcpy(vt, body.data(), 8);
  if (body.size() != 8 + 24 * std::size_t{vt[0]} + 12 * std::size_t{vt[1]}) return {};
  const char* pos = body.data() + 8;
  const char* nrm = pos + 12 * std::size_t{vt[0]};
  const char* tri = nrm + 12 * std::size_t{vt[0]};
  std::vector<std::array<float, 18>> out(vt[1]);
  for (std::size_t k = 0; k < 3 * std::size_t{vt[1]}; ++k) {
    std::uint32_t v;
    std::memcpy(&v, tri + 4 * k, 4);
    if (v >= vt[0]) return {};
    std::memcpy(&out[k / 3][6 * (k % 3)], pos + 12 * std::size_t{v}, 12);
    std::memcpy(&out[k / 3][6 * (k % 3) + 3], nrm + 12 * std::size_t{v}, 12);
  }
  std::sort(out.begin(), out.end());
  return out;
}

// A bisection grid prepared from a synthetic volume, at a relative error.
std::shared_ptr<const PreparedGrid> bisection_grid_of(const Volume& v, double relative_error) {
  PrepareOptions o;
  o.max_error = relative_error;
  o.relative = true;
  return std::make_shared<const PreparedGrid>(prepare(v, o));
}

bool same_surface(const std::string& a, const std::string& b) {
  return a.size() == b.size() && a.compare(0, 8, b, 0, 8) == 0 && corners(a) == corners(b);
}

}  // namespace

TEST(ViewServer, EncodesTheDocumentedLayout) {
  Mesh m;
  m.positions = {{1, 2, 3}, {4, 5, 6}, {7, 8, 9}};
  m.normals = {{0, 0, 1}, {0, 1, 0}, {1, 0, 0}};
  m.triangles = {{0, 1, 2}};
  std::string b = encode_mesh(m);
  ASSERT_EQ(b.size(), 8u + 72 + 12);
  float f[3];
  std::uint32_t idx[3];
  std::memcpy(f, b.data() + 8 + 12, 12);
  EXPECT_EQ(f[0], 4);
  std::memcpy(f, b.data() + 8 + 36 + 12, 12);
  EXPECT_EQ(f[1], 1);
  std::memcpy(idx, b.data() + 8 + 72, 12);
  EXPECT_EQ(idx[2], 2u);
}

TEST(ViewServer, AnswersLikeTheLibraryAndRefusesBadRequests) {
  Fixture f = sphere_grid();
  Running run(testutil::server_options());
  auto c = run.client();
  // Before the grid is there: info says preparing, surfaces are 503.
  auto info = c.Get("/api/info");
  ASSERT_TRUE(info);
  EXPECT_NE(info->body.find("\"preparing\""), std::string::npos);
  auto early = c.Get("/api/surface?iso=700");
  ASSERT_TRUE(early);
  EXPECT_EQ(early->status, 503);

  run.server.set_volume(f.volume);
  run.server.set_grid(f.grid);
  info = c.Get("/api/info");
  ASSERT_TRUE(info);
  auto j = nlohmann::json::parse(info->body);
  EXPECT_EQ(j["state"], "ready");
  EXPECT_EQ(j["kept"], f.grid->grid.vertex_count());
  EXPECT_EQ(j["tetrahedra"], f.grid->grid.tet_count());
  EXPECT_EQ(j["histogram"]["counts"].size(), 128u);
  EXPECT_TRUE(j["reference"].get<bool>());

  Extractor ex(f.grid);
  for (double iso : {700.0, 701.0, 650.0, 5000.0}) {
    auto r = c.Get(("/api/surface?client=t1&iso=" + std::to_string(iso)).c_str());
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200);
    ex.extract(iso);
    EXPECT_EQ(r->body, encode_mesh(ex.mesh())) << iso;
    EXPECT_EQ(r->get_header_value("X-Triangles"), std::to_string(ex.mesh().triangle_count()));
  }
  auto ref = c.Get("/api/reference?iso=700");
  ASSERT_TRUE(ref);
  EXPECT_EQ(triangles_in(ref->body), marching_cubes(*f.volume, 700).triangle_count());
  auto pts = c.Get("/api/points");
  ASSERT_TRUE(pts);
  EXPECT_EQ(pts->body.size(), 4 + 16 * f.grid->grid.vertex_count());
  auto tet = c.Get("/api/tetrahedra?iso=700");
  ASSERT_TRUE(tet);
  EXPECT_EQ(tet->status, 200);
  auto all = c.Get("/api/tetrahedra");
  ASSERT_TRUE(all);
  EXPECT_EQ(all->status, 200);
  EXPECT_EQ(c.Get("/")->status, 200);
  EXPECT_EQ(c.Get("/viewer.js")->status, 200);

  const std::pair<const char*, int> bad[] = {
      {"/api/surface", 400},
      {"/api/surface?iso=", 400},
      {"/api/surface?iso=abc", 400},
      {"/api/surface?iso=nan", 400},
      {"/api/surface?iso=1e999", 400},
      {"/api/surface?iso=700x", 400},
      {"/api/surface?iso=700&client=a%20b", 400},
      {"/api/surface?iso=700&client=aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa", 400},
      {"/api/reference?iso=-", 400},
      {"/api/tetrahedra?iso=inf", 400},
      {"/api/nothing", 404},
      {"/../../../etc/passwd", 404},
      {"/%2e%2e/%2e%2e/etc/passwd", 404},
      {"/node_modules/../../CMakeLists.txt", 404},
      {"/..%2f..%2fCMakeLists.txt", 404},
      {"/.gitignore", 404},
      {"/package.json/", 404},
      {"/does-not-exist.js", 404},
      {"/%00", 404},
  };
  for (const auto& [path, status] : bad) {
    auto r = c.Get(path);
    ASSERT_TRUE(r) << path;
    EXPECT_EQ(r->status, status) << path << ": " << r->body;
    EXPECT_EQ(r->body.find("root:"), std::string::npos) << path;
  }
  auto post = c.Post("/api/surface?iso=700", "x", "text/plain");
  ASSERT_TRUE(post);
  EXPECT_EQ(post->status, 405);
  // Still serving after all of that.
  auto ok = c.Get("/api/surface?iso=700");
  ASSERT_TRUE(ok);
  EXPECT_EQ(ok->status, 200);
}

TEST(ViewServer, ManyConcurrentClientsGetTheirOwnCorrectSurfaces) {
  Fixture f = sphere_grid();
  ViewOptions o = testutil::server_options();
  o.max_clients = 4;  // fewer states than clients: eviction must not break anything
  Running run(o);
  run.server.set_grid(f.grid);
  std::atomic<int> wrong{0}, failed{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t)
    threads.emplace_back([&, t] {
      auto c = run.client();
      Extractor ex(f.grid);
      for (int k = 0; k < 25; ++k) {
        const double iso = 400 + 20 * t + 7 * k;
        auto r = c.Get(("/api/surface?client=c" + std::to_string(t) + "&iso=" + std::to_string(iso)).c_str());
        if (!r || r->status != 200) {
          ++failed;
          continue;
        }
        ex.extract(iso);
        if (!same_surface(r->body, encode_mesh(ex.mesh()))) ++wrong;
      }
    });
  for (auto& th : threads) th.join();
  EXPECT_EQ(failed.load(), 0);
  EXPECT_EQ(wrong.load(), 0);
}

TEST(ViewServer, RefusesAMissingPageFolder) {
  ViewOptions o = testutil::server_options();
  o.web_dir = "/nonexistent/web";
  EXPECT_THROW(ViewServer s(o), InputError);
}

namespace {}  // namespace

TEST(ViewServer, SlowClientsDoNotFreezeTheOthers) {
  // Twelve clients sending their headers a line every 300 ms hold their connections for up to 12 s
  // (until this request is answered); with a fixed pool of 8 workers /api/info waited behind
  // them (10–17 s). The bound leaves room for a loaded machine and still catches the wait.
  Running run(testutil::server_options());
  std::atomic<bool> done{false};
  std::vector<std::thread> slow;
  for (int i = 0; i < 12; ++i)
    slow.emplace_back([&] {
      RawConnection c(run.port);
      c.send_text("GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\n");
      for (int k = 0; k < 40 && !done; ++k) {
        std::this_thread::sleep_for(std::chrono::milliseconds(300));
        c.send_text("X-Slow-" + std::to_string(k) + ": 1\r\n");
      }
    });
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  auto c = run.client();
  const auto t0 = std::chrono::steady_clock::now();
  auto r = c.Get("/api/info");
  const double waited = seconds_since(t0);
  done = true;
  for (auto& t : slow) t.join();
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_LT(waited, 6.0) << "an ordinary request waited behind slow clients";
}

TEST(ViewServer, KeptAliveRequestsAreNotDelayed) {
  // Without TCP_NODELAY the 2nd to 5th request on a kept-alive connection waited ~40 ms each
  // (Nagle's algorithm against delayed acknowledgements); 20 of them took over 0.8 s.
  Fixture f = sphere_grid();
  Running run(testutil::server_options());
  run.server.set_grid(f.grid);
  RawConnection c(run.port);
  auto request = [&](const std::string& path) {  // one request, its whole answer read
    if (!c.send_text("GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")) return false;
    std::string got;
    char buf[65536];
    std::size_t need = std::string::npos;
    while (need == std::string::npos || got.size() < need) {
      const ssize_t n = recv(c.fd, buf, sizeof buf, 0);
      if (n <= 0) return false;
      got.append(buf, static_cast<std::size_t>(n));
      if (const auto end = got.find("\r\n\r\n"); end != std::string::npos && need == std::string::npos) {
        const auto at = got.find("Content-Length: ");
        if (at == std::string::npos) return false;
        need = end + 4 + std::stoul(got.substr(at + 16));
      }
    }
    return true;
  };
  // Small answers (an empty surface: a header, then an 8-byte body) are where a second small
  // write waits for the acknowledgement of the first.
  ASSERT_TRUE(request("/api/surface?iso=5000"));
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(request("/api/surface?iso=" + std::to_string(5000 + i)));
  EXPECT_LT(seconds_since(t0), 0.5);
}

TEST(ViewServer, AnswersOnlyToTheNamesItListensOn) {
  // DNS rebinding: a page from another origin reaching 127.0.0.1 under its own name.
  Running run(testutil::server_options());
  for (const char* host : {"evil.example", "attacker.example:8080", "localhost.evil.example"}) {
    RawConnection c(run.port);
    ASSERT_TRUE(c.send_text(std::string("GET /api/info HTTP/1.1\r\nHost: ") + host + "\r\nConnection: close\r\n\r\n"));
    char buf[256] = {};
    const ssize_t n = recv(c.fd, buf, sizeof buf - 1, 0);
    ASSERT_GT(n, 12) << host;
    EXPECT_EQ(std::string(buf, 12), "HTTP/1.1 403") << host;
  }
  for (std::string host : {"127.0.0.1", "localhost", "LOCALHOST"}) {
    httplib::Client c("127.0.0.1", run.port);
    auto r = c.Get("/api/info", {{"Host", host + ":" + std::to_string(run.port)}});
    ASSERT_TRUE(r) << host;
    EXPECT_EQ(r->status, 200) << host;
  }
}

TEST(ViewServer, InfoGivesTheSourceFileNameOnly) {
  Fixture f = sphere_grid();
  auto grid = std::make_shared<PreparedGrid>(*f.grid);
  grid->grid.source.file = "/home/someone/private/scans/patient-42.nrrd";  // as older grid files stored it
  Running run(testutil::server_options());
  run.server.set_grid(grid);
  auto r = run.client().Get("/api/info");
  ASSERT_TRUE(r);
  EXPECT_EQ(nlohmann::json::parse(r->body)["source"], "patient-42.nrrd");
  EXPECT_EQ(r->body.find("/home/someone"), std::string::npos);
}

TEST(ViewServer, ServesOnlyWhatThePageLoads) {
  Running run(testutil::server_options());
  auto c = run.client();
  for (const char* ok : {"/", "/index.html", "/viewer.js", "/style.css", "/node_modules/three/build/three.module.js",
                         "/node_modules/three/build/three.core.js", "/node_modules/three/examples/jsm/controls/OrbitControls.js"}) {
    auto r = c.Get(ok);
    ASSERT_TRUE(r) << ok;
    EXPECT_EQ(r->status, 200) << ok;
  }
  for (const char* no : {"/node_modules/playwright-core/package.json", "/node_modules/three/package.json", "/package.json", "/served.txt",
                         "/node_modules/.package-lock.json", "/package-lock.json"}) {
    auto r = c.Get(no);
    ASSERT_TRUE(r) << no;
    EXPECT_EQ(r->status, 404) << no;
  }
}

TEST(ViewServer, OtherMethodsAre405) {
  Running run(testutil::server_options());
  auto c = run.client();
  auto o = c.Options("/api/info");
  ASSERT_TRUE(o);
  EXPECT_EQ(o->status, 405);
  auto p = c.Patch("/api/info", "x", "text/plain");
  ASSERT_TRUE(p);
  EXPECT_EQ(p->status, 405);
}

TEST(ViewServer, CoarserLevelsWhileDraggingWithTheirGuaranteedError) {
  // A bisection grid: /api/info lists the ladder; error= and budget= choose a coarser level, whose
  // surface is the one preparing at that level's bound gives, and the answer names its bound.
  const auto volume = std::make_shared<Volume>(make_synthetic("marschner-lobb", 40, ScalarType::f32));
  const auto grid = bisection_grid_of(*volume, 0.002);
  Running run(testutil::server_options());
  run.server.set_grid(grid);
  auto c = run.client();
  const nlohmann::json info = info_with_levels_built(c);
  ASSERT_GE(info["levels"].size(), 5u);
  EXPECT_DOUBLE_EQ(info["error_bound"].get<double>(), grid->stats.error_bound);
  EXPECT_TRUE(info["error_guaranteed"].get<bool>());
  const double iso = 0.5;
  auto fine = c.Get("/api/surface?iso=0.5&client=a");
  ASSERT_EQ(fine->status, 200);
  EXPECT_EQ(fine->get_header_value("X-Level"), "0");
  EXPECT_DOUBLE_EQ(std::stod(fine->get_header_value("X-Error-Bound")), grid->stats.error_bound);
  for (std::size_t k = 1; k < info["levels"].size(); k += 2) {
    if (info["levels"][k]["cell_floor"].get<int>() != 0) continue;  // floored levels serve budgets, not errors
    const double bound = info["levels"][k]["bound"].get<double>();
    auto r = c.Get(fmt::format("/api/surface?iso={}&client=a&error={:.17g}", iso, bound));
    ASSERT_EQ(r->status, 200) << r->body;
    EXPECT_EQ(r->get_header_value("X-Level"), std::to_string(k));
    const double guaranteed = std::stod(r->get_header_value("X-Error-Bound"));
    EXPECT_LE(guaranteed, bound);
    EXPECT_GE(guaranteed, grid->stats.error_bound);
    // The same surface as a grid prepared at that bound.
    PrepareOptions at;
    at.max_error = bound;
    Extractor direct(std::make_shared<const PreparedGrid>(prepare(*volume, at)));
    direct.extract(iso);
    EXPECT_TRUE(same_surface(r->body, encode_mesh(direct.mesh()))) << "level " << k;
  }
  // A budget smaller than the prepared surface gives a coarser level within it, once the ladder
  // has seen the levels' counts.
  const std::uint32_t full = triangles_in(fine->body);
  std::string level;
  for (int step = 0; step < 6; ++step) {
    auto r = c.Get(fmt::format("/api/surface?iso={}&client=a&budget={}", iso + 0.001 * step, full / 4));
    ASSERT_EQ(r->status, 200);
    level = r->get_header_value("X-Level");
    if (step > 2) {
      EXPECT_LE(std::stoul(r->get_header_value("X-Triangles")), full / 4);
    }
  }
  EXPECT_NE(level, "0");
  // Compact encoding: the same triangles in far fewer bytes.
  auto compact = c.Get("/api/surface?iso=0.5&client=b&format=compact");
  ASSERT_EQ(compact->status, 200);
  EXPECT_EQ(compact->get_header_value("X-Encoding"), "compact");
  const Mesh decoded = decode_mesh_compact(compact->body);
  EXPECT_EQ(decoded.triangle_count(), full);
  EXPECT_LT(compact->body.size() * 3, fine->body.size());
  for (const char* bad : {"error=-1", "error=abc", "budget=-5", "format=zip"})
    EXPECT_EQ(c.Get(std::string("/api/surface?iso=0.5&") + bad)->status, 400) << bad;
}

TEST(ViewServer, AfterADragTheSurfaceAtRestIsTheFreshMarchsWhateverTheFollowerWasDoing) {
  // While a page drags, the follower extracts the level at rest in the background; the page's own
  // request cancels it mid-way (or waits for it, when it extracts that very surface: the drag ends
  // at the released iso-value) or drops its stale jobs. Whatever it was doing, the surface at rest
  // and its export are those of a fresh extraction at the released iso-value.
  const auto volume = std::make_shared<Volume>(make_synthetic("marschner-lobb", 48, ScalarType::f32));
  const auto grid = bisection_grid_of(*volume, 0.002);
  Running run(testutil::server_options());
  run.server.set_grid(grid);
  auto c = run.client();
  ASSERT_GT(info_with_levels_built(c)["levels"].size(), 1u);  // so the drag has a coarse level
  for (int round = 0; round < 3; ++round) {
    const double released = 0.3 + 0.1 * round;
    for (int step = 0; step <= 20; ++step) {  // a drag: coarse answers, each queueing the follower
      const double iso = 0.75 - (0.75 - released) * step / 20.0;
      ASSERT_EQ(c.Get(fmt::format("/api/surface?iso={:.17g}&client=d&budget=50", iso))->status, 200);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(round * 3));  // catch the follower at different stages
    auto rest = c.Get(fmt::format("/api/surface?iso={:.17g}&client=d", released));
    ASSERT_EQ(rest->status, 200);
    EXPECT_EQ(rest->get_header_value("X-Level"), "0");
    EXPECT_GE(std::stod(rest->get_header_value("X-Wait-Seconds")), 0.0);
    Extractor direct(grid);
    direct.extract(released);
    EXPECT_TRUE(same_surface(rest->body, encode_mesh(direct.mesh()))) << "round " << round;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));  // stale follower jobs would run now
    auto file = c.Get(fmt::format("/api/export?iso={:.17g}&client=d&format=ply", released));
    ASSERT_EQ(file->status, 200);
    EXPECT_EQ(file->get_header_value("X-Triangles"), std::to_string(direct.mesh().triangle_count())) << "round " << round;
  }
}

TEST(ViewServer, ExportDownloadsTheSurfaceSimplified) {
  const auto grid = bisection_grid_of(make_synthetic("sphere", 40, ScalarType::i16), 0.01);
  Running run(testutil::server_options());
  run.server.set_grid(grid);
  auto c = run.client();
  auto full = c.Get("/api/export?iso=700&format=ply");
  ASSERT_EQ(full->status, 200) << full->body;
  EXPECT_NE(full->get_header_value("Content-Disposition").find("adaptiso-700.ply"), std::string::npos);
  Extractor ex(grid);
  ex.extract(700);
  EXPECT_EQ(full->body, mesh_file_bytes(ex.mesh(), "x.ply"));  // unsimplified: the surface itself
  auto simplified = c.Get("/api/export?iso=700&simplify=0.5&format=glb");
  ASSERT_EQ(simplified->status, 200);
  EXPECT_EQ(simplified->body.substr(0, 4), "glTF");
  EXPECT_LT(std::stoul(simplified->get_header_value("X-Triangles")), ex.mesh().triangle_count());
  EXPECT_EQ(simplified->get_header_value("X-Triangles-Before"), std::to_string(ex.mesh().triangle_count()));
  EXPECT_EQ(simplified->get_header_value("X-Simplify-Checked"), "0");
  auto checked = c.Get("/api/export?iso=700&simplify=0.5&checked=1&format=ply");
  ASSERT_EQ(checked->status, 200) << checked->body;
  EXPECT_EQ(checked->get_header_value("X-Simplify-Checked"), "1");
  EXPECT_LT(std::stoul(checked->get_header_value("X-Triangles")), ex.mesh().triangle_count());
  EXPECT_GE(std::stoul(checked->get_header_value("X-Triangles")), std::stoul(simplified->get_header_value("X-Triangles")));
  for (const char* bad : {"simplify=-1", "format=stl", "simplify=x", "checked=yes"})
    EXPECT_EQ(c.Get(std::string("/api/export?iso=700&") + bad)->status, 400) << bad;
}

TEST(ViewServer, SurfacesWithinADistanceAreTheLibrarysAndNeedNoLevels) {
  const auto volume = std::make_shared<Volume>(make_synthetic("marschner-lobb", 40, ScalarType::f32));
  const auto grid = bisection_grid_of(*volume, 0.002);
  Running run(testutil::server_options());
  run.server.set_grid(grid);
  auto c = run.client();
  const nlohmann::json info = nlohmann::json::parse(c.Get("/api/info")->body);
  EXPECT_TRUE(info["distance"].get<bool>());
  const HierarchyQuery query(grid);
  for (double distance : {0.0, 0.5, 2.0}) {
    auto r = c.Get(fmt::format("/api/surface?iso=0.45&client=a&distance={}", distance));
    ASSERT_EQ(r->status, 200) << r->body;
    EXPECT_EQ(std::stod(r->get_header_value("X-Distance")), distance);
    EXPECT_EQ(r->body, encode_mesh(query.extract_within(0.45, distance))) << distance;  // the same bytes: a fresh query
    EXPECT_EQ(std::to_string(triangles_in(r->body)), r->get_header_value("X-Triangles"));
    auto compact = c.Get(fmt::format("/api/surface?iso=0.45&client=a&distance={}&format=compact", distance));
    ASSERT_EQ(compact->status, 200);
    EXPECT_EQ(compact->get_header_value("X-Encoding"), "compact");
  }
  // No level of detail was built for them.
  const nlohmann::json after = nlohmann::json::parse(c.Get("/api/info")->body);
  for (std::size_t k = 1; k < after["levels"].size(); ++k) EXPECT_FALSE(after["levels"][k]["built"].get<bool>()) << k;
  for (const char* bad : {"distance=-1", "distance=nan", "distance=2&error=0.1", "distance=2&budget=1000", "distance=x",
                          "distance=2&collapse=17", "distance=2&collapse=1.5", "distance=2&collapse=-1", "collapse=1",
                          "distance=2&min_piece=-1", "distance=2&min_piece=nan", "distance=2&min_piece=x", "min_piece=1"}) {
    auto r = c.Get(fmt::format("/api/surface?iso=0.45&client=a&{}", bad));
    EXPECT_EQ(r->status, 400) << bad;
  }
  // collapse= asks for the rounds of edge collapses (the page asks for none while it draws).
  for (int rounds : {0, 1, 3}) {
    auto r = c.Get(fmt::format("/api/surface?iso=0.45&client=a&distance=2&collapse={}", rounds));
    ASSERT_EQ(r->status, 200) << r->body;
    EXPECT_EQ(r->body, encode_mesh(query.extract_within(0.45, 2, nullptr, rounds))) << rounds;
  }
  // min_piece= sets the smallest piece kept (the distance by default; 0 keeps every one): the
  // field's small lobes go at 6 voxels.
  std::vector<std::size_t> specks;
  for (double piece : {0.0, 2.0, 6.0}) {
    auto r = c.Get(fmt::format("/api/surface?iso=0.45&client=a&distance=2&min_piece={}", piece));
    ASSERT_EQ(r->status, 200) << r->body;
    DistanceQueryStats st;
    EXPECT_EQ(r->body, encode_mesh(query.extract_within(0.45, 2, &st, kDefaultCollapseRounds, nullptr, {}, piece))) << piece;
    EXPECT_EQ(r->get_header_value("X-Specks"), std::to_string(st.specks));
    EXPECT_EQ(std::stod(r->get_header_value("X-Min-Piece")), piece);
    auto file = c.Get(fmt::format("/api/export?iso=0.45&client=a&distance=2&min_piece={}&format=ply", piece));
    ASSERT_EQ(file->status, 200);
    EXPECT_EQ(file->get_header_value("X-Triangles"), std::to_string(st.triangles)) << piece;
    specks.push_back(st.specks);
  }
  EXPECT_EQ(specks[0], 0u);
  EXPECT_GT(specks[2], specks[1]);
  EXPECT_EQ(std::stod(c.Get("/api/surface?iso=0.45&client=a&distance=2")->get_header_value("X-Min-Piece")), 2.0);
  EXPECT_EQ(c.Get("/api/export?iso=0.45&client=a&min_piece=0&format=ply")->status, 400);
  auto exported = c.Get("/api/export?iso=0.45&client=a&distance=2&format=ply");
  ASSERT_EQ(exported->status, 200);
  EXPECT_EQ(exported->get_header_value("X-Triangles"), std::to_string(query.extract_within(0.45, 2).triangle_count()));
  auto marched = c.Get("/api/export?iso=0.45&client=a&distance=2&collapse=0&format=ply");
  ASSERT_EQ(marched->status, 200);
  EXPECT_EQ(marched->get_header_value("X-Triangles"), std::to_string(query.extract_within(0.45, 2, nullptr, 0).triangle_count()));
  EXPECT_EQ(c.Get("/api/export?iso=0.45&client=a&collapse=0&format=ply")->status, 400);
  // A Delaunay grid keeps no hierarchy: refused with one line.
  PrepareOptions o;
  o.grid = GridKind::delaunay;
  o.max_error = 0.05;
  o.relative = true;
  run.server.set_grid(std::make_shared<const PreparedGrid>(prepare(*volume, o)));
  EXPECT_FALSE(nlohmann::json::parse(c.Get("/api/info")->body)["distance"].get<bool>());
  auto r = c.Get("/api/surface?iso=0.45&client=a&distance=1");
  EXPECT_EQ(r->status, 400);
  EXPECT_NE(r->body.find("bisection"), std::string::npos);
}

// A page's new distance request cancels its previous one still running (the page dropped it: a
// drag overtook the surface at rest): of two at once from one page, the one that arrives first is
// answered 409 if it had not finished, the other is whole. Requests without client= cancel
// nothing. Which arrives first, and whether it had finished, is the threads' timing: every answer
// is checked either way.
TEST(ViewServer, APagesNextDistanceRequestCancelsItsPreviousOne) {
  const auto volume = std::make_shared<Volume>(make_synthetic("marschner-lobb", 65, ScalarType::f32));
  const auto grid = bisection_grid_of(*volume, 0.0005);
  Running run(testutil::server_options());
  run.server.set_grid(grid);
  const HierarchyQuery query(grid);
  const std::string fine = encode_mesh(query.extract_within(0.45, 0.25)), coarse = encode_mesh(query.extract_within(0.45, 4));
  for (const char* client : {"&client=page", ""}) {
    int cancelled = 0;
    for (int k = 0; k < 8; ++k) {
      std::pair<int, std::string> first, next;
      auto get = [&](double distance, std::pair<int, std::string>& out) {
        auto r = run.client().Get(fmt::format("/api/surface?iso=0.45&distance={}{}", distance, client));
        if (r) out = {r->status, r->body};
      };
      std::thread slow([&] { get(0.25, first); });
      std::this_thread::sleep_for(std::chrono::milliseconds(3 * k));
      get(4, next);
      slow.join();
      for (const auto& [answer, whole] : {std::pair{&first, &fine}, std::pair{&next, &coarse}}) {
        if (answer->first == 409) {
          ++cancelled;
          EXPECT_NE(answer->second.find("cancelled"), std::string::npos) << answer->second;
        } else {
          ASSERT_EQ(answer->first, 200) << answer->second;
          EXPECT_EQ(answer->second, *whole);
        }
      }
      EXPECT_FALSE(first.first == 409 && next.first == 409) << "both cancelled";
    }
    // The fine surface takes about 0.1 s and the coarse one is asked for within 21 ms: they overlap.
    if (*client == 0) {
      EXPECT_EQ(cancelled, 0) << "anonymous requests cancelled each other";
    } else {
      EXPECT_GE(cancelled, 1) << "no request of the page was cancelled";
    }
  }
}

// `adaptiso view GRID.adg` serves a bisection grid loaded in part (OpenGridFile): surfaces within a
// distance need nothing more; the first route that walks the tetrahedra reads them, once, from the
// file as opened (here deleted by then), and a rest that cannot be read answers every such request
// with its message without reading again.
TEST(ViewServer, AGridLoadedInPartReadsItsTetrahedraOnceWhenARouteNeedsThem) {
  const auto volume = std::make_shared<Volume>(make_synthetic("marschner-lobb", 40, ScalarType::f32));
  const auto grid = bisection_grid_of(*volume, 0.002);
  testutil::TempDir t("view_in_part");
  const std::string path = (t.path / "g.adg").string();
  save_grid(*grid, path);
  const auto file = std::make_shared<const OpenGridFile>(path);
  const auto part = std::make_shared<const PreparedGrid>(file->load(GridParts::hierarchy_or_all));
  ASSERT_TRUE(loaded_in_part(*part));
  std::filesystem::remove(path);
  std::atomic<int> reads = 0;
  Running run(testutil::server_options());
  run.server.set_grid(part, [&] {
    ++reads;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));  // the second request arrives meanwhile
    return std::make_shared<const PreparedGrid>(file->load(GridParts::all));
  });
  auto c = run.client();
  const nlohmann::json info = nlohmann::json::parse(c.Get("/api/info")->body);
  EXPECT_EQ(info["tetrahedra"].get<std::uint64_t>(), grid->grid.tet_count());
  EXPECT_TRUE(info["distance"].get<bool>());
  EXPECT_GT(info["levels"].size(), 1u);
  auto near = c.Get("/api/surface?iso=0.45&client=a&distance=1");
  ASSERT_EQ(near->status, 200) << near->body;
  EXPECT_EQ(near->body, encode_mesh(HierarchyQuery(grid).extract_within(0.45, 1)));
  EXPECT_EQ(reads, 0);

  Extractor ex(grid);
  ex.extract(0.45);
  const std::string expected = encode_mesh(ex.mesh());
  std::string bodies[2];
  std::thread other([&] { bodies[1] = run.client().Get("/api/surface?iso=0.45&client=b")->body; });
  bodies[0] = c.Get("/api/surface?iso=0.45&client=a")->body;
  other.join();
  EXPECT_TRUE(same_surface(bodies[0], expected));
  EXPECT_TRUE(same_surface(bodies[1], expected));
  EXPECT_EQ(c.Get("/api/tetrahedra?iso=0.45")->status, 200);
  EXPECT_EQ(reads, 1);
  EXPECT_EQ(nlohmann::json::parse(c.Get("/api/info")->body)["tetrahedra"].get<std::uint64_t>(), grid->grid.tet_count());

  std::atomic<int> failures = 0;
  run.server.set_grid(part, [&]() -> std::shared_ptr<const PreparedGrid> {
    ++failures;
    throw InputError("g.adg: grid file is corrupt (a test's lie)");
  });
  for (int k = 0; k < 2; ++k) {
    auto r = c.Get("/api/surface?iso=0.45&client=a");
    EXPECT_EQ(r->status, 400);
    EXPECT_NE(r->body.find("a test's lie"), std::string::npos) << r->body;
    EXPECT_EQ(c.Get("/api/tetrahedra?iso=0.45")->status, 400);
  }
  EXPECT_EQ(failures, 1);
  EXPECT_EQ(c.Get("/api/surface?iso=0.45&client=a&distance=1")->status, 200);
}

// Without a volume the histogram is the grid's vertex values: of a padded lattice, those inside the
// volume's box, not the copies of its last slices past the far faces. The same for the kept count
// (the info's and the facts') and the point cloud, which counted and drew the copies too.
TEST(ViewServer, AGridsHistogramKeptCountAndPointsAreTheVolumesVoxelsNotThePaddingsCopies) {
  const Volume v = make_synthetic("noise", 14, ScalarType::f32);
  PrepareOptions o;
  o.max_error = 0;
  const auto g = std::make_shared<const PreparedGrid>(prepare(v, o));
  ASSERT_TRUE(g->grid.source.padded());
  std::int64_t inside = 0;
  for (const auto& c : g->grid.ijk) inside += c[0] < 14 && c[1] < 14 && c[2] < 14;
  ASSERT_LT(inside, std::int64_t(g->grid.vertex_count()));
  EXPECT_GE(inside, 13 * 13 * 13);  // noise at error 0: every voxel off the last slices
  Running run(testutil::server_options());
  run.server.set_grid(g);
  auto c = run.client();
  const auto j = nlohmann::json::parse(c.Get("/api/info")->body);
  ASSERT_EQ(j["histogram"]["of"], "vertices");
  std::int64_t total = 0;
  for (const auto& n : j["histogram"]["counts"]) total += n.get<std::int64_t>();
  EXPECT_EQ(total, inside);
  EXPECT_EQ(j["kept"].get<std::int64_t>(), inside);
  EXPECT_EQ(j["facts"]["kept"].get<std::int64_t>(), inside);
  EXPECT_EQ(j["facts"]["vertices"].get<std::size_t>(), g->grid.vertex_count());
  const auto pts = c.Get("/api/points");
  ASSERT_EQ(pts->status, 200);
  std::uint32_t n = 0;
  std::memcpy(&n, pts->body.data(), 4);
  ASSERT_EQ(std::int64_t(n), inside);
  ASSERT_EQ(pts->body.size(), 4 + 16 * std::size_t{n});
  for (std::size_t i = 0; i < 3 * std::size_t{n}; ++i) {
    float x;
    std::memcpy(&x, pts->body.data() + 4 + 4 * i, 4);
    ASSERT_TRUE(x >= 0 && x <= 13) << i << " " << x;  // unit spacing, origin 0: the box is [0, 13]
  }
}
