// adaptiso compare: symmetric surface distance between two meshes (PLY).
#include <fmt/format.h>

#include <iostream>

#include "adaptiso/mesh_io.hpp"
#include "adaptiso/surface_distance.hpp"
#include "cli_common.hpp"

namespace adaptiso::cli {

void add_compare(CLI::App& app) {
  auto* cmd = app.add_subcommand("compare", "Symmetric surface distance between two meshes (.ply): mean, RMS, 95th percentile, max");
  auto a = std::make_shared<std::string>(), b = std::make_shared<std::string>();
  auto voxel = std::make_shared<double>(1.0);
  auto samples = std::make_shared<std::size_t>(200'000);
  auto max_samples = std::make_shared<std::size_t>(4'000'000);
  auto out = std::make_shared<OutputFlags>();
  cmd->add_option("A", *a, "First mesh (.ply)")->required();
  cmd->add_option("B", *b, "Second mesh (.ply)")->required();
  cmd->add_option("--voxel", *voxel, "Length of a voxel in the meshes' units, for the figures in voxels")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_option("--samples", *samples, "Minimum samples per direction (at least 4 per triangle are taken)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{1000}, std::size_t{100'000'000}));
  cmd->add_option("--max-samples", *max_samples, "Most samples per direction (besides the vertices)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{1000}, std::size_t{100'000'000}));
  out->add(cmd);
  cmd->callback([=] {
    auto t0 = Clock::now();
    Mesh ma = read_ply(*a), mb = read_ply(*b);
    DistanceOptions o;
    o.min_samples = *samples;
    o.max_samples = std::max(*max_samples, *samples);
    SurfaceDistance d = surface_distance(ma, mb, o);
    auto stats = [&](const DistanceStats& s) {
      return nlohmann::json{{"samples", s.samples},
                            {"mean", s.mean},
                            {"rms", s.rms},
                            {"p95", s.p95},
                            {"max", s.max},
                            {"mean_voxels", s.mean / *voxel},
                            {"rms_voxels", s.rms / *voxel},
                            {"p95_voxels", s.p95 / *voxel},
                            {"max_voxels", s.max / *voxel}};
    };
    nlohmann::json j = {{"a", *a},
                        {"b", *b},
                        {"a_triangles", ma.triangle_count()},
                        {"b_triangles", mb.triangle_count()},
                        {"voxel", *voxel},
                        {"a_to_b", stats(d.a_to_b)},
                        {"b_to_a", stats(d.b_to_a)},
                        {"hausdorff", d.hausdorff()},
                        {"hausdorff_voxels", d.hausdorff() / *voxel},
                        {"seconds", seconds_since(t0)}};
    if (out->json) return print_json(j);
    if (out->quiet) return;
    auto line = [&](const char* name, const DistanceStats& s) {
      std::cout << fmt::format(
          "{}: mean {:.4g}  rms {:.4g}  p95 {:.4g}  max {:.4g}   (voxels: {:.3g} / {:.3g} / {:.3g} / {:.3g})  [{} samples]\n", name, s.mean,
          s.rms, s.p95, s.max, s.mean / *voxel, s.rms / *voxel, s.p95 / *voxel, s.max / *voxel, s.samples);
    };
    line("A→B", d.a_to_b);
    line("B→A", d.b_to_a);
    std::cout << fmt::format("Hausdorff distance {:.4g} ({:.3g} voxels)\n", d.hausdorff(), d.hausdorff() / *voxel);
  });
}

}  // namespace adaptiso::cli
