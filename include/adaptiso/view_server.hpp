// adaptiso/view_server.hpp — the local web server behind `adaptiso view`: serves the viewer page
// and a small HTTP API over one prepared grid (docs/API.md specifies the routes, parameters,
// headers, errors and binary layouts). The grid may arrive after the server starts (the page
// shows the progress of the preparation meanwhile). Each client (`client=` parameter) gets its
// own Extractor per level of detail, so small slider moves are incremental and clients never block
// each other. What the server keeps for its clients is held within a memory budget (bytes of its
// resident set): idle extractors and levels of detail are dropped, and a request that cannot fit
// is answered 503 with Retry-After. Bad requests get 400/404/405 with a message, requests for a
// grid not ready yet 503, web pages of other origins 403, and the server keeps running.
// Throws OptionError("web_dir") when the page's folder lacks index.html, InputError when it
// cannot bind.
#pragma once
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/mesh.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/volume.hpp"

namespace adaptiso {

// Makes a surface within a distance (HierarchyQuery::extract_within's arguments, `local` the
// server's own query) and returns it with the number of the process that made it (0: this one).
// The default asks `local`; `mpirun … adaptiso view` hands the query to another rank holding the
// same grid (apps/adaptiso/view_ranks.cpp), so the library stays free of MPI. Called from the
// connection threads, several at once; honours `cancel` as extract_within does and throws what it
// throws (ExtractCancelled, OptionError, std::bad_alloc).
using DistanceSurfaces =
    std::function<Mesh(const HierarchyQuery& local, double iso, double distance, int collapse_rounds, std::optional<double> min_piece,
                       DistanceQueryStats* stats, const std::atomic<bool>* cancel, int* process)>;

struct ViewOptions {
  std::string host = "127.0.0.1";
  int port = 8080;               // 0: any free port
  std::string web_dir;           // the page's folder; static files are served from it only
  std::size_t max_clients = 32;  // least recently used client states are dropped beyond this
  // Bytes of resident set the server may hold, its grid included; 0: half of the machine's memory,
  // no more than it can have now (see src/view/memory_budget.hpp). A budget below the grid's own
  // size serves one request at a time.
  std::uint64_t memory_budget = 0;
  // An extractor unused this long is dropped, the levels of detail unused 5× as long.
  double idle_seconds = 60;
  // Origins ("http://host:port", "*": any) whose web pages may use the API besides the page the
  // server serves itself.
  std::vector<std::string> allowed_origins;
  double thread_idle_seconds = 10;  // connection threads idle this long exit (a few are kept)
  // Where surfaces within a distance are made (empty: in this process). Only for a grid that
  // stays the one set first (set_grid, or its whole read later), since the makers hold their own.
  DistanceSurfaces distance_surfaces;
  int ranks = 1;  // the processes those are made by (mpirun … view), in /api/info for the page
};

class ViewServer {
public:
  explicit ViewServer(ViewOptions options);
  ~ViewServer();
  ViewServer(const ViewServer&) = delete;
  ViewServer& operator=(const ViewServer&) = delete;

  // Binds the socket; returns the port (throws InputError when it cannot bind).
  int bind();
  void listen();  // serves until stop()
  void stop();

  void set_progress(const std::string& stage, double fraction);
  void set_failed(const std::string& message);
  // The grid to serve; its statistics appear in /api/info. Clients of an earlier grid start anew.
  // A grid loaded in part (grid_file.hpp: OpenGridFile, GridParts::hierarchy) serves what it
  // holds as it is (surfaces within a distance, the points, /api/info); `rest` reads the whole
  // grid the first time a route needs its tetrahedra (a surface at an error level, a download at
  // one, the wireframe), once: the other requests wait for it, and its InputError answers them.
  void set_grid(std::shared_ptr<const PreparedGrid> grid, std::function<std::shared_ptr<const PreparedGrid>()> rest = {});
  // The source volume: enables /api/reference and the histogram of voxel values.
  void set_volume(std::shared_ptr<const Volume> volume);
  std::uint64_t memory_budget() const;  // bytes, the default resolved

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Little-endian body of /api/surface and /api/reference: u32 vertex count V, u32 triangle count T,
// f32 positions[3V], f32 normals[3V], u32 indices[3T].
std::string encode_mesh(const Mesh& mesh);

}  // namespace adaptiso
