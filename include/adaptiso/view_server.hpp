// adaptiso/view_server.hpp — the local web server behind `adaptiso view`: serves the viewer page
// and a small HTTP API over one prepared grid (docs/API.md specifies the routes and the
// binary layouts). The grid may arrive after the server starts (the page shows the progress of
// the preparation meanwhile). Each client (`client=` parameter) gets its own Extractor, so small
// slider moves are incremental and clients never block each other; bad requests get 400/404 with
// a message, requests for a grid not ready yet 503, and the server keeps running.
// Throws OptionError("web_dir") when the page's folder lacks index.html, InputError when it
// cannot bind.
#pragma once
#include <memory>
#include <string>

#include "adaptiso/mesh.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/volume.hpp"

namespace adaptiso {

struct ViewOptions {
  std::string host = "127.0.0.1";
  int port = 8080;               // 0: any free port
  std::string web_dir;           // the page's folder; static files are served from it only
  std::size_t max_clients = 32;  // least recently used client states are dropped beyond this
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
  void set_grid(std::shared_ptr<const PreparedGrid> grid);
  // The source volume: enables /api/reference and the histogram of voxel values.
  void set_volume(std::shared_ptr<const Volume> volume);

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Little-endian body of /api/surface and /api/reference: u32 vertex count V, u32 triangle count T,
// f32 positions[3V], f32 normals[3V], u32 indices[3T].
std::string encode_mesh(const Mesh& mesh);

}  // namespace adaptiso
